"""Vectorised decoding of a batch of ``.cwa`` data sectors (pure functions, no I/O, no state).

* ``classify``  — why each sector is unusable (tag, length, checksum, format) or 0 if valid.
* ``decode_samples`` — packed (3 x 10 bit + exponent) and unpacked int16 samples to counts.
* ``sector_anchors`` — each sector's timing anchor (sample index, UTC ns) per cwa-format.md §7.2.
* ``interpolate_times`` — piecewise-linear sample times through a segment's anchors.

All work on whole batches of sectors with numpy; no per-sample Python loops.
"""

from __future__ import annotations

import numpy as np

from . import constants as C
from .cwa_layout import FORMATS, unpack_timestamps

_NS = 1_000_000_000

# Reason codes of ``classify`` (0 = valid) and their QC names.
OK, ERASED, HEADER, LEGACY, BAD_TAG, BAD_LENGTH, CHECKSUM, BAD_FORMAT, EMPTY = range(9)
REASONS = {
    ERASED: "erased", HEADER: "header_sector", LEGACY: "legacy_sector", BAD_TAG: "bad_tag",
    BAD_LENGTH: "bad_length", CHECKSUM: "checksum", BAD_FORMAT: "bad_format", EMPTY: "empty",
}
# legacy / prototype sector tags that are skipped (§2): UB, SI, GY, GX, MX
_LEGACY_TAGS = np.array([0x4255, 0x4953, 0x5947, 0x5847, 0x584D], np.uint16)
_CAPACITY = np.zeros(256, np.int64)  # numAxesBPS -> samples per sector (0 = not decodable)
for _fmt, (_, _bps, _) in FORMATS.items():
    _CAPACITY[_fmt] = 480 // _bps


def classify(sec: np.ndarray) -> np.ndarray:
    """(k,) SECTOR_DTYPE -> (k,) uint8 reason code (0 = a valid, decodable data sector)."""
    k = sec.shape[0]
    words = sec.view("<u2").reshape(k, 256)
    csum_ok = words.sum(axis=1, dtype=np.uint16) == 0
    tag = sec["tag"]
    fmt = sec["num_axes_bps"]
    reason = np.zeros(k, np.uint8)
    bad = ~csum_ok
    if bad.any():
        # legacy checksum accepted by cwa-convert: stored word == byte sum of the first 510 bytes
        idx = np.flatnonzero(bad)
        raw = sec[idx].view(np.uint8).reshape(-1, 512)
        legacy = raw[:, :510].sum(axis=1, dtype=np.uint32) & 0xFFFF
        csum_ok[idx] = legacy == sec["checksum"][idx]
        reason[~csum_ok] = CHECKSUM
    known_fmt = _CAPACITY[fmt] > 0
    rate_low = sec["rate_code"] & 0x0F
    reason[(reason == 0) & (~known_fmt | (rate_low < 6) | (sec["rate_code"] == 0))] = BAD_FORMAT
    reason[(reason == 0) & (sec["sample_count"] == 0)] = EMPTY
    # structural problems override the checksum reason (they say more)
    reason[sec["length"] != C.CWA_DATA_PACKET_LENGTH] = BAD_LENGTH
    not_ax = tag != C.CWA_TAG_DATA
    if not_ax.any():
        reason[not_ax] = BAD_TAG
        reason[not_ax & np.isin(tag, _LEGACY_TAGS)] = LEGACY
        reason[tag == C.CWA_TAG_HEADER] = HEADER
        erased = (tag == C.CWA_TAG_ERASED) & (words == 0xFFFF).all(axis=1)
        reason[erased] = ERASED
    return reason


def max_samples(fmt: np.ndarray) -> np.ndarray:
    """Samples that fit one sector for each numAxesBPS value (§5.1)."""
    return _CAPACITY[fmt]


