"""CDR (XCDR1, little-endian) message types of the MCAP log, with numpy encoders and decoders.

Every type is declared once as a list of ``(field, type)`` pairs; the ``ros2msg`` schema text
(what Foxglove and ROS 2 tooling read) and the byte layout both come from that declaration.
Layout rules (specs/mcap-python.md §7.2): a 4-byte encapsulation header ``00 01 00 00``; every
primitive aligned to its own size relative to the first byte after the header; a sequence
``T[]`` is a uint32 count (4-aligned) followed by the elements; a fixed array ``T[k]`` has no count.
``stamp`` is a ``builtin_interfaces/Time`` (int32 sec, uint32 nanosec).

Types
-----
* ``AccelBatchRaw`` (``/raw/accel``): the raw stream, lossless. Exact sample times as ``t0_ns``
  plus ``dt_ns[i] = t[i] - t[i-1]`` (``dt_ns[0] = 0``); counts as int16 with the block's
  counts-per-g and zero; the per-unit (sector/page) auxiliary arrays; per-sample GENEActiv
  light/button (empty when absent).
* ``GyroBatchRaw`` (``/raw/gyro``, AX6): gyro counts of the same samples, with dps per count.
* ``AccelBatch`` (``/corrected/accel``): calibrated acceleration, float32 g.
* ``Temperature`` (``/temperature``): one value per raw batch (mean of its units, degC).
* ``AccelSample`` (``/view/accel``): one decimated corrected sample and its norm, for plots.
* ``EpochMetrics`` (``/metrics/epoch``): one message per epoch, scalars only, so Foxglove's Plot
  panel draws every field against time: the plot-friendly preview of the run (§7.3).
"""

from __future__ import annotations

import struct

import numpy as np

_TIME_STRUCT = struct.Struct("<iI")
_U32 = struct.Struct("<I")

ENCAPSULATION = b"\x00\x01\x00\x00"  # CDR_LE

_PRIM = {
    "bool": "u1", "int8": "i1", "uint8": "u1", "int16": "<i2", "uint16": "<u2", "int32": "<i4",
    "uint32": "<u4", "int64": "<i8", "uint64": "<u8", "float32": "<f4", "float64": "<f8",
}

_STRUCT_CODE = {"i1": "b", "u1": "B", "i2": "h", "u2": "H", "i4": "i", "u4": "I", "i8": "q",
                "u8": "Q", "f4": "f", "f8": "d"}

TIME_DEF = "builtin_interfaces/Time"
_TIME_MSG = "int32 sec\nuint32 nanosec\n"


def _parse(t: str):
    """'int16[]' -> ('int16', None); 'float64[3]' -> ('float64', 3); 'int32' -> ('int32', 0)."""
    if t.endswith("]"):
        base, k = t[:-1].split("[")
        return base, (None if k == "" else int(k))
    return t, 0


