"""Write AX3/AX6 ``.cwa`` files (for the simulator and the tests), vectorised with numpy.

``CwaWriter`` turns per-sample times and integer counts into real sectors: header, packed AX3
(120 samples/sector), unpacked AX3 / AX6 accel-only (80), AX6 gyro+accel (40, order gx gy gz ax
ay az, accel/gyro scale codes in lightScale), sequence ids, events, auxiliary channels and
correct checksums (../shared/specs/cwa-format.md §4-§6). Each sector is anchored at its first
sample: ``timestamp`` = whole second, ``deviceFractional`` = 0x8000 | fraction in 1/32768 s,
``timestampOffset`` = -floor(F16 * f_int / 65536), so a reader following §7.2 puts the anchor
exactly on the sector's first sample and reproduces every sample time to the format's
resolution (1/32768 s at the anchors, linear in between).

Also: ``corrupt_sector`` (break a sector of an existing file: checksum, timestamp, tag, erase)
and ``patch_sector`` (rewrite header fields of a sector and fix its checksum).
"""

from __future__ import annotations

import os
from datetime import datetime, timezone
from typing import BinaryIO, Optional, Union

import numpy as np

from . import constants as C
from .cwa_layout import (SECTOR_DTYPE, TS_ALWAYS, TS_NEVER, build_header, pack_timestamp,
                         pack_timestamps)

_NS = 1_000_000_000
# AX3 packed mode: the firmware drops the low e bits of the 1/256 g counts; e by range (§6.1)
_AX3_PACKED_EXPONENT = {2: 0, 4: 1, 8: 2, 16: 3}
# AX6 accel scale code A: counts per g = 2^(8+A) = 32768 / range (§6.3)
_AX6_ACCEL_CODE = {16: 3, 8: 4, 4: 5, 2: 6}
_GYRO_CODE = {2000: 2, 1000: 3, 500: 4, 250: 5, 125: 6}  # range = 8000 / 2^G dps (§6.3)
_AUX = ("temperature_raw", "light_raw", "battery_raw", "events")


def _time_field(value) -> int:
    """Header logging start/end: None, int ns (device clock) or datetime -> packed u32."""
    if value is None:
        raise TypeError
    if isinstance(value, datetime):
        if value.tzinfo is not None:
            value = value.astimezone(timezone.utc).replace(tzinfo=None)
        secs = int((value - datetime(1970, 1, 1)).total_seconds())
    else:
        secs = int(value) // _NS
    return pack_timestamp(secs)