def decode_samples(sec: np.ndarray, fmt: int, counts: np.ndarray):
    """Samples of sectors that all share format ``fmt`` -> (accel (n,3) int16, gyro (n,3) | None).

    ``counts`` (k,) valid samples per sector (already clamped to the sector's capacity).
    Packed: x, y, z are 10-bit two's complement scaled by 2^e (e = bits 31..30), computed as
    int32((v << (22 - 10*axis)) & 0xFFC00000) >> (22 - e); unpacked: int16 LE, gyro first on 6-axis sectors.
    """
    k = sec.shape[0]
    ch, bps, packed = FORMATS[fmt]
    spp = 480 // bps
    raw = sec.view(np.uint8).reshape(k, 512)
    full = bool((counts == spp).all())
    if packed:
        v = np.ascontiguousarray(raw[:, 30:510]).view("<u4").reshape(k * spp)
        if not full:
            v = v[(np.arange(spp) < counts[:, None]).reshape(-1)]
        n = v.shape[0]
        sh = (v >> np.uint32(30)).view(np.int32)  # exponent 0..3, reinterpreted in place
        np.subtract(np.int32(22), sh, out=sh)
        accel = np.empty((n, 3), np.int16)
        tmp = np.empty(n, np.uint32)
        top10 = np.uint32(0xFFC00000)
        for axis, left in enumerate((22, 12, 2)):
            np.left_shift(v, np.uint32(left), out=tmp)
            if left != 22:
                np.bitwise_and(tmp, top10, out=tmp)  # drop the lower fields' bits
            accel[:, axis] = np.right_shift(tmp.view(np.int32), sh)
        return accel, None
    s = np.ascontiguousarray(raw[:, 30:30 + spp * bps]).view("<i2").reshape(k * spp, ch)
    if not full:
        s = s[(np.arange(spp) < counts[:, None]).reshape(-1)]
    # The result must own its memory: ``sec`` may view the reader's reusable buffer, and a
    # one-sector batch makes ``s`` a plain view of it (which ascontiguousarray would not copy).
    if ch == 6:
        return np.array(s[:, 3:6], order="C"), np.array(s[:, 0:3], order="C")
    return (s if s.base is None else np.array(s, order="C")), None


def sector_anchors(sec: np.ndarray, tz_s: int):
    """(k,) sectors -> (idx int64, t_ns int64 UTC, ok bool) per cwa-format.md §7.2.

    idx is the anchor's sample index relative to the sector's first sample; t_ns the anchor
    time (whole seconds + 15-bit fraction when bit 15 of deviceFractional is set, rounded to
    the nearest ns). ok is False when the timestamp is 0 or not a valid date.
    """
    secs, ok = unpack_timestamps(sec["timestamp"])
    df = sec["device_fractional"].astype(np.int64)
    has_frac = (df & 0x8000) != 0
    f15 = np.where(has_frac, df & 0x7FFF, 0)
    f_int = (3200 >> (15 - (sec["rate_code"].astype(np.int64) & 0x0F)))  # integer rate (§5.2)
    idx = sec["timestamp_offset"].astype(np.int64) + ((f15 << 1) * f_int >> 16)
    t_ns = (secs - tz_s) * _NS + (f15 * _NS + 16384) // 32768
    return idx, t_ns, ok


def interpolate_times(j0: int, j1: int, g: np.ndarray, t_rel: np.ndarray,
                      slope_first: float, slope_last: float, closed: bool) -> np.ndarray:
    """Times (float64 ns relative to the segment origin) of segment samples j0..j1-1.

    ``g``/``t_rel``: the segment's accepted anchors (strictly increasing indices) covering the
    range. Between anchors: linear. Before the first anchor: extrapolate with ``slope_first``
    (ns per sample); after the last (only allowed when the segment is ``closed``):
    ``slope_last``. Results for a sample depend only on its bracketing anchors, so they do
    not depend on how the file was cut into batches.
    """
    x = np.arange(j0, j1, dtype=np.float64)
    if g.shape[0] == 1:
        return t_rel[0] + (x - g[0]) * slope_first
    out = np.interp(x, g.astype(np.float64), t_rel)
    if j0 < g[0]:
        m = int(min(g[0], j1) - j0)
        out[:m] = t_rel[0] + (x[:m] - g[0]) * slope_first
    if closed and j1 - 1 > g[-1]:
        s = int(max(g[-1] + 1, j0) - j0)
        out[s:] = t_rel[-1] + (x[s:] - g[-1]) * slope_last
    return out
