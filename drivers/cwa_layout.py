"""The AX3/AX6 ``.cwa`` byte layout: structured dtypes, packed timestamps, header and metadata.

Pure encode/decode helpers shared by the reader (``cwa_reader``) and the writer
(``cwa_writer``); no file I/O here. Layout and field meanings: ../shared/specs/cwa-format.md
(§3 timestamps, §4 header, §4.1 metadata text, §5 data sector). Constants live in
``drivers/constants.py``.
"""

from __future__ import annotations

import urllib.parse
from typing import Optional

import numpy as np

from stillpoint.engine.core.times import iso_utc, parse_offset

from . import constants as C

# ----------------------------------------------------------------------------- data sector (§5)
SECTOR_DTYPE = np.dtype([
    ("tag", "<u2"),  # 0  "AX" = 0x5841
    ("length", "<u2"),  # 2  508
    ("device_fractional", "<u2"),  # 4  bit 15: fraction (1/32768 s) of timestamp; else device id
    ("session_id", "<u4"),  # 6
    ("sequence_id", "<u4"),  # 10
    ("timestamp", "<u4"),  # 14 packed date/time (§3)
    ("light_scale", "<u2"),  # 18 A (15..13), G (12..10), light (9..0)
    ("temperature", "<u2"),  # 20 low 10 bits
    ("events", "u1"),  # 22
    ("battery", "u1"),  # 23
    ("rate_code", "u1"),  # 24
    ("num_axes_bps", "u1"),  # 25
    ("timestamp_offset", "<i2"),  # 26
    ("sample_count", "<u2"),  # 28
    ("data", "V480"),  # 30
    ("checksum", "<u2"),  # 510
])
assert SECTOR_DTYPE.itemsize == C.CWA_SECTOR_BYTES

# numAxesBPS -> (channels, bytes per sample, packed) for the formats we decode (§5.1, §5.3)
FORMATS = {
    0x30: (3, 4, True),  # AX3 packed 3 x 10 bit + exponent
    0x32: (3, 6, False),  # AX3 unpacked / AX6 accel-only
    0x62: (6, 12, False),  # AX6 gyro + accel (gx gy gz ax ay az)
}

# short metadata names -> expanded names (OmGui convention, §4.1)
METADATA_NAMES = {
    "_c": "Study Centre", "_s": "Study Code", "_i": "Investigator", "_x": "Exercise Code",
    "_v": "Volunteer Num", "_p": "Body Location", "_so": "Setup Operator", "_n": "Notes",
    "_b": "Start time", "_e": "End time", "_ro": "Recovery Operator", "_r": "Retrieval Time",
    "_co": "Comments", "_sc": "Subject Code", "_se": "Sex", "_h": "Height", "_w": "Weight",
    "_ha": "Handedness", "_sn": "Subject Notes",
}
METADATA_SHORT = {v: k for k, v in METADATA_NAMES.items()}

TS_ALWAYS = 0x00000000  # header start/stop: "infinitely early" (§3)
TS_NEVER = 0xFFFFFFFF  # header start/stop: "infinitely late" (§3)

# Days before the 1st of each month (non-leap), for vectorised timestamp decoding.
_CUM_DAYS = np.array([0, 0, 31, 59, 90, 120, 151, 181, 212, 243, 273, 304, 334], np.int64)
_DAYS_IN_MONTH = np.array([0, 31, 29, 31, 30, 31, 30, 31, 31, 30, 31, 30, 31], np.int64)


