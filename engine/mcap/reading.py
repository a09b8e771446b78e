"""Reading a stillpoint MCAP back, defensively: the errors and payload checks of every read path.
The messages themselves come from the one streaming reader, ``stream.iter_messages``, which turns
any failure of the container (bad CRC, torn record, decompression error) into an
``McapReadError`` from here, naming the file, the channel and the record reached.

* ``locate_damage(path)`` / ``walk_records(f)``: the first unreadable record, for that message.
* ``decode(cdr_type, path, topic, index, data)`` / ``loads_json(...)`` / ``text(...)``: a message
  payload decoded, or an ``McapReadError`` naming the file, channel and message.
* ``check_raw_message(...)``: the structural invariants of a ``/raw/accel`` or ``/raw/gyro``
  message (equal lengths, unit starts inside the message and increasing), checked before anything
  is allocated from them, so one corrupt field cannot make a reader allocate gigabytes.

``McapReadError`` is a ``CorruptRecordingError`` (a ``StillpointError``): the CLI prints it as one
line with exit code 2.
"""

from __future__ import annotations

import json
from typing import Iterator, Optional

import numpy as np

from stillpoint.engine.core.errors import CorruptRecordingError

RECOVER_HINT = "`stillpoint recover` salvages every readable chunk of it"
# Scales a raw message may carry. Every reader's scale is far inside these: AX3/AX6 256..16384
# counts per g, GENEActiv gain/100 >= 0.01 with offsets within +-GNA_OFFSET_MAX/100
# (drivers/constants.py); AX6 gyro 125..2000 dps over 32768 counts. The bounds keep raw * scale
# a normal number in float32, the engine's working type (a scale of 1e-300 would underflow, one
# of 1e300 overflow).
RAW_COUNTS_PER_G = (1e-3, 1e6)
RAW_ZERO_COUNTS_MAX = 1e6  # |zero_counts|; a nonzero one below RAW_ZERO_COUNTS_MIN is damage
RAW_ZERO_COUNTS_MIN = 1e-6
RAW_DPS_PER_COUNT = (1e-6, 1e3)
# Per-unit temperature (degC) and battery (V): NaN (unknown) or within +-RAW_UNIT_VALUE_MAX. The
# readers give far less (a CWA 16-bit temperature code reads at most ~19,150 degC); the bound keeps
# the values finite in the float32 topics they are written to.
RAW_UNIT_VALUE_MAX = 1e6


class McapReadError(CorruptRecordingError):
    """A stillpoint MCAP that cannot be read: ``path``, ``channel`` (topic) and ``record``."""

    def __init__(self, path, message: str, channel: Optional[str] = None,
                 record: Optional[str] = None):
        self.channel = channel
        self.record = record
        where = ", ".join(x for x in (f"channel {channel}" if channel else None, record) if x)
        super().__init__(path, message, where or None)


def _describe(e: BaseException) -> str:
    s = str(e)
    return f"{type(e).__name__}: {s}" if s else type(e).__name__


def locate_damage(path) -> Optional[str]:
    """The first unreadable or torn record of the file, described (None if none is found)."""
    try:
        with open(path, "rb") as f:
            for rec in walk_records(f):
                if isinstance(rec, (BadRecord, TornTail)):
                    return rec.describe()
    except Exception:  # locating is best effort; the caller reports the original error
        return None
    return None


def decode(cdr_type, path, topic: str, index: int, data):
    """One CDR payload decoded, or an ``McapReadError`` naming the message."""
    try:
        return cdr_type.decode(data)
    except Exception as e:
        raise McapReadError(path, f"message payload is not a valid {cdr_type.name} ({_describe(e)})",
                            channel=topic, record=f"message {index}") from None


def text(path, topic: str, index: int, data) -> str:
    try:
        return bytes(data).decode("utf-8")
    except UnicodeDecodeError as e:
        raise McapReadError(path, f"message payload is not UTF-8 text ({e.reason} at byte {e.start})",
                            channel=topic, record=f"message {index}") from None


def loads_json(path, topic: str, index, data, *, what: str = "message") -> object:
    """A JSON payload (message or metadata value) parsed, or an ``McapReadError``."""
    rec = f"{what} {index}" if isinstance(index, int) else f"{what} {index!r}"
    try:
        s = data if isinstance(data, str) else bytes(data).decode("utf-8")
        return json.loads(s)
    except UnicodeDecodeError as e:
        raise McapReadError(path, f"payload is not UTF-8 text ({e.reason} at byte {e.start})",
                            channel=topic, record=rec) from None
    except (ValueError, RecursionError) as e:
        raise McapReadError(path, f"payload is not valid JSON ({_describe(e)})",
                            channel=topic, record=rec) from None


