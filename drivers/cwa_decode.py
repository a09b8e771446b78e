"""Vectorised decoding of a batch of ``.cwa`` data sectors (pure functions, no I/O, no state).

* ``classify``  — why each sector is unusable (tag, length, checksum, format) or 0 if valid.
* ``decode_samples`` — packed (3 x 10 bit + exponent) and unpacked int16 samples to counts.
* ``sector_anchors`` — each sector's timing anchor (sample index, UTC ns) per cwa-format.md §7.2.
* ``interpolate_times`` — piecewise-linear sample times through a segment's anchors.
* ``SampleClock`` — the same times for chosen samples only, and where given times fall.

All work on whole batches of sectors with numpy; no per-sample Python loops.
"""

from __future__ import annotations

from typing import Literal

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


def decode_samples(sec: np.ndarray, fmt: int, counts: np.ndarray, order: str = "C"):
    """Samples of sectors that all share format ``fmt`` -> (accel (n,3) int16, gyro (n,3) | None).

    ``counts`` (k,) valid samples per sector (already clamped to the sector's capacity).
    ``order="F"``: the arrays are column-major (each axis contiguous).
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
        layout: Literal["C", "F"] = "F" if order == "F" else "C"
        accel = np.empty((n, 3), np.int16, order=layout)
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
        layout6: Literal["C", "F"] = "F" if order == "F" else "C"
        return np.array(s[:, 3:6], order=layout6), np.array(s[:, 0:3], order=layout6)
    if order == "F":
        return np.array(s, order="F"), None
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


def anchor_times(x: np.ndarray, g: np.ndarray, t_rel: np.ndarray, slope_first: float,
                 slope_last: float, closed: bool) -> np.ndarray:
    """:func:`interpolate_times` at the segment sample indices ``x`` (float64, any order): the
    same arithmetic per sample, so any subset of a range gets the same bits as the range.
    ``g`` may be given as float64 already (the same integers)."""
    if g.shape[0] == 1:
        return t_rel[0] + (x - g[0]) * slope_first
    out = np.interp(x, g if g.dtype == np.float64 else g.astype(np.float64), t_rel)
    before = x < g[0]
    if before.any():
        out[before] = t_rel[0] + (x[before] - g[0]) * slope_first
    if closed:
        after = x > g[-1]
        if after.any():
            out[after] = t_rel[-1] + (x[after] - g[-1]) * slope_last
    return out


class SampleClock:
    """The times of ``n`` consecutive samples of one segment (segment indices ``j0`` onwards),
    held as the segment's anchors: any sample's time on request, the same int64 ns the reader
    gives per sample (:func:`interpolate_times`, rounded to the ns, plus the origin).

    For passes that need the times of a few samples only (where each 10 s window starts): the
    per-sample times of a whole recording cost a fifth of its decoding.
    """

    __slots__ = ("j0", "n", "g", "t_rel", "slope_first", "slope_last", "closed", "origin")

    def __init__(self, j0: int, n: int, g: np.ndarray, t_rel: np.ndarray, slope_first: float,
                 slope_last: float, closed: bool, origin: int):
        self.j0, self.n = int(j0), int(n)
        self.g = np.asarray(g).astype(np.float64)  # anchor sample indices (exact integers)
        self.t_rel = t_rel
        self.slope_first, self.slope_last = float(slope_first), float(slope_last)
        self.closed, self.origin = bool(closed), int(origin)

    def at(self, rows) -> np.ndarray:
        """int64 ns of the samples at ``rows`` (0 .. n-1)."""
        rows = np.asarray(rows, np.int64)
        x = (rows.reshape(-1) + self.j0).astype(np.float64)
        rel = anchor_times(x, self.g, self.t_rel, self.slope_first, self.slope_last, self.closed)
        np.rint(rel, out=rel)
        t = rel.astype(np.int64)
        t += self.origin
        return t.reshape(rows.shape)

    def times(self, start: int = 0, stop=None) -> np.ndarray:
        """int64 ns of rows ``start .. stop-1`` (every sample by default)."""
        stop = self.n if stop is None else stop
        return self.at(np.arange(start, stop, dtype=np.int64))

    def search(self, edges) -> np.ndarray:
        """For each time in ``edges`` (int64 ns): the first row whose time is at or after it
        (``n`` if none), as ``np.searchsorted(self.times(), edges, side="left")`` gives.

        The row is first estimated by inverting the anchors' line, then moved until its time is
        at or after the edge and the previous row's is before it; the times never decrease
        along the rows, so that row is the searchsorted one. An edge not settled within a few
        rows is looked up in the full times.
        """
        e = np.asarray(edges, np.int64)
        if e.size == 0 or self.n == 0:
            return np.zeros(e.shape, np.int64)
        rel = (e - self.origin).astype(np.float64)
        g = self.g
        x = np.interp(rel, self.t_rel, g)
        if g.shape[0] == 1:
            x = g[0] + (rel - self.t_rel[0]) / self.slope_first
        else:
            lo = rel < self.t_rel[0]
            x[lo] = g[0] + (rel[lo] - self.t_rel[0]) / self.slope_first
            hi = rel > self.t_rel[-1]
            x[hi] = g[-1] + (rel[hi] - self.t_rel[-1]) / self.slope_last
        r = np.clip(np.ceil(x) - self.j0, 0, self.n).astype(np.int64)
        n = self.n
        k = e.shape[0]
        for _ in range(4):
            t = self.at(np.concatenate([np.minimum(r, n - 1), np.maximum(r - 1, 0)]))
            up = (r < n) & (t[:k] < e)
            down = (r > 0) & (t[k:] >= e)
            if not (up.any() or down.any()):
                return r
            r += up
            r -= down
        return np.searchsorted(self.times(), e, side="left").astype(np.int64)
