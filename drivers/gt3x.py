"""ActiGraph ``.gt3x`` reader: a streaming Source of Blocks (format constants: drivers/constants.py [GT3X]).

A ``.gt3x`` is a zip. Two layouts exist:

* **log.bin** (GT3X+ firmware >= 3, wGT3X+, wGT3X-BT, GT9X Link, ...): ``info.txt`` and ``log.bin``,
  a sequence of records ``0x1E, type, u32 time, u16 size, payload, checksum``. One ACTIVITY
  (12-bit, YXZ) or ACTIVITY2 (int16, XYZ) record holds one second of samples. EVENT records mark
  *idle sleep* (the device stops writing samples while it is still: 0x08 enter, 0x09 exit);
  BATTERY and LUX records give the battery voltage and light; PARAMETERS the scale; a 1-byte
  ACTIVITY record is a USB connection, not samples. SENSOR_SCHEMA/SENSOR_DATA (IMU) and any other
  record are skipped by their size.
* **legacy** (NHANES-era GT3X+/ActiSleep+, firmware <= 2.5.0): ``info.txt``, ``activity.bin`` (a
  continuous 12-bit YXZ stream from ``Start Date``) and ``lux.bin`` (one u16 per second).

What the reader does:

* the zip member is **streamed** (never extracted): ``log.bin``/``activity.bin`` is read in
  chunks of ``CHUNK_BYTES``; a member declaring an implausible size or compression ratio is
  refused (a zip bomb); a zip whose central directory is missing (a truncated download) is read
  from its local file headers, and every complete record before the damage is returned;
* records are parsed with a vectorised fast path over runs of equal-sized ACTIVITY records
  (separator, type, size and checksum checked for all of them at once); any other byte is handled
  one record at a time: a bad checksum or a byte that is not a separator is logged and the reader
  **resynchronises** on the next 0x1E (zero bytes between records are normal and not logged);
* **times**: record times are the device's local clock (whole seconds); ``info.txt`` ``TimeZone``
  gives the zone (the PARAMETERS UTC offset often reads 0) and ``timezone=`` overrides it; sample
  k of a second is at ``k * 1e9 // rate`` ns. Without a zone the clock is read as UTC and the
  outputs say the zone is unknown (engine/timezones.py);
* **idle sleep**: the seconds the device slept are filled with its last sample (as ActiLife,
  pygt3x and GGIR's reader do), flagged ``per_sample["idle_sleep"] = 1``; any other missing second
  (a gap, after a USB connection) starts a new segment; an idle-sleep period still open when the
  log ends lasts up to info.txt's ``Last Sample Time`` (else the log's last record), one open at
  a USB connection up to that record;
* **scale** (LSB/g): ``info.txt`` ``Acceleration Scale``, else the PARAMETERS ``ACCEL_SCALE``,
  else the serial-prefix table; the wGT3X-BT firmware 1.6.0 axis turn is undone.

Accel counts are returned raw (int16, X Y Z) with ``accel_counts_per_g = scale``. Units are
seconds: ``unit_sequence`` is the device-clock second (seconds since 1970, local), ``unit_index``
the ACTIVITY record's index among the file's activity records (-1 for an idle-sleep second),
``light`` the last LUX value (lux, log.bin) or the scaled lux.bin value (legacy), ``battery_v``
the last BATTERY record (volts), ``temperature_c`` NaN (not recorded).
"""

from __future__ import annotations

import json
import re
import struct
import zipfile
import zlib
from pathlib import Path
from typing import Iterator, Optional, Union

import numpy as np

from stillpoint.engine.core.blocks import PER_SAMPLE_IDLE_SLEEP, Block, DeviceInfo, QCEvent, QCReport
from . import constants as C
from .byteio import check_recording_path, is_gzip
from stillpoint.engine.core.errors import CorruptRecordingError, UnsupportedFormatError

__all__ = ["Gt3xReader", "read_header", "unpack12", "PER_SAMPLE_IDLE_SLEEP", "ticks_to_local_ns",
           "scale_round_half_away"]

CHUNK_BYTES = 1 << 20  # bytes of log.bin / activity.bin read at a time
INFO_LIMIT_BYTES = 64 * 1024  # an info.txt longer than this is not an info.txt
PRESCAN_LIMIT_BYTES = 1 << 20  # log.bin read ahead for PARAMETERS/METADATA before the first sample
MAX_MEMBER_BYTES = 64 * 1024**3  # a member larger than this is not a recording (a year at 100 Hz
#                                  ACTIVITY2 is ~19 GB)
BOMB_RATIO = 100.0  # a member over BOMB_MIN_BYTES that expands more than this is refused
BOMB_MIN_BYTES = 64 * 1024**2
MAX_QC_EVENTS = 10_000  # QC events listed per file (as the other readers); the rest are counted
RUN_LOOKAHEAD = 256  # records checked at once on the fast path (other records cut runs anyway)
HEADER_MASK = np.uint64(0xFFFF_0000_0000_FFFF)  # separator, type and size of a record header (LE)
MAX_METADATA_BYTES = 1 << 16  # a METADATA record's JSON kept for the header (longer: skipped)


