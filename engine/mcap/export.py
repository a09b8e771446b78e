"""Export topics of a stillpoint MCAP log to tables: ``export_mcap(path, out, topics)``.

``out`` ending in ``.csv`` / ``.csv.gz``: one topic (default ``/metrics/epoch``), one row per
sample or epoch. ``.npz``: every selected topic (default: corrected stream, epoch metrics,
temperature, calibration), arrays named ``<topic>/<column>`` (e.g. ``corrected/accel/x``).

Columns per topic: ``time_ns`` (int64, exact) and, in CSV, ``time`` (ISO 8601 UTC, µs), then
(a log whose ``clock`` record says the zone is unknown holds the device clock, not UTC: the
CSV columns are then ``time_local_ns`` and ``time_local``, ISO text without ``Z``;
engine/timezones.py; NPZ arrays keep ``<topic>/time_ns``)

* ``/corrected/accel``: ``x, y, z`` (g), ``segment``;
* ``/raw/accel``: ``x, y, z`` (g, from counts and the logged scale), ``cx, cy, cz`` (counts), ``segment``;
* ``/raw/gyro``: ``gx, gy, gz`` (dps);
* ``/metrics/epoch``: ``n, enmo_mg, bfen_mg, mad_mg, x, y, z, temperature_c``;
* ``/temperature``: ``celsius``;
* ``/calibration``, ``/qc``: ``json`` (the message text).

Streaming: messages are decoded one at a time and written as they come (CSV text formatted with
numpy per message; NPZ columns streamed into temporary files, then copied into the zip), so memory
stays flat. The output is written as ``<name>.part`` and renamed when complete
(``stillpoint.engine.core.outputs``).
"""

from __future__ import annotations

import gzip
import io
import json
import shutil
import tempfile
import zipfile
from pathlib import Path

import numpy as np
from stillpoint.engine.core.errors import StillpointError
from stillpoint.drivers.names import csv_cell
from stillpoint.engine.core.outputs import atomic_output, check_output_path

from ..core.times import iso_texts
from .reading import McapReadError, check_raw_message, decode, text
from .stream import iter_messages

from .schemas import (ACCEL_BATCH, ACCEL_BATCH_RAW, EPOCH_METRICS, GYRO_BATCH_RAW, TEMPERATURE,
                           times_from_deltas)

DEFAULT_NPZ_TOPICS = ("/corrected/accel", "/metrics/epoch", "/temperature", "/calibration")
DEFAULT_CSV_TOPIC = "/metrics/epoch"
COLUMNS = {  # per exportable topic: the columns of ``_rows``, in order (a CSV's header)
    "/corrected/accel": ("time_ns", "x", "y", "z", "segment"),
    "/raw/accel": ("time_ns", "x", "y", "z", "cx", "cy", "cz", "segment"),
    "/raw/gyro": ("time_ns", "gx", "gy", "gz"),
    "/metrics/epoch": ("time_ns", "n", "enmo_mg", "bfen_mg", "mad_mg", "x", "y", "z",
                       "temperature_c"),
    "/temperature": ("time_ns", "celsius"),
    "/calibration": ("time_ns", "json"),
    "/qc": ("time_ns", "json"),
}


class ExportError(StillpointError):
    pass


def _rows(topic: str, data: bytes, log_time: int, path=None, index: int = 0) -> dict:
    """Columns of one message (numpy arrays of equal length); a payload that does not decode is
    an ``McapReadError`` naming the file, topic and message."""
    if topic == "/corrected/accel":
        m = decode(ACCEL_BATCH, path, topic, index, data)
        if not m["x"].shape[0] == m["y"].shape[0] == m["z"].shape[0] == m["dt_ns"].shape[0]:
            raise McapReadError(path, "x/y/z and times differ in length", channel=topic,
                                record=f"message {index}")
        t = times_from_deltas(m["t0_ns"], m["dt_ns"])
        return {"time_ns": t, "x": m["x"], "y": m["y"], "z": m["z"],
                "segment": np.full(t.shape[0], m["segment"], np.int64)}
    if topic == "/raw/accel":
        m = decode(ACCEL_BATCH_RAW, path, topic, index, data)
        check_raw_message(m, path, topic, index)
        t = times_from_deltas(m["t0_ns"], m["dt_ns"])
        c = np.stack([m["x"], m["y"], m["z"]], axis=1).astype(np.float64)
        g = (c - m["zero_counts"]) / m["counts_per_g"]
        return {"time_ns": t, "x": g[:, 0], "y": g[:, 1], "z": g[:, 2], "cx": m["x"], "cy": m["y"],
                "cz": m["z"], "segment": np.full(t.shape[0], m["segment"], np.int64)}
    if topic == "/raw/gyro":
        m = decode(GYRO_BATCH_RAW, path, topic, index, data)
        check_raw_message(m, path, topic, index, gyro=True)
        t = times_from_deltas(m["t0_ns"], m["dt_ns"])
        k = m["dps_per_count"]
        return {"time_ns": t, "gx": m["x"] * k, "gy": m["y"] * k, "gz": m["z"] * k}
    if topic == "/metrics/epoch":
        m = decode(EPOCH_METRICS, path, topic, index, data)
        return {"time_ns": np.array([m["stamp"]], np.int64),
                **{k: np.array([m[k]]) for k in ("n", "enmo_mg", "bfen_mg", "mad_mg", "x", "y", "z",
                                                 "temperature_c")}}
    if topic == "/temperature":
        m = decode(TEMPERATURE, path, topic, index, data)
        return {"time_ns": np.array([m["stamp"]], np.int64), "celsius": np.array([m["celsius"]])}
    if topic in ("/calibration", "/qc"):
        return {"time_ns": np.array([log_time], np.int64),
                "json": np.array([text(path, topic, index, data)], object)}
    raise _not_exportable(topic)