# ----------------------------------------------------------------------------- timestamps (§3)
def unpack_timestamps(ts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Packed u32 timestamps -> (seconds since 1970 as naive/UTC int64, valid mask).

    Invalid: 0, 0xFFFFFFFF, month not 1..12, day 0 or past the month's end, hour > 23,
    minute or second > 59. Invalid entries get seconds 0.
    """
    ts = np.asarray(ts, dtype=np.uint32).astype(np.int64)
    year = 2000 + ((ts >> 26) & 0x3F)
    month = (ts >> 22) & 0x0F
    day = (ts >> 17) & 0x1F
    hour = (ts >> 12) & 0x1F
    minute = (ts >> 6) & 0x3F
    second = ts & 0x3F
    leap = (year % 4) == 0  # 2000..2063: every 4th year is leap (2000 included)
    m = np.clip(month, 0, 12)
    dim = _DAYS_IN_MONTH[m] - ((m == 2) & ~leap)
    valid = ((ts != TS_ALWAYS) & (ts != TS_NEVER) & (month >= 1) & (month <= 12) & (day >= 1)
             & (day <= dim) & (hour <= 23) & (minute <= 59) & (second <= 59))
    y = year - 2000
    # days from 1970-01-01 to 2000-01-01 = 10957; leap days in [2000, year) = ceil(y / 4)
    days = 10957 + y * 365 + (y + 3) // 4 + _CUM_DAYS[m] + ((m > 2) & leap) + day - 1
    secs = ((days * 24 + hour) * 60 + minute) * 60 + second
    return np.where(valid, secs, 0), valid


def unpack_timestamp(value: int) -> Optional[int]:
    """One packed timestamp -> seconds since 1970 (naive, taken as UTC), or None if invalid."""
    s, ok = unpack_timestamps(np.array([value], np.uint32))
    return int(s[0]) if ok[0] else None


def pack_timestamps(seconds) -> np.ndarray:
    """Seconds since 1970 (naive/UTC, whole, years 2000..2063) -> packed u32 timestamps."""
    s = np.asarray(seconds, dtype=np.int64)
    if s.size and (s.min() < 946684800 or s.max() >= 2966371200):
        raise ValueError("CWA timestamps cover 2000-01-01 .. 2063-12-31 only")
    d = s.astype("datetime64[s]")
    year = d.astype("datetime64[Y]").astype(np.int64) + 1970
    month = d.astype("datetime64[M]").astype(np.int64) % 12 + 1
    day = (d.astype("datetime64[D]") - d.astype("datetime64[M]")).astype(np.int64) + 1
    sod = (d - d.astype("datetime64[D]")).astype(np.int64)
    hour, minute, second = sod // 3600, (sod // 60) % 60, sod % 60
    packed = (((year - 2000) << 26) | (month << 22) | (day << 17) | (hour << 12) | (minute << 6)
              | second)
    return packed.astype(np.uint32)


def pack_timestamp(seconds: int) -> int:
    return int(pack_timestamps(np.array([seconds]))[0])


# ----------------------------------------------------------------------------- time zone
def parse_timezone(tz) -> int:
    """Device clock offset from UTC in seconds: int seconds, "UTC", "Z", "+01:00", "-0530"."""
    if tz is None:
        return 0
    if isinstance(tz, (int, np.integer)) and not isinstance(tz, bool):
        return int(tz)
    if isinstance(tz, float) and tz.is_integer():
        return int(tz)
    if isinstance(tz, str):
        if not tz.strip():
            return 0
        try:
            return parse_offset(tz)
        except ValueError:
            pass
    raise ValueError(f"time zone must be seconds or like '+01:00' / 'UTC', got {tz!r}")


# ----------------------------------------------------------------------------- metadata (§4.1)
def decode_metadata(raw: bytes) -> tuple[dict[str, str], list[tuple[str, str]]]:
    """Annotation bytes -> (expanded-name dict, raw (short key, value) items)."""
    text = raw.rstrip(b" \x00\xff")
    items: list[tuple[str, str]] = []
    if not text:
        return {}, items
    for part in text.split(b"&"):
        if not part:
            continue
        name, _, value = part.partition(b"=")
        n = urllib.parse.unquote_plus(name.decode("latin-1"), encoding="utf-8", errors="replace")
        v = urllib.parse.unquote_plus(value.decode("latin-1"), encoding="utf-8", errors="replace")
        items.append((n, v))
    expanded = {METADATA_NAMES.get(k, k): v for k, v in items}
    return expanded, items


def encode_metadata(meta: Optional[dict], size: int = 448) -> bytes:
    """Metadata dict (short keys like "_sc" or expanded names) -> padded annotation bytes."""
    if not meta:
        return b" " * size
    parts = []
    for k, v in meta.items():
        key = METADATA_SHORT.get(k, k)
        parts.append(urllib.parse.quote_plus(str(key), safe="_") + "="
                     + urllib.parse.quote_plus(str(v)))
    text = "&".join(parts).encode("ascii")
    if len(text) > size:
        raise ValueError(f"metadata text is {len(text)} bytes; a CWA header holds {size}")
    return text + b" " * (size - len(text))


# ----------------------------------------------------------------------------- header (§4)
def device_type_of(hardware_type: int) -> str:
    if hardware_type in C.CWA_HW_AX6:
        return "AX6"
    if hardware_type in C.CWA_HW_AX3:
        return "AX3"
    return "unknown"


def _ts_field(value: int, tz_s: int) -> Optional[str]:
    if value == TS_ALWAYS:
        return "always"
    if value == TS_NEVER:
        return "never"
    s = unpack_timestamp(value)
    if s is None:
        return None
    return iso_utc((s - tz_s) * 10**9)


def parse_header(buf: bytes, tz_s: int = 0) -> dict:
    """Decode the 1024-byte header into a dict of fields (raises ValueError if not a header)."""
    if len(buf) < C.CWA_HEADER_BYTES:
        raise ValueError(f"header needs {C.CWA_HEADER_BYTES} bytes, got {len(buf)}")
    tag, length = int.from_bytes(buf[0:2], "little"), int.from_bytes(buf[2:4], "little")
    if tag != C.CWA_TAG_HEADER:
        raise ValueError(f"not a CWA header: first bytes are {bytes(buf[:8])!r} (expected 'MD')")
    u16 = lambda o: int.from_bytes(buf[o:o + 2], "little")  # noqa: E731
    u32 = lambda o: int.from_bytes(buf[o:o + 4], "little")  # noqa: E731
    hw = buf[4]
    upper = u16(11)
    device_id = u16(5) | ((0 if upper == 0xFFFF else upper) << 16)
    sensor_config = buf[35]
    gyro_range = None
    if sensor_config not in (0x00, 0xFF):
        n = sensor_config & 0x0F
        gyro_range = 8000.0 / (1 << n) if n else None
    rate_code = buf[36]
    tzone = int.from_bytes(buf[42:44], "little", signed=True)
    meta, items = decode_metadata(bytes(buf[64:512]))
    meta2, items2 = decode_metadata(bytes(buf[512:1024]))
    flash = buf[26]
    return {
        "packet_length": length,
        "hardware_type": hw,
        "device_type": device_type_of(hw),
        "device_id": device_id,
        "device_id_low": u16(5),
        "upper_device_id": upper,
        "session_id": u32(7),
        "logging_start_raw": u32(13),
        "logging_end_raw": u32(17),
        "logging_start": _ts_field(u32(13), tz_s),
        "logging_end": _ts_field(u32(17), tz_s),
        "logging_capacity": u32(21),
        "flash_led": 0 if flash == 0xFF else flash,
        "sensor_config": sensor_config,
        "gyro_range_dps": gyro_range,
        "magnetometer_enabled": sensor_config not in (0x00, 0xFF) and (sensor_config >> 4) != 0,
        "rate_code": rate_code,
        "sample_rate_hz": C.cwa_rate_hz(rate_code),
        "accel_range_g": C.cwa_range_g(rate_code),
        "low_power": bool(rate_code & 0x10),
        "last_change": _ts_field(u32(37), tz_s),
        "firmware_revision": buf[41],
        "time_zone_field": tzone,
        "annotation": bytes(buf[64:512]).rstrip(b" \x00\xff").decode("latin-1"),
        "annotation_items": items,
        "device_metadata": meta2,
        "device_metadata_items": items2,
        "metadata": meta,
    }


def build_header(*, hardware_type: int, device_id: int, session_id: int, rate_code: int,
                 firmware: int, sensor_config: int = 0x00, logging_start: int = TS_ALWAYS,
                 logging_end: int = TS_NEVER, last_change: int = 0,
                 metadata: Optional[dict] = None, upper_id_word: bool = True) -> bytes:
    """Encode a 1024-byte header (inverse of parse_header for the fields a writer sets).

    ``upper_id_word=False`` writes the id as AX3 firmware V50 does: only its low 16 bits at
    offset 5, bytes 11-12 left 0xFFFF (Firmware/AX3/Firmware/src/Logger.c 444-448); the AX6
    writes both words (Firmware/AX6/Firmware/src/Logger.c 538-540)."""
    if not 0 <= device_id <= 0xFFFFFFFF:
        raise ValueError(f"device id must fit 32 bits, got {device_id}")
    b = bytearray(b"\xff" * C.CWA_HEADER_BYTES)
    b[0:2] = C.CWA_TAG_HEADER.to_bytes(2, "little")
    b[2:4] = (C.CWA_HEADER_BYTES - 4).to_bytes(2, "little")
    b[4] = hardware_type
    b[5:7] = (device_id & 0xFFFF).to_bytes(2, "little")
    b[7:11] = int(session_id).to_bytes(4, "little")
    if upper_id_word:
        b[11:13] = (device_id >> 16).to_bytes(2, "little")
    b[13:17] = int(logging_start).to_bytes(4, "little")
    b[17:21] = int(logging_end).to_bytes(4, "little")
    b[21:25] = (0).to_bytes(4, "little")
    b[25] = 0
    b[26] = 0
    b[35] = sensor_config
    b[36] = rate_code
    b[37:41] = int(last_change).to_bytes(4, "little")
    b[41] = firmware
    b[42:44] = (-1).to_bytes(2, "little", signed=True)
    b[64:512] = encode_metadata(metadata)
    return bytes(b)


def sector_checksums(sectors: np.ndarray) -> np.ndarray:
    """(k, 512) uint8 or SECTOR_DTYPE array -> (k,) uint16 word sums (valid sector: 0). §5.5"""
    words = np.ascontiguousarray(sectors).view("<u2").reshape(-1, 256)
    return words.sum(axis=1, dtype=np.uint16)