# ---------------------------------------------------------------------- pure helpers
def unpack12(payload: np.ndarray, n_samples: int) -> np.ndarray:
    """12-bit two's-complement big-endian nibble stream -> (..., n_samples, 3) int16 (stored axis
    order). ``payload``: (..., bytes) uint8. [GT3X] LogRecords/Activity.md 4-13."""
    p = np.asarray(payload, np.uint8)
    lead = p.shape[:-1]
    if n_samples <= 0:
        return np.zeros(lead + (0, 3), np.int16)
    nbytes = p.shape[-1]
    need = ((3 * n_samples + 1) // 2) * 3
    if nbytes < need:
        pad = np.zeros(lead + (need - nbytes,), np.uint8)
        p = np.concatenate([p, pad], axis=-1)
    elif nbytes > need:
        p = p[..., :need]
    # each 3 bytes hold two values: the big-endian int16 at byte 0 shifted right 4 (the top 12
    # bits, sign-extended by the arithmetic shift) and the one at byte 1 with its top nibble
    # shifted out (<< 4, then >> 4)
    flat = np.ascontiguousarray(p).reshape(-1)
    m = flat.shape[0] // 3
    v = np.empty((m, 2), np.int16)
    v[:, 0] = np.ndarray((m,), ">i2", flat, 0, (3,)) >> 4
    v[:, 1] = (np.ndarray((m,), ">i2", flat, 1, (3,)) << 4) >> 4
    vals = v.reshape(lead + (-1,))[..., :3 * n_samples]
    return vals.reshape(lead + (n_samples, 3))


def ticks_to_local_ns(ticks: int) -> int:
    """.NET ticks (100 ns since 0001-01-01) -> ns since 1970 on the same (local) clock."""
    return (int(ticks) - C.GT3X_TICKS_AT_UNIX_EPOCH) * 100


def ssp_decode(value: int) -> float:
    """The PARAMETERS float code (24-bit two's-complement fraction, 8-bit exponent).
    [GT3X] LogRecords/Parameters.md 11, 36-62."""
    value &= 0xFFFFFFFF
    if value == 0x007FFFFF:
        return float("inf")
    if value == 0x00800000:
        return float("-inf")
    exp = (value >> 24) & 0xFF
    if exp & 0x80:
        exp -= 256
    sig = value & 0x00FFFFFF
    if sig & 0x00800000:
        sig -= 1 << 24
    return sig / 8388608.0 * 2.0 ** exp


def scale_round_half_away(counts: np.ndarray, scale: float, decimals: int = C.GT3X_ACTILIFE_DECIMALS):
    """counts / scale rounded half away from zero to ``decimals``, as integer thousandths (for 3
    decimals): what ActiLife writes ([ALF]; [GT3X] Activity.md 21). Done in float64 exactly as
    ``Math.Round(v, 3, MidpointRounding.AwayFromZero)``: v*1000, then away from zero at .5."""
    p = 10.0 ** decimals
    x = np.asarray(counts, np.float64) / float(scale) * p
    return (np.sign(x) * np.floor(np.abs(x) + 0.5)).astype(np.int64)


def _model_of(serial: str, device_type: str) -> str:
    if device_type:
        return device_type
    s = serial.upper()
    for prefix, model in C.GT3X_MODEL_BY_SERIAL_PREFIX:
        if s.startswith(prefix):
            return model
    return ""


def _parse_info(text: str) -> dict:
    """info.txt "Key: Value" lines (a value may hold ':' e.g. TimeZone -05:00:00)."""
    out: dict = {}
    for line in text.splitlines():
        if ":" not in line:
            continue
        k, v = line.split(":", 1)
        k, v = k.strip().strip("\ufeff"), v.strip()
        if k and k not in out:
            out[k] = v
    return out


_TZ_RE = re.compile(r"^\s*(?:UTC|GMT)?\s*([+-])?(\d{1,2}):(\d{2})(?::(\d{2}))?\s*$")


def parse_info_timezone(text: str) -> Optional[int]:
    """info.txt ``TimeZone`` ("-05:00:00", "05:30:00") -> seconds east of UTC; None if unreadable."""
    m = _TZ_RE.match(text or "")
    if not m:
        return None
    sign = -1 if m.group(1) == "-" else 1
    s = int(m.group(2)) * 3600 + int(m.group(3)) * 60 + int(m.group(4) or 0)
    if s > 14 * 3600 + 1800:
        return None
    return sign * s


# ---------------------------------------------------------------------- zip access
class _LocalMember:
    """A zip member read from its local file header (a zip without its central directory: a
    truncated download). Streams stored or deflated data until the member ends or the file does;
    ``damage`` says why it ended early."""

    def __init__(self, path: Path, data_offset: int, method: int, comp_size: Optional[int]):
        self._f = open(path, "rb")
        self._f.seek(data_offset)
        self._left = comp_size  # None: unknown (data descriptor)
        self._d = zlib.decompressobj(-15) if method == 8 else None
        self._pending = b""
        self._eof = False
        self.damage: Optional[str] = None

    def read(self, n: int) -> bytes:
        out = bytearray(self._pending)
        self._pending = b""
        while len(out) < n and not self._eof:
            if self._d is not None and self._d.unconsumed_tail:
                raw = self._d.unconsumed_tail
            else:
                want = 1 << 16 if self._left is None else min(1 << 16, self._left)
                raw = self._f.read(want) if want > 0 else b""
                if self._left is not None:
                    self._left -= len(raw)
                if not raw:
                    self._eof = True
                    if self._d is not None and not self._d.eof:
                        self.damage = "the member's compressed data ends early (truncated zip)"
                    elif self._left:
                        self.damage = "the member's data ends early (truncated zip)"
                    break
            if self._d is None:
                out += raw
                continue
            try:
                out += self._d.decompress(raw, n - len(out))
            except zlib.error as e:
                self.damage = f"damaged compressed data: {e}"
                self._eof = True
                break
            if self._d.eof:
                self._eof = True
        if len(out) > n:
            self._pending = bytes(out[n:])
            del out[n:]
        return bytes(out)

    def close(self) -> None:
        self._f.close()


class _CheckedMember:
    """A zip member stream whose CRC-32 is checked here, not by zipfile: zipfile raises on the read
    that reaches the end and drops that read's data; here every byte is returned and a mismatch
    is reported in ``damage`` (the reader logs it)."""

    def __init__(self, f, crc: int):
        self._f = f
        self._want = crc & 0xFFFFFFFF
        self._crc = 0
        self._eof = False
        self.damage: Optional[str] = None
        if hasattr(f, "_expected_crc"):
            f._expected_crc = None  # zipfile's own check off (ours below)

    def read(self, n: int) -> bytes:
        data = self._f.read(n)
        if data:
            self._crc = zlib.crc32(data, self._crc)
        elif not self._eof:
            self._eof = True
            if self._crc != self._want:
                self.damage = (f"the member's CRC-32 is {self._crc:08x}, the zip says {self._want:08x}: "
                               "its data may be damaged")
        return data

    def close(self) -> None:
        self._f.close()


def _local_members(path: Path) -> dict:
    """name -> (data offset, method, compressed size or None) from the local file headers."""
    out: dict = {}
    with open(path, "rb") as f:
        pos = 0
        for _ in range(4096):
            f.seek(pos)
            h = f.read(30)
            if len(h) < 30 or h[:4] != b"PK\x03\x04":
                break
            flags, method = struct.unpack_from("<HH", h, 6)
            csize, = struct.unpack_from("<I", h, 18)
            nlen, xlen = struct.unpack_from("<HH", h, 26)
            name = f.read(nlen).decode("cp437", "replace")
            data = pos + 30 + nlen + xlen
            known = not (flags & 0x08)
            out.setdefault(name, (data, method, csize if known else None, flags))
            if not known:
                break  # the next header is after data whose size we do not know
            pos = data + csize
    return out


class _Zip:
    """The .gt3x container: members opened as streams, through the central directory or, when
    that is missing, through the local file headers."""

    def __init__(self, path: Path):
        self.path = path
        self.zf: Optional[zipfile.ZipFile] = None
        self.local: dict = {}
        self.recovered = None  # why the central directory could not be used
        try:
            self.zf = zipfile.ZipFile(path)
        except zipfile.BadZipFile as e:
            with open(path, "rb") as f:
                head = f.read(4)
            if head != b"PK\x03\x04":
                raise CorruptRecordingError(path, f"not a readable .gt3x (zip) file: {e}") from None
            self.local = _local_members(path)
            if not self.local:
                raise CorruptRecordingError(path, f"not a readable .gt3x (zip) file: {e}") from None
            self.recovered = f"{e}; members read from their local headers"
        except (OSError, ValueError, NotImplementedError, EOFError, struct.error) as e:
            raise CorruptRecordingError(path, f"not a readable .gt3x (zip) file: {e}") from None

    def names(self) -> list:
        if self.zf is not None:
            return self.zf.namelist()
        return list(self.local)

    def has(self, name: str) -> bool:
        return name in self.names()

    def size(self, name: str) -> Optional[int]:
        if self.zf is not None:
            return self.zf.getinfo(name).file_size
        return None

    def open(self, name: str):
        if self.zf is not None:
            zi = self.zf.getinfo(name)
            if zi.flag_bits & 0x1:
                raise UnsupportedFormatError(self.path, f"{name} is encrypted")
            if zi.file_size > MAX_MEMBER_BYTES or (
                    zi.file_size > BOMB_MIN_BYTES and zi.file_size > BOMB_RATIO * max(zi.compress_size, 1)):
                raise CorruptRecordingError(
                    self.path, f"{name} claims {zi.file_size} bytes from {zi.compress_size} compressed: "
                               "not a recording (a zip bomb?)")
            try:
                return _CheckedMember(self.zf.open(zi), zi.CRC)
            except NotImplementedError as e:
                raise UnsupportedFormatError(self.path, f"{name}: {e}") from None
            except (zipfile.BadZipFile, OSError, ValueError, EOFError) as e:
                raise CorruptRecordingError(self.path, f"{name}: {e}") from None
        data, method, csize, flags = self.local[name]
        if flags & 0x1:
            raise UnsupportedFormatError(self.path, f"{name} is encrypted")
        if method not in (0, 8):
            raise UnsupportedFormatError(self.path, f"{name}: compression method {method} is not supported")
        return _LocalMember(self.path, data, method, csize)

    def read_small(self, name: str, limit: int) -> bytes:
        f = self.open(name)
        try:
            data = _read(f, limit + 1)
        finally:
            f.close()
        if len(data) > limit:
            raise CorruptRecordingError(self.path, f"{name} is longer than {limit} bytes: not a .gt3x {name}")
        return data

    def close(self) -> None:
        if self.zf is not None:
            self.zf.close()


def _read(f, n: int) -> bytes:
    """Read up to n bytes; a damaged member ends the data (the reason is on ``f.damage``)."""
    chunks, got = [], 0
    while got < n:
        try:
            b = f.read(n - got)
        except (zipfile.BadZipFile, zlib.error, EOFError, OSError, ValueError) as e:
            try:
                f.damage = str(e)
            except AttributeError:
                pass
            break
        if not b:
            break
        chunks.append(b)
        got += len(b)
    return b"".join(chunks)


# ---------------------------------------------------------------------- header
def _header(z: _Zip, path: Path, timezone) -> tuple[DeviceInfo, dict]:
    names = z.names()
    if C.GT3X_INFO_MEMBER not in names:
        raise CorruptRecordingError(path, f"no {C.GT3X_INFO_MEMBER} in the zip: not a .gt3x file "
                                          f"(members: {', '.join(names[:8]) or 'none'})")
    if C.GT3X_LOG_MEMBER in names:
        layout = "log.bin"
    elif C.GT3X_ACTIVITY_MEMBER in names:
        layout = "legacy"
    else:
        raise CorruptRecordingError(path, f"neither {C.GT3X_LOG_MEMBER} nor {C.GT3X_ACTIVITY_MEMBER} "
                                          "in the zip: no samples")
    raw = z.read_small(C.GT3X_INFO_MEMBER, INFO_LIMIT_BYTES)
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        text = raw.decode("latin-1")
    info = _parse_info(text)
    serial = info.get("Serial Number", "")
    try:
        rate = float(info.get("Sample Rate", "nan"))
    except ValueError:
        rate = float("nan")
    lo, hi = C.PLAUSIBLE_RATE_HZ
    if not (lo <= rate <= hi) or rate != int(rate):
        raise CorruptRecordingError(path, f"info.txt Sample Rate {info.get('Sample Rate')!r} is not a "
                                          "plausible whole number of Hz", where="info.txt")
    rate = float(int(rate))

    def ticks(key):
        v = info.get(key)
        try:
            t = int(v)
        except (TypeError, ValueError):
            return None
        if t <= 0:
            return None
        ns = ticks_to_local_ns(t)
        return ns if C.PLAUSIBLE_TIME_NS[0] <= ns <= C.PLAUSIBLE_TIME_NS[1] else None

    start_ns, stop_ns = ticks("Start Date"), ticks("Stop Date")
    download_ns, last_ns = ticks("Download Date"), ticks("Last Sample Time")
    if layout == "legacy" and start_ns is None:
        raise CorruptRecordingError(path, f"info.txt Start Date {info.get('Start Date')!r} is not a "
                                          "valid time (the legacy layout's samples are timed from it)",
                                    where="info.txt")
    pre = _prescan(z, path) if layout == "log.bin" else {"params": {}, "metadata": [], "damage": None}
    params = pre["params"]
    scale, scale_source = None, None
    v = info.get("Acceleration Scale")
    lo_s, hi_s = C.GT3X_PLAUSIBLE_SCALE
    try:
        if v is not None and lo_s <= float(v) <= hi_s:
            scale, scale_source = float(v), "info.txt Acceleration Scale"
    except ValueError:
        pass
    if scale is None and C.GT3X_PARAM_ACCEL_SCALE in params:
        s = ssp_decode(params[C.GT3X_PARAM_ACCEL_SCALE])
        if np.isfinite(s) and lo_s <= s <= hi_s:
            scale, scale_source = float(s), "PARAMETERS ACCEL_SCALE"
    if scale is None:
        for prefix, s in C.GT3X_SCALE_BY_SERIAL_PREFIX.items():
            if serial.upper().startswith(prefix):
                scale, scale_source = s, f"serial prefix {prefix}"
                break
    if scale is None:
        raise CorruptRecordingError(path, f"no accelerometer scale: info.txt has no Acceleration Scale, "
                                          f"no PARAMETERS ACCEL_SCALE, and serial {serial!r} is not "
                                          "in the serial-prefix table", where="info.txt")
    try:
        range_g = float(info["Acceleration Max"])
    except (KeyError, ValueError):
        range_g = C.GT3X_RANGE_BY_SCALE.get(scale, round(2048.0 / scale, 3))
    # the clock's zone: info.txt TimeZone; a log initialised in UTC says so in a METADATA record
    # ([GT3X] LogRecords/Metadata.md 67-90)
    used_utc = False
    meta_offset = None
    for m in pre["metadata"]:
        if m.get("MetadataType") == "LocalTimeLog" and m.get("UsedUtc") is True:
            used_utc = True
        if m.get("MetadataType") in ("SubjectTimeLog", "LocalTimeLog") and m.get("UtcOffset"):
            meta_offset = parse_info_timezone(str(m.get("UtcOffset")))
    zone_text = info.get("TimeZone")
    info_tz = parse_info_timezone(zone_text) if zone_text else None
    if zone_text and info_tz is None:
        raise CorruptRecordingError(path, f"info.txt TimeZone {zone_text!r} is not an offset like "
                                          "-05:00:00; pass timezone= (CLI --timezone) to set it",
                                    where="info.txt")
    stored_tz = info_tz if info_tz is not None else (meta_offset if used_utc else None)
    if timezone is not None:
        from .geneactiv_header import parse_timezone
        try:
            tz = parse_timezone(timezone)
        except ValueError as e:
            raise ValueError(f"timezone override: {e}") from None
    else:
        tz = stored_tz if stored_tz is not None else 0
    firmware = info.get("Firmware", "")
    model = _model_of(serial, info.get("Device Type", ""))
    swap = (serial.upper().startswith(C.GT3X_AXIS_SWAP_SERIAL_PREFIX)
            and firmware.strip() == C.GT3X_AXIS_SWAP_FIRMWARE)
    feature = params.get(C.GT3X_PARAM_FEATURE_ENABLE)
    idle_enabled = None if feature is None else bool(feature >> C.GT3X_FEATURE_SLEEP_MODE_BIT & 1)
    metadata = {k: info[k] for k in ("Subject Name", "Limb", "Side", "Dominance", "Sex", "Height",
                                     "Mass", "Age", "Race") if info.get(k)}
    header = {
        "layout": layout, "model": model, "scale": scale, "scale_source": scale_source,
        "info": info, "timezone_stored_s": stored_tz, "clock_is_utc": used_utc,
        "start_time_ns": None if start_ns is None else start_ns - tz * 10**9,
        "start_local_ns": start_ns, "stop_local_ns": stop_ns, "download_local_ns": download_ns,
        "last_sample_local_ns": last_ns, "axis_swap_fixed": swap,
        "idle_sleep_enabled": idle_enabled, "battery_v_download": _float(info.get("Battery Voltage")),
        "parameters": {f"{a}:{i}": v for (a, i), v in sorted(params.items())},
        "metadata_records": pre["metadata"], "zip_recovered": z.recovered,
        "members": z.names(),
    }
    dev = DeviceInfo(device_type="ActiGraph", device_id=serial, session_id=None, firmware=firmware,
                     sample_rate_nominal=rate, accel_range_g=range_g, timezone_offset_s=int(tz),
                     metadata=metadata, header=header, path=str(path))
    return dev, pre


def _float(v) -> Optional[float]:
    try:
        return float(v)
    except (TypeError, ValueError):
        return None


def _prescan(z: _Zip, path: Path) -> dict:
    """PARAMETERS and METADATA records written before the first sample (initialisation)."""
    f = z.open(C.GT3X_LOG_MEMBER)
    try:
        buf = _read(f, PRESCAN_LIMIT_BYTES)
    finally:
        f.close()
    params: dict = {}
    metadata: list = []
    p, n = 0, len(buf)
    while p + C.GT3X_HEADER_BYTES < n:
        if buf[p] != C.GT3X_SEPARATOR:
            q = buf.find(bytes([C.GT3X_SEPARATOR]), p + 1)
            if q < 0:
                break
            p = q
            continue
        typ = buf[p + 1]
        size = buf[p + 6] | (buf[p + 7] << 8)
        end = p + C.GT3X_HEADER_BYTES + size + 1
        if end > n:
            break
        if _xor(buf, p, end) != C.GT3X_CHECKSUM_OK:
            p += 1
            continue
        payload = buf[p + 8:end - 1]
        if typ in (C.GT3X_REC_ACTIVITY, C.GT3X_REC_ACTIVITY2) and size > C.GT3X_USB_PAYLOAD_BYTES:
            break
        if typ == C.GT3X_REC_PARAMETERS:
            for k in range(0, size - size % 8, 8):
                a, i, v = struct.unpack_from("<HHI", payload, k)
                params[(a, i)] = v
        elif typ == C.GT3X_REC_METADATA and size <= MAX_METADATA_BYTES:
            try:
                m = json.loads(payload.decode("utf-8"))
                if isinstance(m, dict):
                    metadata.append({k: v for k, v in m.items() if k != "JSON"})
            except (UnicodeDecodeError, ValueError, RecursionError):
                pass
        p = end
    return {"params": params, "metadata": metadata}


def _xor(buf: bytes, a: int, b: int) -> int:
    """XOR of the bytes buf[a:b] (a short record in Python, a long one with numpy)."""
    if b - a <= 64:
        x = 0
        for c in buf[a:b]:
            x ^= c
        return x
    return int(np.bitwise_xor.reduce(np.frombuffer(buf, np.uint8, b - a, a)))


def xor_rows(rows: np.ndarray) -> np.ndarray:
    """(k,) XOR of each row's bytes of a (k, w) uint8 array: 8 bytes at a time, then folded."""
    w8 = rows.shape[1] // 8 * 8
    x = np.zeros(rows.shape[0], np.uint64)
    if w8:
        x = np.bitwise_xor.reduce(rows[:, :w8].view("<u8"), axis=1)
        for s in (32, 16, 8):
            x ^= x >> np.uint64(s)
    x = (x & np.uint64(0xFF)).astype(np.uint8)
    if rows.shape[1] > w8:
        x ^= np.bitwise_xor.reduce(rows[:, w8:], axis=1)
    return x


def read_header(path, *, timezone=None) -> DeviceInfo:
    """DeviceInfo from info.txt and the log's initialisation records (reads no samples)."""
    p = Path(path)
    check_recording_path(p)
    _refuse_gzip(p)
    z = _Zip(p)
    try:
        return _header(z, p, timezone)[0]
    finally:
        z.close()


def _refuse_gzip(p: Path) -> None:
    if is_gzip(p):
        raise UnsupportedFormatError(p, "a gzipped .gt3x is not supported (a .gt3x is already a zip); "
                                        "gunzip it first")


# ---------------------------------------------------------------------- the reader
class Gt3xReader:
    """Streaming Source over an ActiGraph ``.gt3x``.

    >>> with Gt3xReader("rec.gt3x") as src:          # doctest: +SKIP
    ...     for block in src: ...                    # Blocks of up to batch_seconds seconds
    ...     print(src.qc.as_dict(), src.idle_sleep_s)

    ``timezone`` overrides info.txt's ``TimeZone`` (e.g. "+01:00", seconds).
    ``fill_idle_sleep=False`` leaves idle-sleep seconds out (a new segment after each).
    """

    def __init__(self, path, *, timezone: Union[str, int, None] = None, batch_seconds: int = 3600,
                 fill_idle_sleep: bool = True):
        self.path = Path(path)
        if batch_seconds < 1:
            raise ValueError("batch_seconds must be >= 1")
        self.batch_seconds = int(batch_seconds)
        self.fill_idle_sleep = bool(fill_idle_sleep)
        check_recording_path(self.path)
        _refuse_gzip(self.path)
        self._zip = _Zip(self.path)
        try:
            self.info, _ = _header(self._zip, self.path, timezone)
        except BaseException:
            self._zip.close()
            raise
        h = self.info.header
        self.layout = h["layout"]
        self.rate = int(self.info.sample_rate_nominal)
        self.scale = float(h["scale"])
        self._swap = bool(h["axis_swap_fixed"])
        self._tz_ns = int(self.info.timezone_offset_s) * 10**9
        self._offsets = (np.arange(self.rate, dtype=np.int64) * 10**9) // self.rate
        self.qc = QCReport(unit="second")
        self._n_events = 0
        self._iterated = False
        self._member = None
        self._carry = np.zeros(3, np.int16)  # the last sample of the previous block
        self._read_bytes = 0
        self._total_bytes = self._zip.size(C.GT3X_LOG_MEMBER if self.layout == "log.bin"
                                           else C.GT3X_ACTIVITY_MEMBER)
        # what the stream told (filled while iterating)
        self.idle_sleep_s = 0  # seconds filled as idle sleep
        self.idle_periods: list = []  # (first local second, seconds)
        self.usb_connections: list = []  # local seconds of USB-connect records
        self.last_record_local_s: Optional[int] = None  # time of the log's last record (any type)
        self.first_local_s: Optional[int] = None
        self.last_local_s: Optional[int] = None  # last second with samples (idle-filled included)

    # ------------------------------------------------------------------ Source protocol
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self) -> None:
        for f in (self._member,):
            try:
                if f is not None:
                    f.close()
            except Exception:  # pragma: no cover - closing never masks the real error
                pass
        try:
            self._zip.close()
        except Exception:  # pragma: no cover
            pass

    def progress(self) -> Optional[float]:
        if not self._total_bytes:
            return None
        return min(1.0, self._read_bytes / self._total_bytes)

    def __iter__(self) -> Iterator[Block]:
        if self._iterated:
            raise RuntimeError("a Gt3xReader is single-pass; open the file again")
        self._iterated = True
        try:
            if self.layout == "log.bin":
                yield from self._log_blocks()
            else:
                yield from self._legacy_blocks()
        finally:
            self.close()

    def _event(self, index: int, reason: str, detail: str = "", time_s=None, samples: int = 0):
        self._n_events += 1
        if self._n_events <= MAX_QC_EVENTS:
            t = None if time_s is None else int(time_s) * 10**9 - self._tz_ns
            self.qc.add(QCEvent(index=index, reason=reason, detail=detail, time_ns=t, samples=samples))

    def _chunk(self, n: int) -> bytes:
        data = _read(self._member, n)
        self._read_bytes += len(data)
        return data

    def _damage(self) -> Optional[str]:
        return getattr(self._member, "damage", None)

    # ------------------------------------------------------------------ block assembly
    def _new_acc(self):
        # runs of seconds: (secs (k,), kind "a12"/"a16"/"fill", payload rows (k, S) or None,
        # first record index, lux, battery); decoded together when the block is made
        return {"runs": [], "n": 0}

    def _decode(self, kind: str, P: np.ndarray) -> np.ndarray:
        """Payload rows (k, S) of one record kind -> (k, rate, 3) int16 X Y Z."""
        rate = self.rate
        S = P.shape[1]
        if kind == "a12":
            n = S * 8 // C.GT3X_BITS_PER_SAMPLE
            v = unpack12(P, n)[..., [1, 0, 2]]  # stored Y X Z -> X Y Z
        else:
            n = S // 6
            v = np.ascontiguousarray(P[:, :n * 6]).view("<i2").reshape(-1, n, 3)
        if n > rate:
            v = v[:, :rate]
        elif n < rate:
            v = np.concatenate([v, np.repeat(v[:, -1:], rate - n, axis=1)], axis=1)
        return self._fix_axes(v)

    def _emit(self, acc, segment: int, first_sample: int) -> Optional[Block]:
        runs = acc["runs"]
        if not runs:
            return None
        rate = self.rate
        lengths = np.array([r[0].shape[0] for r in runs], np.int64)
        total = int(lengths.sum())
        out = np.empty((total, rate, 3), np.int16)
        ptr, i = 0, 0
        while i < len(runs):
            kind, pl = runs[i][1], runs[i][2]
            if kind == "fill":
                k = int(lengths[i])
                out[ptr:ptr + k] = out[ptr - 1, -1] if ptr > 0 else self._carry
                ptr += k
                i += 1
                continue
            j = i + 1
            while j < len(runs) and runs[j][1] == kind and runs[j][2].shape[1] == pl.shape[1]:
                j += 1
            P = pl if j == i + 1 else np.concatenate([r[2] for r in runs[i:j]])
            k = P.shape[0]
            out[ptr:ptr + k] = self._decode(kind, P)
            ptr += k
            i = j
        self._carry = out[ptr - 1, -1].copy()
        secs = np.concatenate([r[0] for r in runs]).astype(np.int64)
        fill = np.array([r[1] == "fill" for r in runs])
        starts = np.cumsum(lengths) - lengths
        within = np.arange(total, dtype=np.int64) - np.repeat(starts, lengths)
        idx = np.where(np.repeat(fill, lengths), -1,
                       np.repeat(np.array([r[3] for r in runs], np.int64), lengths) + within)
        idle = np.repeat(fill.astype(np.uint8), lengths * rate)
        t = (secs[:, None] * 10**9 - self._tz_ns + self._offsets[None, :]).reshape(-1)
        return Block(
            time_ns=t, accel=out.reshape(-1, 3),
            accel_counts_per_g=np.full(3, self.scale), accel_zero=np.zeros(3),
            unit_index=idx, unit_sequence=secs,
            unit_start=np.arange(total, dtype=np.int64) * rate,
            temperature_c=np.full(total, np.nan), temperature_raw=np.full(total, -1, np.int32),
            light=np.repeat(np.array([r[4] for r in runs], np.int32), lengths),
            battery_v=np.repeat(np.array([r[5] for r in runs], np.float64), lengths),
            events=np.zeros(total, np.uint8), per_sample={PER_SAMPLE_IDLE_SLEEP: idle},
            segment=segment, first_sample=first_sample)

    def _fix_axes(self, a: np.ndarray) -> np.ndarray:
        """(..., 3) X Y Z with the firmware 1.6.0 turn undone ([GT3X] Activity.md 26-37)."""
        if self._swap:
            x, y = a[..., 0].copy(), a[..., 1].copy()
            a[..., 0] = y
            a[..., 1] = -x
        return a

    # ------------------------------------------------------------------ log.bin
    def _log_blocks(self) -> Iterator[Block]:
        self._member = self._zip.open(C.GT3X_LOG_MEMBER)
        rate = self.rate
        st = _LogState()
        acc = self._new_acc()
        segment, first_sample = 0, 0
        buf = b""
        pos = 0
        eof = False
        rec_index = -1  # ACTIVITY record counter
        sep = bytes([C.GT3X_SEPARATOR])

        def flush():
            nonlocal acc, first_sample
            b = self._emit(acc, segment, first_sample)
            acc = self._new_acc()
            if b is not None:
                first_sample += b.n
            return b

        def add_seconds(secs, kind, payload, idx0):
            """Append whole seconds (secs (k,); payload rows (k, S), None for idle sleep),
            splitting segments where the seconds are not consecutive; yields each block as soon
            as it holds ``batch_seconds`` seconds (a long run is cut to that size, so a block
            never holds more, however long the run)."""
            nonlocal segment
            secs = np.asarray(secs, np.int64)
            k = secs.shape[0]
            # breaks inside this run: non-consecutive seconds
            if k > 1 and int(secs[-1]) - int(secs[0]) != k - 1:
                br = np.flatnonzero(np.diff(secs) != 1) + 1
            else:
                br = np.zeros(0, np.int64)
            edges = [0] + br.tolist() + [k]
            idx = None if idx0 < 0 else (lambda q: idx0 + q)
            for a, b in zip(edges[:-1], edges[1:]):
                s0 = int(secs[a])
                if st.last_sec is not None and s0 <= st.last_sec:
                    # a second already returned (the clock went back): drop these
                    keep = secs[a:b] > st.last_sec
                    if not keep.any():
                        self._event(idx(a) if idx is not None else -1, "overlapping_time",
                                    f"{b - a} second(s) at or before the last returned second; dropped",
                                    time_s=s0, samples=(b - a) * rate)
                        continue
                    j = a + int(np.argmax(keep))
                    self._event(idx(a) if idx is not None else -1, "overlapping_time",
                                f"{j - a} second(s) at or before the last returned second; dropped",
                                time_s=s0, samples=(j - a) * rate)
                    a, s0 = j, int(secs[j])
                if st.last_sec is not None and s0 != st.last_sec + 1:
                    gap = s0 - st.last_sec - 1
                    self._event(idx(a) if idx is not None else -1, "time_gap",
                                f"{gap} s without samples before this second (not idle sleep); "
                                "a new segment starts", time_s=s0)
                    fb = flush()
                    if fb is not None:
                        yield fb
                    segment += 1
                while a < b:
                    c = min(b, a + max(1, self.batch_seconds - acc["n"]))
                    acc["runs"].append((secs[a:c], kind, None if payload is None else payload[a:c],
                                        -1 if idx0 < 0 else idx0 + a, st.lux, st.battery))
                    acc["n"] += c - a
                    st.last_sec = int(secs[c - 1])
                    if self.first_local_s is None:
                        self.first_local_s = int(secs[a])
                    self.last_local_s = st.last_sec
                    if acc["n"] >= self.batch_seconds:
                        fb = flush()
                        if fb is not None:
                            yield fb
                    a = c

        def fill_idle(until_s: int):
            """Idle-sleep seconds from the last returned one up to ``until_s`` (exclusive)."""
            if st.last_sec is None or until_s <= st.last_sec + 1:
                return
            start = st.last_sec + 1
            n = until_s - start
            self.idle_sleep_s += n
            self.idle_periods.append((start, n))
            # one QC event per period, never capped: the MCAP log keeps the periods (a replay
            # marks its samples again from them); logged before the samples it covers
            t0 = start * 10**9 - self._tz_ns
            self.qc.add(QCEvent(index=-1, reason="idle_sleep", time_ns=t0, end_ns=t0 + n * 10**9,
                                detail=f"{n} s of idle sleep: " +
                                ("the device's last sample is repeated" if self.fill_idle_sleep
                                 else "left out")))
            if not self.fill_idle_sleep:
                return
            step = max(1, self.batch_seconds)  # the period's seconds a block at a time
            for a in range(start, until_s, step):
                yield from add_seconds(np.arange(a, min(a + step, until_s), dtype=np.int64),
                                       "fill", None, -1)

        def activity(secs, payloads, typ, idx0):
            """k activity records (payloads (k, S)), decoded when their block is made."""
            S = payloads.shape[1]
            kind = "a12" if typ == C.GT3X_REC_ACTIVITY else "a16"
            n = S * 8 // C.GT3X_BITS_PER_SAMPLE if kind == "a12" else S // 6
            if n != rate:
                if not st.size_warned:
                    st.size_warned = True
                    self._event(idx0, "record_size",
                                f"an activity record holds {n} samples, the rate is {rate} Hz "
                                "(logged once); samples beyond the rate are dropped, missing ones "
                                "repeat the record's last", time_s=int(secs[0]))
                if n == 0:
                    return
            if st.idle_since is not None or st.idle_until is not None:
                # an idle-sleep period ended (or is still marked): fill up to the exit event, or
                # up to this record when the exit event is missing
                end = int(secs[0]) if st.idle_until is None else min(st.idle_until, int(secs[0]))
                yield from fill_idle(end)
                st.idle_since = st.idle_until = None
            yield from add_seconds(secs, kind, payloads, idx0)

        def more() -> bool:
            nonlocal buf, pos, eof
            if eof:
                return False
            data = self._chunk(CHUNK_BYTES)
            if not data:
                eof = True
                return False
            buf = buf[pos:] + data
            pos = 0
            return True

        while True:
            if len(buf) - pos < C.GT3X_HEADER_BYTES + 1:
                if not more():
                    break
                continue
            if buf[pos] != C.GT3X_SEPARATOR:
                q = buf.find(sep, pos)
                skipped = buf[pos:q if q >= 0 else len(buf)]
                if skipped.strip(b"\0"):
                    st.junk += len(skipped)
                else:
                    st.zeros += len(skipped)
                if q < 0:
                    pos = len(buf)
                    if not more():
                        break
                    continue
                pos = q
                continue
            if st.junk:
                self._event(rec_index + 1, "resync", f"{st.junk} byte(s) that are not a record skipped "
                            "up to the next record separator")
                st.junk = 0
            typ = buf[pos + 1]
            size = buf[pos + 6] | (buf[pos + 7] << 8)
            end = pos + C.GT3X_HEADER_BYTES + size + 1
            if end > len(buf):
                if not more():
                    self._event(rec_index + 1, "truncated_record",
                                f"the log ends inside a record (type {typ}, {size} payload bytes, "
                                f"{len(buf) - pos} of {size + 9} bytes present)")
                    pos = len(buf)
                    break
                continue
            ts = int.from_bytes(buf[pos + 2:pos + 6], "little")
            is_act = typ in (C.GT3X_REC_ACTIVITY, C.GT3X_REC_ACTIVITY2) and size > C.GT3X_USB_PAYLOAD_BYTES
            if is_act:
                # fast path: a run of equal-sized activity records
                stride = size + 9
                k = min((len(buf) - pos) // stride, RUN_LOOKAHEAD)
                arr = np.frombuffer(buf, np.uint8, k * stride, pos).reshape(k, stride)
                head = arr[:, :8].view("<u8")[:, 0] & HEADER_MASK
                ok = head == (head[0] if k else 0)
                run = k if ok.all() else int(np.argmin(ok))
                arr = arr[:run]
                good = xor_rows(arr) == C.GT3X_CHECKSUM_OK
                if not good.all():
                    run = int(np.argmin(good))
                    arr = arr[:run]
                if run > 0:
                    secs = arr[:, 2:6].copy().view("<u4").reshape(-1).astype(np.int64)
                    idx0 = rec_index + 1
                    rec_index += run
                    self.qc.total += run
                    self.qc.valid += run
                    self.last_record_local_s = int(secs[-1])
                    blocks = activity(secs, arr[:, 8:8 + size], typ, idx0)
                    pos += run * stride
                    yield from blocks
                    continue
            # one record, slow path
            if _xor(buf, pos, end) != C.GT3X_CHECKSUM_OK:
                if is_act:
                    self.qc.total += 1
                    self.qc.skipped += 1
                self._event(rec_index + 1, "checksum", f"record type {typ} ({size} payload bytes) at "
                            "a bad checksum; resynchronising on the next separator", time_s=None,
                            samples=rate if is_act else 0)
                pos += 1
                continue
            payload = buf[pos + 8:end - 1]
            pos = end
            self.last_record_local_s = ts
            if typ in (C.GT3X_REC_ACTIVITY, C.GT3X_REC_ACTIVITY2):  # 1 byte (or empty): USB
                self.usb_connections.append(ts)
                self._event(rec_index + 1, "usb_connect", "USB connection record", time_s=ts)
                if st.idle_since is not None:  # docked while asleep: the sleep ends here
                    yield from fill_idle(ts if st.idle_until is None else min(st.idle_until, ts))
                st.idle_since = st.idle_until = None
            elif typ == C.GT3X_REC_EVENT and size >= 1:
                code = payload[0]
                if code == C.GT3X_EVENT_IDLE_ENTER:
                    st.idle_since = ts
                    st.idle_until = None
                elif code == C.GT3X_EVENT_IDLE_EXIT and st.idle_since is not None:
                    st.idle_until = ts
            elif typ == C.GT3X_REC_BATTERY and size >= 2:
                st.battery = (payload[0] | payload[1] << 8) / 1000.0
            elif typ == C.GT3X_REC_LUX and size >= 2:
                st.lux = payload[0] | payload[1] << 8
            # PARAMETERS/METADATA were read by the header; SENSOR_SCHEMA/SENSOR_DATA (IMU), TAG,
            # EPOCH*, HEART_RATE*, CAPSENSE and unknown types are skipped by their size
        if st.junk:
            self._event(rec_index + 1, "resync", f"{st.junk} byte(s) after the last record are not a record")
        dmg = self._damage()
        if dmg:
            self._event(rec_index + 1, "damaged_member", f"{C.GT3X_LOG_MEMBER}: {dmg}; the records "
                        "before the damage are returned")
        if st.idle_since is not None and self.last_record_local_s is not None:
            # idle sleep still open when the log ends: it lasts up to info.txt's Last Sample Time
            # ([GT3X] info.txt.md 47-51) or, without one, up to the log's last record
            end = self.last_record_local_s
            last_ns = self.info.header.get("last_sample_local_ns")
            if last_ns is not None:
                end = max(end, int(last_ns) // 10**9)
            if st.idle_until is not None:
                end = st.idle_until
            yield from fill_idle(end)
        b = flush()
        if b is not None:
            yield b
        self.qc.segments = segment + 1 if first_sample else 0
        if self._n_events > MAX_QC_EVENTS:
            self.qc.add(QCEvent(index=-1, reason="events_truncated",
                                detail=f"{self._n_events - MAX_QC_EVENTS} more QC events not listed"))

    # ------------------------------------------------------------------ legacy (NHANES)
    def _legacy_blocks(self) -> Iterator[Block]:
        rate = self.rate
        self._member = self._zip.open(C.GT3X_ACTIVITY_MEMBER)
        lux_f = self._zip.open(C.GT3X_LUX_MEMBER) if self._zip.has(C.GT3X_LUX_MEMBER) else None
        serial = self.info.device_id.upper()
        lux_scale, lux_max = next((v for p, v in C.GT3X_LUX_SCALE_BY_SERIAL_PREFIX.items()
                                   if serial.startswith(p)), (1.0, float("inf")))
        start_local_s, start_frac_ns = divmod(int(self.info.header["start_local_ns"]), 10**9)
        bytes_per_sec = rate * C.GT3X_BITS_PER_SAMPLE // 8  # exact for even rates; odd below
        per_chunk_s = max(1, min(self.batch_seconds, CHUNK_BYTES // max(bytes_per_sec, 1)))
        # read whole seconds; 9 bytes hold 2 samples, so an even number of samples per read
        sec = 0
        first_sample = 0
        carry = b""
        samples_per_read = per_chunk_s * rate
        nbytes = (samples_per_read * C.GT3X_BITS_PER_SAMPLE + 7) // 8
        if samples_per_read % 2:
            samples_per_read += 1
            nbytes = samples_per_read * C.GT3X_BITS_PER_SAMPLE // 8
        pending = np.zeros((0, 3), np.int16)
        try:
            while True:
                data = carry + self._chunk(nbytes - len(carry))
                carry = b""
                if not data:
                    break
                n = len(data) * 8 // C.GT3X_BITS_PER_SAMPLE
                v = unpack12(np.frombuffer(data, np.uint8), n)[:, [1, 0, 2]]
                v = self._fix_axes(np.ascontiguousarray(v))
                pending = np.concatenate([pending, v]) if pending.shape[0] else v
                last = len(data) < nbytes
                whole = pending.shape[0] // rate
                if last and pending.shape[0] % rate:
                    self._event(sec + whole, "partial_second",
                                f"{C.GT3X_ACTIVITY_MEMBER} ends {pending.shape[0] % rate} sample(s) into "
                                "a second; they are returned")
                k = pending.shape[0] if last else whole * rate
                if k == 0:
                    if last:
                        break
                    continue
                take, pending = pending[:k], pending[k:]
                m = -(-k // rate)
                lux_raw = np.zeros(m, np.int64)
                if lux_f is not None:
                    lb = _read(lux_f, 2 * m)
                    got = np.frombuffer(lb[:len(lb) // 2 * 2], "<u2").astype(np.int64)
                    lux_raw[:got.shape[0]] = got
                lux = np.where((lux_raw < C.GT3X_LUX_MIN_RAW) | (lux_raw == C.GT3X_LUX_INVALID), 0,
                               np.minimum(np.floor(lux_raw * lux_scale + 0.5), lux_max)).astype(np.int32)
                i = np.arange(k, dtype=np.int64)
                t = ((start_local_s + sec) * 10**9 + start_frac_ns - self._tz_ns
                     + (i // rate) * 10**9 + self._offsets[i % rate])
                secs = start_local_s + sec + np.arange(m, dtype=np.int64)
                yield Block(
                    time_ns=t, accel=take, accel_counts_per_g=np.full(3, self.scale),
                    accel_zero=np.zeros(3), unit_index=sec + np.arange(m, dtype=np.int64),
                    unit_sequence=secs, unit_start=np.arange(m, dtype=np.int64) * rate,
                    temperature_c=np.full(m, np.nan), temperature_raw=np.full(m, -1, np.int32),
                    light=lux, battery_v=np.full(m, np.nan), events=np.zeros(m, np.uint8),
                    per_sample={PER_SAMPLE_IDLE_SLEEP: np.zeros(k, np.uint8)},
                    segment=0, first_sample=first_sample)
                if self.first_local_s is None:
                    self.first_local_s = int(secs[0])
                self.last_local_s = int(secs[-1])
                first_sample += k
                self.qc.total += m
                self.qc.valid += m
                sec += m
                if last:
                    break
        finally:
            if lux_f is not None:
                lux_f.close()
        dmg = self._damage()
        if dmg:
            self._event(sec, "damaged_member", f"{C.GT3X_ACTIVITY_MEMBER}: {dmg}; the samples before "
                        "the damage are returned")
        self.qc.segments = 1 if first_sample else 0


class _LogState:
    """What the log.bin parser carries from record to record."""

    __slots__ = ("last_sec", "idle_since", "idle_until", "battery", "lux", "junk",
                 "zeros", "size_warned")

    def __init__(self):
        self.last_sec: Optional[int] = None
        self.idle_since: Optional[int] = None
        self.idle_until: Optional[int] = None
        self.battery = float("nan")
        self.lux = 0
        self.junk = 0
        self.zeros = 0
        self.size_warned = False