class CdrType:
    def __init__(self, name: str, fields: list[tuple[str, str]], doc: str = ""):
        self.name = name
        self.fields = fields
        self.doc = doc
        for f, t in fields:
            if t != "time" and _parse(t)[0] not in _PRIM:
                raise ValueError(f"{name}.{f}: unsupported type {t}")

    # ------------------------------------------------------------------ schema
    def schema_text(self) -> str:
        lines = [f"# {line}" for line in self.doc.splitlines()] if self.doc else []
        for f, t in self.fields:
            lines.append(f"{TIME_DEF} {f}" if t == "time" else f"{t} {f}")
        text = "\n".join(lines) + "\n"
        if any(t == "time" for _, t in self.fields):
            text += "=" * 80 + f"\nMSG: {TIME_DEF}\n" + _TIME_MSG
        return text

    # ------------------------------------------------------------------ encode
    def _make_plan(self):
        plan = []
        for f, t in self.fields:
            if t == "time":
                plan.append((f, "time", None, 0))
                continue
            base, k = _parse(t)
            plan.append((f, "seq" if k is None else ("arr" if k else "prim"), np.dtype(_PRIM[base]), k))
        return plan

    def encode(self, values: dict) -> bytes:
        plan = self.__dict__.get("_plan") or self.__dict__.setdefault("_plan", self._make_plan())
        parts = [ENCAPSULATION]
        pos = 0
        zeros = b"\x00" * 8
        for f, kind, dt, k in plan:
            v = values[f]
            if kind == "time":
                p = (-pos) & 3
                if p:
                    parts.append(zeros[:p])
                    pos += p
                sec, nsec = divmod(int(v), 10**9)
                parts.append(_TIME_STRUCT.pack(sec, nsec) if -2**31 <= sec < 2**31 else zeros)
                pos += 8
                continue
            size = dt.itemsize
            if kind == "prim":
                p = (-pos) % size
                if p:
                    parts.append(zeros[:p])
                    pos += p
                parts.append(np.array(v, dt).tobytes())
                pos += size
                continue
            arr = v if (type(v) is np.ndarray and v.dtype == dt and v.flags.c_contiguous) \
                else np.ascontiguousarray(v, dtype=dt)
            if kind == "seq":
                p = (-pos) & 3
                if p:
                    parts.append(zeros[:p])
                    pos += p
                parts.append(_U32.pack(arr.size))
                pos += 4
            elif arr.size != k:
                raise ValueError(f"{self.name}.{f}: expected {k} values, got {arr.size}")
            if arr.size:
                p = (-pos) % size
                if p:
                    parts.append(zeros[:p])
                    pos += p
                b = arr.tobytes()
                parts.append(b)
                pos += len(b)
        return b"".join(parts)

    def encode_values(self, values) -> bytes:
        """Like ``encode`` with the values in field order, arrays already 1-D, contiguous and of
        the field's dtype (the hot path: no conversions, no dict)."""
        plan = self.__dict__.get("_fast") or self.__dict__.setdefault("_fast", [
            (0 if kind == "time" else 1 if kind == "prim" else 2 if kind == "seq" else 3,
             (dt.itemsize if dt is not None else 4), struct.Struct("<" + _STRUCT_CODE[dt.str[1:]]) if kind == "prim" else None)
            for _f, kind, dt, _k in self._make_plan()])
        parts = [ENCAPSULATION]
        pos = 0
        zeros = b"\x00" * 8
        for (kind, size, st), v in zip(plan, values):
            if kind == 0:
                p = -pos & 3
                if p:
                    parts.append(zeros[:p])
                    pos += p
                sec, nsec = divmod(v, 1000000000)
                parts.append(_TIME_STRUCT.pack(sec, nsec) if -2**31 <= sec < 2**31 else zeros)
                pos += 8
                continue
            if kind == 1:
                p = -pos % size
                if p:
                    parts.append(zeros[:p])
                    pos += p
                parts.append(st.pack(v))
                pos += size
                continue
            n = v.shape[0]
            if kind == 2:
                p = -pos & 3
                if p:
                    parts.append(zeros[:p])
                    pos += p
                parts.append(_U32.pack(n))
                pos += 4
            if n:
                p = -pos % size
                if p:
                    parts.append(zeros[:p])
                    pos += p
                parts.append(v.tobytes())
                pos += n * size
        return b"".join(parts)

    # ------------------------------------------------------------------ decode
    def decode(self, data) -> dict:
        plan = self.__dict__.get("_dplan") or self.__dict__.setdefault("_dplan", [
            (f, None, 0) if t == "time" else (f, np.dtype(_PRIM[_parse(t)[0]]), _parse(t)[1])
            for f, t in self.fields])
        buf = memoryview(data)
        if bytes(buf[:2]) != ENCAPSULATION[:2]:
            raise ValueError(f"{self.name}: not little-endian CDR (header {bytes(buf[:4])!r})")
        body = buf[4:]
        pos = 0
        out = {}
        for f, dt, k in plan:
            if dt is None:
                pos += (-pos) % 4
                sec, nsec = _TIME_STRUCT.unpack_from(body, pos)
                out[f] = sec * 10**9 + nsec
                pos += 8
                continue
            size = dt.itemsize
            if k == 0:
                pos += (-pos) % size
                out[f] = np.frombuffer(body, dt, 1, pos)[0].item()
                pos += size
                continue
            if k is None:
                pos += (-pos) % 4
                k = _U32.unpack_from(body, pos)[0]
                pos += 4
            if k:
                pos += (-pos) % size
            out[f] = np.frombuffer(body, dt, k, pos)
            pos += k * size
        return out