class CwaWriter:
    """Write a ``.cwa`` recording; see the module docstring.

    ``write(time_ns, accel_counts, gyro_counts=..., temperature_raw=..., light_raw=...,
    battery_raw=..., events=...)`` appends samples; times are per-sample device-clock int64 ns
    (taken as UTC), counts are integers in the file's units: 1/256 g for AX3 (packed mode keeps
    only multiples of 2^e, e = 0..3 for ±2..16 g, and saturates at the 10-bit range, as the
    firmware does), ``accel_counts_per_g`` for AX6, gyro in ``gyro_dps_per_count`` units.
    Auxiliary values are scalars or per-sample arrays; a sector stores the value at its first
    sample (events: the OR over its samples). Samples are buffered until a sector is full;
    ``close()`` flushes a final short sector, ``restart()`` ends the current logging run.

    Options: ``packed`` (default: AX3 without gyro -> packed 0x30; False -> unpacked 0x32),
    ``gyro_range_dps`` (AX6 only: 125..2000 -> 6-axis 0x62 sectors), ``firmware`` (default 48 for
    AX3, 56 for AX6), ``metadata`` (short keys like "_sc" or expanded names like "Subject Code"),
    ``logging_start`` / ``logging_end`` (None = always / never; int ns or datetime),
    ``fractional=False`` writes old-firmware sectors without the fractional timestamp (anchor at
    the whole second, good to about one sample). ``path_or_fileobj`` may be an open binary file
    (e.g. ``gzip.open(..., "wb")``); it is flushed, not closed. Times must increase strictly.
    Attributes: ``accel_counts_per_g``, ``gyro_dps_per_count``, ``samples_per_sector``,
    ``exponent`` (packed), ``sectors_written``.
    """

    def __init__(self, path_or_fileobj: Union[str, os.PathLike, BinaryIO], *,
                 device_type: str = "AX3", device_id: int = 12345, session_id: int = 0,
                 rate_hz: float = 100.0, range_g: int = 8, packed: Optional[bool] = None,
                 gyro_range_dps: Optional[float] = None, firmware: Optional[int] = None,
                 metadata: Optional[dict] = None, logging_start=None, logging_end=None,
                 fractional: bool = True):
        device_type = device_type.upper()
        if device_type not in ("AX3", "AX6"):
            raise ValueError(f"device_type must be 'AX3' or 'AX6', got {device_type!r}")
        if packed is None:
            packed = device_type == "AX3" and gyro_range_dps is None
        if gyro_range_dps is not None and device_type != "AX6":
            raise ValueError("a gyroscope range needs device_type='AX6'")
        if packed and device_type != "AX3":
            raise ValueError("packed sectors are written for the AX3 only (cwa-format.md §6.1)")
        self.device_type = device_type
        self.device_id = int(device_id)
        self.session_id = int(session_id)
        self.rate_hz = float(rate_hz)
        self.range_g = int(range_g)
        self.rate_code = C.cwa_rate_code(self.rate_hz, self.range_g)
        self._f_int = int(C.cwa_rate_hz(self.rate_code))  # firmware's integer rate (§5.2)
        self.packed = bool(packed)
        self.fractional = bool(fractional)
        self.firmware = int(firmware if firmware is not None else (48 if device_type == "AX3" else 56))
        self.gyro_range_dps = None
        gyro_code = 0
        if gyro_range_dps is not None:
            code = _GYRO_CODE.get(int(gyro_range_dps), None) if float(gyro_range_dps).is_integer() else None
            if code is None:
                raise ValueError(f"gyro range must be one of {sorted(_GYRO_CODE)} dps, got {gyro_range_dps}")
            gyro_code = code
            self.gyro_range_dps = float(gyro_range_dps)
        if device_type == "AX3":
            accel_code = 0
            self.num_axes_bps = 0x30 if self.packed else 0x32
        else:
            accel_code = _AX6_ACCEL_CODE[self.range_g]
            self.num_axes_bps = 0x62 if self.gyro_range_dps else 0x32
        self.channels = self.num_axes_bps >> 4
        self.samples_per_sector = {0x30: 120, 0x32: 80, 0x62: 40}[self.num_axes_bps]
        self.exponent = _AX3_PACKED_EXPONENT[self.range_g] if self.packed else 0
        self.accel_counts_per_g = C.cwa_accel_counts_per_g(accel_code)
        self.gyro_dps_per_count = (self.gyro_range_dps / 32768.0) if self.gyro_range_dps else None
        self._light_scale_hi = (accel_code << 13) | (gyro_code << 10)
        self.sectors_written = 0
        self._sequence = 0
        self._resume = True  # the first sector after (re)start carries the RESUME event
        self._last_time: Optional[int] = None
        self._pending: Optional[dict] = None
        self._closed = False

        self._f: BinaryIO
        if isinstance(path_or_fileobj, (str, os.PathLike)):
            self._f = open(path_or_fileobj, "wb")
            self._own = True
        else:
            self._f = path_or_fileobj
            self._own = False
        start = TS_ALWAYS if logging_start is None else _time_field(logging_start)
        end = TS_NEVER if logging_end is None else _time_field(logging_end)
        hw = 0x64 if device_type == "AX6" else 0x17
        sensor_config = gyro_code if device_type == "AX6" else 0x00
        self._f.write(build_header(
            hardware_type=hw, device_id=self.device_id, session_id=self.session_id,
            rate_code=self.rate_code, firmware=self.firmware, sensor_config=sensor_config,
            logging_start=start, logging_end=end, last_change=start if start != TS_NEVER else 0,
            metadata=metadata))
        self._f.flush()

    # ------------------------------------------------------------------ public API
    def write(self, time_ns, accel_counts, *, gyro_counts=None, temperature_raw=256,
              light_raw=0, battery_raw=190, events=0) -> None:
        """Append samples (see the class docstring)."""
        if self._closed:
            raise ValueError("write() on a closed CwaWriter")
        t = np.asarray(time_ns, dtype=np.int64).reshape(-1)
        n = t.shape[0]
        a = np.asarray(accel_counts)
        if a.shape != (n, 3):
            raise ValueError(f"accel_counts must have shape ({n}, 3), got {a.shape}")
        g = None
        if self.num_axes_bps == 0x62:
            if gyro_counts is None:
                raise ValueError("this AX6 file has gyro sectors: gyro_counts is required")
            g = np.asarray(gyro_counts)
            if g.shape != (n, 3):
                raise ValueError(f"gyro_counts must have shape ({n}, 3), got {g.shape}")
        elif gyro_counts is not None:
            raise ValueError("gyro_counts given but the writer has no gyro (gyro_range_dps=None)")
        aux = {}
        for name, v in zip(_AUX, (temperature_raw, light_raw, battery_raw, events)):
            v = np.asarray(v)
            if v.ndim and v.shape != (n,):
                raise ValueError(f"{name} must be a scalar or have shape ({n},), got {v.shape}")
            aux[name] = v
        if n == 0:
            return
        if (self._last_time is not None and t[0] <= self._last_time) or (n > 1 and not (t[1:] > t[:-1]).all()):
            raise ValueError("sample times must increase strictly (also across write() calls and restarts)")
        self._last_time = int(t[-1])
        spp = self.samples_per_sector
        i = 0
        if self._pending is not None:
            p = self._pending
            take = min(spp - p["time"].shape[0], n)
            part = self._chunk(t, a, g, aux, 0, take)
            self._pending = {k: np.concatenate([p[k], part[k]]) for k in p if p[k] is not None}
            self._pending.setdefault("gyro", None)
            i = take
            if self._pending["time"].shape[0] == spp:
                self._flush_pending()
        full = (n - i) // spp
        if full:
            j = i + full * spp
            self._encode(t[i:j], a[i:j], None if g is None else g[i:j],
                         self._per_sector(aux, i, j, spp), np.full(full, spp))
            i = j
        if i < n:
            self._pending = self._chunk(t, a, g, aux, i, n)
        self._f.flush()

    def restart(self) -> None:
        """End the logging run: flush a short sector; the next sector has sequence id 0 + RESUME."""
        self._flush_pending()
        self._sequence = 0
        self._resume = True
        self._f.flush()

    def close(self) -> None:
        if self._closed:
            return
        self._flush_pending()
        self._f.flush()
        if self._own:
            self._f.close()
        self._closed = True

    def __enter__(self) -> "CwaWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------ internals
    @staticmethod
    def _chunk(t, a, g, aux, i, j) -> dict:
        d = {"time": t[i:j].copy(), "accel": np.asarray(a[i:j]).copy(),
             "gyro": None if g is None else np.asarray(g[i:j]).copy()}
        for k, v in aux.items():
            d[k] = (v[i:j] if v.ndim else np.full(j - i, v)).copy()
        return d

    @staticmethod
    def _per_sector(aux, i, j, spp) -> dict:
        k = (j - i) // spp
        out = {}
        for name, v in aux.items():
            if not v.ndim:
                out[name] = np.full(k, v)
            elif name == "events":
                out[name] = np.bitwise_or.reduce(v[i:j].astype(np.uint8).reshape(k, spp), axis=1)
            else:
                out[name] = v[i:j:spp]
        return out

    def _flush_pending(self) -> None:
        p = self._pending
        if p is None:
            return
        self._pending = None
        n = p["time"].shape[0]
        per = {name: (np.bitwise_or.reduce(p[name].astype(np.uint8), keepdims=True)
                      if name == "events" else p[name][:1]) for name in _AUX}
        self._encode(p["time"], p["accel"], p["gyro"], per, np.array([n]))

    def _encode(self, t, a, g, per: dict, counts: np.ndarray) -> None:
        """Encode k sectors (all full except possibly a last short one) and write them."""
        k = counts.shape[0]
        spp = self.samples_per_sector
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
        first = t[starts]

        sec = np.zeros(k, SECTOR_DTYPE)
        sec["tag"] = C.CWA_TAG_DATA
        sec["length"] = C.CWA_DATA_PACKET_LENGTH
        whole = first // _NS
        rem = first - whole * _NS
        frac15 = (rem * 32768 + _NS // 2) // _NS  # nearest 1/32768 s
        carry = frac15 >= 32768
        whole = whole + carry
        frac15 = np.where(carry, 0, frac15)
        if self.fractional:
            f16 = frac15 << 1
            sec["device_fractional"] = 0x8000 | frac15
            sec["timestamp_offset"] = -((f16 * self._f_int) // 65536)
        else:
            # old firmware: no fraction; offset = index of the whole second (nearest sample)
            sec["device_fractional"] = self.device_id & 0x7FFF
            frac_s = frac15 / 32768.0
            sec["timestamp_offset"] = -np.rint(frac_s * self.rate_hz).astype(np.int64)
        sec["timestamp"] = pack_timestamps(whole)
        sec["session_id"] = self.session_id
        sec["sequence_id"] = self._sequence + np.arange(k, dtype=np.int64)
        light = np.asarray(per["light_raw"], dtype=np.int64) & 0x3FF
        sec["light_scale"] = self._light_scale_hi | light
        sec["temperature"] = np.asarray(per["temperature_raw"], dtype=np.int64) & 0x3FF
        ev = np.asarray(per["events"], dtype=np.uint8).copy()
        if self._resume:
            ev[0] |= C.CWA_EVENT_RESUME
            self._resume = False
        sec["events"] = ev
        sec["battery"] = np.clip(np.asarray(per["battery_raw"], dtype=np.int64), 0, 255)
        sec["rate_code"] = self.rate_code
        sec["num_axes_bps"] = self.num_axes_bps
        sec["sample_count"] = counts

        raw = sec.view(np.uint8).reshape(k, C.CWA_SECTOR_BYTES)
        n = t.shape[0]
        full_n = k * spp
        if self.packed:
            e = self.exponent
            q = np.clip(np.asarray(a, dtype=np.int32) >> e, -512, 511) & 0x3FF
            v = np.zeros(full_n, np.uint32)
            v[:n] = (q[:, 0].astype(np.uint32) | (q[:, 1].astype(np.uint32) << 10)
                     | (q[:, 2].astype(np.uint32) << 20) | np.uint32(e << 30))
            raw[:, 30:510] = v.view(np.uint8).reshape(k, 480)
        else:
            ch = self.channels
            s = np.zeros((full_n, ch), "<i2")
            if ch == 6:
                s[:n, :3] = _to_i16(g, "gyro")
                s[:n, 3:] = _to_i16(a, "accel")
            else:
                s[:n] = _to_i16(a, "accel")
            raw[:, 30:30 + spp * ch * 2] = s.view(np.uint8).reshape(k, spp * ch * 2)
        words = raw.view("<u2").reshape(k, 256)
        words[:, 255] = 0
        words[:, 255] = -words.sum(axis=1, dtype=np.uint16)  # word sum becomes 0 (§5.5)
        self._f.write(raw.tobytes())
        self._sequence += k
        self.sectors_written += k


def _to_i16(x, name) -> np.ndarray:
    x = np.asarray(x)
    if x.dtype != np.int16:
        if np.issubdtype(x.dtype, np.integer) is False:
            x = np.rint(x)
        if x.size and (x.min() < -32768 or x.max() > 32767):
            raise ValueError(f"{name} counts exceed the int16 range")
        x = x.astype(np.int16)
    return x


# ----------------------------------------------------------------------------- file surgery
def _sector_offset(index: int) -> int:
    return C.CWA_HEADER_BYTES + int(index) * C.CWA_SECTOR_BYTES


def corrupt_sector(path, index: int, how: str = "checksum") -> None:
    """Damage data sector ``index`` of an existing file in place.

    how: "checksum" flips bits of one sample byte (checksum fails); "timestamp" overwrites
    bytes 14-21 like the GGIRread corrupt fixture (timestamp zeroed, checksum fails); "tag"
    overwrites the "AX" tag; "erase" fills the sector with 0xFF (an erased flash sector).
    """
    off = _sector_offset(index)
    with open(path, "r+b") as f:
        f.seek(off)
        sec = bytearray(f.read(C.CWA_SECTOR_BYTES))
        if len(sec) != C.CWA_SECTOR_BYTES:
            raise IndexError(f"{path}: no data sector {index}")
        if how == "checksum":
            sec[100] ^= 0xA5
        elif how == "timestamp":
            sec[14:22] = bytes.fromhex("00000000" "00e06f40")
        elif how == "tag":
            sec[0:2] = b"XX"
        elif how == "erase":
            sec[:] = b"\xff" * C.CWA_SECTOR_BYTES
        else:
            raise ValueError(f"unknown corruption {how!r}")
        f.seek(off)
        f.write(sec)


def read_sector(path, index: int) -> np.ndarray:
    """Data sector ``index`` as a one-element SECTOR_DTYPE array (a copy)."""
    with open(path, "rb") as f:
        f.seek(_sector_offset(index))
        b = f.read(C.CWA_SECTOR_BYTES)
    if len(b) != C.CWA_SECTOR_BYTES:
        raise IndexError(f"{path}: no data sector {index}")
    return np.frombuffer(b, SECTOR_DTYPE).copy()


def fix_checksum(sector: np.ndarray) -> np.ndarray:
    """Recompute the checksum of SECTOR_DTYPE sector(s) in place (and return them)."""
    words = sector.view("<u2").reshape(-1, 256)
    words[:, 255] = 0
    words[:, 255] = -words.sum(axis=1, dtype=np.uint16)
    return sector


def patch_sector(path, index: int, **fields) -> None:
    """Set SECTOR_DTYPE fields (e.g. sequence_id=0, session_id=7) of data sector ``index`` of an
    existing file and recompute its checksum, so the change is a valid (not corrupt) sector."""
    sec = read_sector(path, index)
    for k, v in fields.items():
        sec[k] = v
    fix_checksum(sec)
    with open(path, "r+b") as f:
        f.seek(_sector_offset(index))
        f.write(sec.tobytes())