def check_raw_message(m: dict, path, topic: str, index: int, *, gyro: bool = False) -> int:
    """Validate a decoded raw message; returns its sample count. Everything later allocated from
    the message (sample-to-unit maps, times) is then bounded by the message's own size."""
    n = int(m["dt_ns"].shape[0])

    def bad(why: str):
        raise McapReadError(path, f"inconsistent raw message: {why}", channel=topic,
                            record=f"message {index}")

    if not (m["x"].shape[0] == m["y"].shape[0] == m["z"].shape[0] == n):
        bad(f"{n} times but x/y/z hold {m['x'].shape[0]}/{m['y'].shape[0]}/{m['z'].shape[0]} samples")
    if gyro:
        k = m["dps_per_count"]
        lo, hi = RAW_DPS_PER_COUNT
        if not lo <= k <= hi:  # NaN fails too
            bad(f"dps_per_count is {k}, not a gyro scale ({lo:g}..{hi:g})")
        return n
    units = int(m["unit_start"].shape[0])
    for f in ("unit_index", "unit_sequence", "temperature_c", "temperature_raw", "light",
              "battery_v", "events"):
        if m[f].shape[0] != units:
            bad(f"{f} has {m[f].shape[0]} entries for {units} units")
    st = m["unit_start"].astype(np.int64)
    if units and (st[0] != 0 or (np.diff(st) < 0).any() or st[-1] > n):
        bad(f"unit_start must rise from 0 within the message's {n} samples "
            f"(first {int(st[0])}, min {int(st.min())}, max {int(st.max())})")
    if n and not units:
        bad(f"{n} samples but no unit")
    for f in ("light_raw", "button"):
        if m[f].shape[0] not in (0, n):
            bad(f"{f} has {m[f].shape[0]} entries for {n} samples")
    for f in ("temperature_c", "battery_v"):
        v = m[f]
        far = ~np.isnan(v) & ~(np.abs(v) <= RAW_UNIT_VALUE_MAX)
        if far.any():
            bad(f"{f} {float(v[far][0])!r} is neither NaN nor within +-{RAW_UNIT_VALUE_MAX:g}")
    cpg, zero = m["counts_per_g"], m["zero_counts"]
    lo, hi = RAW_COUNTS_PER_G
    az = np.abs(zero)
    if not (((cpg >= lo) & (cpg <= hi)).all()  # NaN fails too
            and ((az == 0) | ((az >= RAW_ZERO_COUNTS_MIN) & (az <= RAW_ZERO_COUNTS_MAX))).all()):
        bad(f"counts_per_g {cpg.tolist()} / zero_counts {zero.tolist()} are not a usable scale "
            f"(counts per g {lo:g}..{hi:g}, |zero| 0 or {RAW_ZERO_COUNTS_MIN:g}..{RAW_ZERO_COUNTS_MAX:g})")
    return n


# ----------------------------------------------------------------------------- record walk
MAGIC = b"\x89MCAP0\r\n"
OP_CHUNK = 0x06
OP_FOOTER = 0x02


class BadRecord:
    """A top-level record that is complete but unreadable (bad CRC, bad compression, bad fields):
    skipped, the walk goes on with the next record."""

    def __init__(self, offset: int, opcode: int, chunk: Optional[int], why: str):
        self.offset, self.opcode, self.chunk, self.why = offset, opcode, chunk, why

    def describe(self) -> str:
        what = f"chunk {self.chunk}" if self.chunk is not None else f"record 0x{self.opcode:02X}"
        return f"{what} at byte {self.offset}: {self.why}"


class TornTail:
    """The file ends inside a record (or holds garbage where a record should start): the walk
    stops here."""

    def __init__(self, offset: int, why: str):
        self.offset, self.why = offset, why

    def describe(self) -> str:
        return f"at byte {self.offset}: {self.why}"


def walk_records(f) -> Iterator:
    """Every record of an MCAP (finished or not) in file order, chunks opened into their records,
    each chunk's CRC checked. A complete but unreadable record yields a ``BadRecord`` and the walk
    continues with the next one (a bad chunk in the middle loses only that chunk); a record that
    runs past the end of the file yields a ``TornTail`` and ends the walk. A record's length is
    checked against what the file still holds before anything is read, so a corrupt length never
    allocates more than the file size."""
    import io
    import os
    import struct

    from mcap.exceptions import EndOfFile
    from mcap.stream_reader import StreamReader

    f.seek(0, os.SEEK_END)
    size = f.tell()
    f.seek(0)
    if f.read(len(MAGIC)) != MAGIC:
        yield TornTail(0, "not an MCAP file (bad magic)")
        return
    pos = len(MAGIC)
    chunk_no = 0
    while True:
        head = f.read(9)
        if len(head) == 0:
            return
        if head == MAGIC and pos + len(MAGIC) == size:
            return  # trailing magic of a finished file
        if len(head) < 9:
            yield TornTail(pos, f"the file ends {len(head)} bytes into a record header")
            return
        op, length = head[0], struct.unpack_from("<Q", head, 1)[0]
        if length > size - pos - 9:
            yield TornTail(pos, f"a record of {length} bytes (opcode 0x{op:02X}) runs past the end "
                                f"of the file ({size - pos - 9} bytes left)")
            return
        body = f.read(length)
        chunk = chunk_no + 1 if op == OP_CHUNK else None  # numbered from 1, in file order
        if op == OP_CHUNK:
            chunk_no += 1
        try:
            recs = []
            try:
                for r in StreamReader(io.BytesIO(MAGIC + head + body), validate_crcs=True).records:
                    recs.append(r)
            except EndOfFile:
                pass
        except Exception as e:
            yield BadRecord(pos, op, chunk, _describe(e))
        else:
            yield from recs
        pos += 9 + length
        if op == OP_FOOTER:
            return