ACCEL_BATCH_RAW = CdrType("stillpoint/msg/AccelBatchRaw", [
    ("stamp", "time"),
    ("t0_ns", "int64"),
    ("segment", "int64"),
    ("first_sample", "int64"),
    ("counts_per_g", "float64[3]"),
    ("zero_counts", "float64[3]"),
    ("dt_ns", "int32[]"),
    ("x", "int16[]"), ("y", "int16[]"), ("z", "int16[]"),
    ("unit_index", "int64[]"),
    ("unit_sequence", "int64[]"),
    ("unit_start", "int32[]"),
    ("temperature_c", "float64[]"),
    ("temperature_raw", "int32[]"),
    ("light", "int32[]"),
    ("battery_v", "float64[]"),
    ("events", "uint8[]"),
    ("light_raw", "uint16[]"),
    ("button", "uint8[]"),
], doc="Raw accelerometer samples, lossless: g = (count - zero_counts) / counts_per_g.\n"
       "Sample i time (ns since the Unix epoch, UTC) = t0_ns + sum(dt_ns[:i+1]).\n"
       "unit_* arrays: one entry per .cwa sector / .bin page; unit_start = first sample.")

GYRO_BATCH_RAW = CdrType("stillpoint/msg/GyroBatchRaw", [
    ("stamp", "time"),
    ("t0_ns", "int64"),
    ("dps_per_count", "float64"),
    ("dt_ns", "int32[]"),
    ("x", "int16[]"), ("y", "int16[]"), ("z", "int16[]"),
], doc="Raw gyroscope samples (AX6): dps = count * dps_per_count; times as AccelBatchRaw.")

ACCEL_BATCH = CdrType("stillpoint/msg/AccelBatch", [
    ("stamp", "time"),
    ("t0_ns", "int64"),
    ("segment", "int64"),
    ("dt_ns", "int32[]"),
    ("x", "float32[]"), ("y", "float32[]"), ("z", "float32[]"),
], doc="Calibrated acceleration in g; times as AccelBatchRaw.")

TEMPERATURE = CdrType("stillpoint/msg/Temperature", [
    ("stamp", "time"),
    ("celsius", "float64"),
], doc="Device temperature (mean of the units of one raw batch), degC.")

EPOCH_METRICS = CdrType("stillpoint/msg/EpochMetrics", [
    ("stamp", "time"),
    ("n", "int32"),
    ("enmo_mg", "float32"),
    ("bfen_mg", "float32"),
    ("mad_mg", "float32"),
    ("x", "float32"), ("y", "float32"), ("z", "float32"),
    ("temperature_c", "float32"),
], doc="One epoch: ENMO, BFEN, MAD (mg), mean calibrated acceleration (g), mean temperature.")

EPOCH_COUNTS = CdrType("stillpoint/msg/EpochCounts", [
    ("stamp", "time"),
    ("n", "int32"),
    ("axis1", "int32"), ("axis2", "int32"), ("axis3", "int32"),
    ("vm", "float32"),
], doc="ActiLife counts of one epoch (and segment): axis1 = Y, axis2 = X, axis3 = Z; vm = their\n"
       "vector magnitude; n = 10 Hz values summed (engine/operators/counts.py).")

EPOCH_MIMS = CdrType("stillpoint/msg/EpochMims", [
    ("stamp", "time"),
    ("n", "int32"),
    ("mims", "float32"),
    ("x", "float32"), ("y", "float32"), ("z", "float32"),
], doc="MIMS-units of one epoch (and segment) and per axis; NaN where undefined; n = 100 Hz\n"
       "samples (engine/operators/mims.py).")

VIEW_SAMPLE = CdrType("stillpoint/msg/AccelSample", [
    ("stamp", "time"),
    ("x", "float32"), ("y", "float32"), ("z", "float32"),
    ("norm", "float32"),
], doc="One corrected sample (g) of the decimated view stream, with its norm.")

ALL_TYPES = (ACCEL_BATCH_RAW, GYRO_BATCH_RAW, ACCEL_BATCH, TEMPERATURE, EPOCH_METRICS, VIEW_SAMPLE,
             EPOCH_COUNTS, EPOCH_MIMS)

INT32_MAX = 2**31 - 1


def time_deltas(time_ns: np.ndarray) -> np.ndarray:
    """int32 ``dt_ns`` with ``dt[0] = 0`` (caller guarantees every step fits in int32)."""
    d = np.empty(time_ns.shape[0], np.int32)
    if d.size:
        d[0] = 0
        d[1:] = np.diff(time_ns)
    return d


def times_from_deltas(t0_ns: int, dt_ns: np.ndarray) -> np.ndarray:
    return np.int64(t0_ns) + np.cumsum(dt_ns, dtype=np.int64)


def max_step_ok(time_ns: np.ndarray) -> bool:
    if time_ns.shape[0] < 2:
        return True
    d = np.diff(time_ns)
    return bool(d.max() <= INT32_MAX and d.min() >= -INT32_MAX)