def _not_exportable(topic: str) -> "ExportError":
    return ExportError(f"topic {topic} cannot be exported (known: {', '.join(COLUMNS)})")


def _iso(t: np.ndarray, utc: bool = True) -> np.ndarray:
    text = iso_texts(t, "us")
    return np.char.add(text, "Z") if utc else text


def _zone_known(path) -> bool:
    """Whether the log's times are UTC (``engine.timezones.log_zone``; unreadable: as before)."""
    from stillpoint.engine.timezones import log_zone
    zone = log_zone(path)
    return True if zone is None else zone.known


def _fmt(col: np.ndarray) -> np.ndarray:
    if col.dtype == object:  # message text: a cell a spreadsheet never reads as a formula
        return np.array([json.dumps(s) if ("," in s or '"' in s) else s
                         for s in map(csv_cell, col)])
    if col.dtype.kind in "iu":
        return col.astype(str)
    return np.char.mod("%.9g", col)


def _messages(path, topics):
    """(topic, index within the topic, message), CRC-checked; damage is an ``McapReadError``."""
    yield from iter_messages(path, topics)


def _export_csv(path, raw, topic: str, gz: bool, utc: bool = True) -> int:
    """Rows of ``topic`` as CSV text into the binary file ``raw`` (left open); ``utc``: the
    log's zone is known (else the time columns are ``time_local``/``time_local_ns``)."""
    rows = 0
    inner = gzip.GzipFile(fileobj=raw, mode="wb", compresslevel=6) if gz else io.BufferedWriter(raw, 1 << 20)
    f = io.TextIOWrapper(inner, encoding="utf-8", newline="")
    try:
        header = ["time"] + list(COLUMNS[topic])
        names = header if utc else ["time_local", "time_local_ns"] + header[2:]
        f.write(",".join(names) + "\n")  # also when the log holds no message of the topic
        for _t, i, msg in _messages(path, [topic]):
            cols = _rows(topic, msg.data, msg.log_time, path, i)
            parts = [_iso(cols["time_ns"], utc)] + [_fmt(np.asarray(cols[k])) for k in header[1:]]
            lines = parts[0]
            for p in parts[1:]:
                lines = np.char.add(np.char.add(lines, ","), p)
            f.write("\n".join(lines.tolist()) + "\n")
            rows += len(cols["time_ns"])
    finally:
        f.flush()
        f.detach()
        if gz:
            inner.close()  # writes the gzip trailer; ``raw`` stays open
        else:
            inner.flush()
            inner.detach()
    return rows


def _export_npz(path, out: Path, topics) -> dict:
    check_output_path(out)
    tmpdir = Path(tempfile.mkdtemp(prefix=".export-", dir=out.parent))
    files: dict[str, tuple] = {}  # name -> (file, dtype, count)
    counts: dict[str, int] = {}
    try:
        for topic, i, msg in _messages(path, topics):
            cols = _rows(topic, msg.data, msg.log_time, path, i)
            counts[topic] = counts.get(topic, 0) + len(cols["time_ns"])
            for k, v in cols.items():
                name = f"{topic.strip('/')}/{k}"
                if v.dtype == object:
                    v = np.array([s.encode() for s in v], object)
                    ent = files.setdefault(name, [open(tmpdir / f"{len(files)}.bin", "wb"), "json", 0])
                    for s in v:
                        ent[0].write(len(s).to_bytes(4, "little") + s)
                    ent[2] += len(v)
                    continue
                ent = files.setdefault(name, [open(tmpdir / f"{len(files)}.bin", "wb"), v.dtype, 0])
                ent[0].write(np.ascontiguousarray(v, ent[1]).tobytes())
                ent[2] += len(v)
        with atomic_output(out) as raw, zipfile.ZipFile(raw, "w", zipfile.ZIP_STORED, allowZip64=True) as z:
            for name, (fh, dtype, n) in files.items():
                fh.close()
                if dtype == "json":
                    raw = Path(fh.name).read_bytes()
                    items, pos = [], 0
                    while pos < len(raw):
                        k = int.from_bytes(raw[pos:pos + 4], "little")
                        items.append(raw[pos + 4:pos + 4 + k].decode())
                        pos += 4 + k
                    buf = io.BytesIO()
                    np.save(buf, np.array(items, dtype=str))
                    z.writestr(name + ".npy", buf.getvalue())
                    continue
                with z.open(name + ".npy", "w", force_zip64=True) as dst:
                    hdr = io.BytesIO()
                    np.lib.format.write_array_header_1_0(
                        hdr, {"descr": np.lib.format.dtype_to_descr(np.dtype(dtype)),
                              "fortran_order": False, "shape": (n,)})
                    dst.write(hdr.getvalue())
                    with open(fh.name, "rb") as src:
                        shutil.copyfileobj(src, dst, 1 << 20)
    finally:
        for fh, _d, _n in files.values():
            fh.close()
        shutil.rmtree(tmpdir, ignore_errors=True)
    return counts


def _check_stillpoint_log(path) -> None:
    """Refuse an MCAP that another program wrote (no 'device' metadata record), as replay and
    inspect do. A log without a summary (not finished) is left to the streaming read, which
    names any damage and points at ``recover``."""
    from stillpoint.engine.core.errors import UnsupportedFormatError
    from stillpoint.engine.mcap.replay import NOT_A_STILLPOINT_LOG
    from stillpoint.engine.mcap.replay import check_is_log
    from .stream import read_metadata
    check_is_log(path)
    with open(path, "rb") as f:
        try:
            meta = read_metadata(f)
        except Exception:  # noqa: BLE001 - unfinished or damaged: the export's own read reports it
            return {}
    if "device" not in meta:
        raise UnsupportedFormatError(path, NOT_A_STILLPOINT_LOG)
    return meta


def _lean_topics(path, meta: dict, topics, named: bool):
    """``topics`` of a lean log (settings ``"log": "lean"``): a per-sample topic it does not
    keep is refused when asked for by name, left out of the defaults otherwise."""
    import json
    from ..settings import is_lean
    from .sink import LEAN_DROPPED
    try:
        lean = is_lean(json.loads((meta.get("settings") or {}).get("json") or "null"))
    except (TypeError, ValueError, RecursionError):
        lean = False
    if not lean:
        return list(topics)
    gone = [t for t in topics if t in LEAN_DROPPED]
    if gone and named:
        raise ExportError(f"{path}: a lean log keeps no {', '.join(gone)} (per-sample streams); "
                          f"`stillpoint replay {path} --raw RECORDING --log full` brings them back")
    return [t for t in topics if t not in LEAN_DROPPED]


def export_mcap(path, out, topics=None) -> dict:
    """Export topics of a stillpoint MCAP to CSV or NPZ; returns rows per topic."""
    out = Path(out)
    name = out.name.lower()
    topics = [t if t.startswith("/") else "/" + t for t in (topics or [])]
    for t in topics:
        if t not in COLUMNS:
            raise _not_exportable(t)
    if name.endswith(".csv") or name.endswith(".csv.gz"):
        if len(topics) > 1:
            raise ExportError("CSV export takes one --topic (use .npz for several)")
        topic = topics[0] if topics else DEFAULT_CSV_TOPIC
        check_output_path(out)
        _lean_topics(path, _check_stillpoint_log(path), [topic], True)
        with atomic_output(out) as raw:
            n = _export_csv(path, raw, topic, name.endswith(".gz"), _zone_known(path))
        return {topic: n}
    if name.endswith(".npz"):
        meta = _check_stillpoint_log(path)  # the output is checked by _export_npz, before any work
        return _export_npz(path, out, _lean_topics(path, meta, topics or DEFAULT_NPZ_TOPICS,
                                                   bool(topics)))
    raise ExportError(f"{out}: output must end with .csv, .csv.gz or .npz")
