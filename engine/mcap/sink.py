"""The MCAP log of record: raw stream (lossless), corrected stream, temperature, epoch metrics,
calibration estimates, QC events, device metadata and the run's settings.

Topics (see engine/mcap/schemas.py for the CDR layouts; ``json`` topics carry a JSON object):

==================== ============================ =============================================
topic                encoding / schema            one message per
==================== ============================ =============================================
/raw/accel           cdr AccelBatchRaw            cell (10 s of data) of whole sectors/pages
/raw/gyro            cdr GyroBatchRaw (AX6 only)  same samples as /raw/accel
/corrected/accel     cdr AccelBatch (float32 g)   cell and segment
/temperature         cdr Temperature              raw message (mean of its units)
/view/accel          cdr AccelSample              view sample (``view_hz`` a second; 0 = off)
/metrics/epoch       cdr EpochMetrics             epoch (plot-friendly preview, one value each)
/metrics/counts      cdr EpochCounts              epoch and segment (with ``--counts``)
/metrics/mims        cdr EpochMims                epoch and segment (with ``--mims``)
/calibration         json + jsonschema            estimate published (with fit range, effect)
/qc                  json + jsonschema            QC event (reader and engine)
==================== ============================ =============================================

A lean log (settings ``"log": "lean"``, engine/settings.py) has no per-sample topics
(``LEAN_DROPPED``: raw, gyro, the raw pages' temperature, corrected); its chunks are cut by the
epochs' cells. Everything else is as in a full log.

No message is logged before the recording's first sample: an online prior is logged at the
first sample's time, with ``fitted_at_ns`` saying when it was fitted.

Metadata records: ``device`` (DeviceInfo fields), ``settings`` (the run's settings, JSON in the
value ``json``), and at the end ``summary`` and ``calibration`` (the estimate applied).

Cells: data time is cut into cells of ``flush_every_s`` (default 10 s) on the UTC grid. Raw
messages hold the whole sectors/pages that start in a cell; corrected messages hold the samples
of one cell and segment (so replay reproduces the message layout exactly). The sink flushes the
chunk in progress each time a new chunk span begins (``chunk_s``: one cell by default; the engine
uses 60 s for batch runs); the chunks a pipeline step completes go to the writer together at the
end of the step, so a killed process loses the step in progress and the open span (plus the
correction's one-unit lag). Every chunk is followed by its Message Index
records (the MCAP specification's layout, which indexed readers such as Foxglove's need).
Corrected values are rounded to ``corrected_quantum_g`` (2^-16 g = 15 µg, 1/256 of the finest
AX3 count) before float32: float noise below the sensor's resolution does not compress, and
without it the corrected stream alone would be twice the size of the raw one.
The file is fsynced at flushes at most once per ``fsync_every_wall_s`` of wall time (SIGKILL
only loses what Python had not handed to the OS; fsync protects against power loss).
``recover`` salvages every complete chunk of a file that was never finished.

The sink is an ``McapLog`` (engine/mcap/log.py, the one writer path: ``<name>.part`` renamed
when finished) and builds each chunk's records itself: all the messages of a pipeline step at once
(``_frame_block``, engine/mcap/blockframe.py: each topic's records back to back in one buffer,
handed to engine/mcap/chunks.py as one slice per run of records; the cell-by-cell path, one
``struct.pack`` per message, handles the rare rest with the same bytes); the writer (engine/mcap/writer.py) compresses and
writes chunks and the summary. By default that happens inline (``writer="inline"``; the engine
picks a writer per mode, engine.run.tuning.WRITER_BY_MODE): each chunk is compressed and handed to the
OS as its cell ends, so a killed run loses only the cell in progress. ``writer="process"`` runs the writer in a child process (compression on another core;
pays off only on an otherwise idle machine: every chunk crosses a pipe; if the engine dies, the
writer still writes what it received). Measured (tools/benchmarks/bench_process.py, 7-day 100 Hz
AX3, 2 cores shared with other jobs): inline 12.6 s wall / 11.1 s CPU, writer process 14.4 s
wall / 14.1 s CPU (the pipe copies).

``writer="thread"`` (the batch mode's) compresses and writes on a writer thread (at most one
chunk waiting) when the process may use a second core (``core.prefetch.cores_available``;
``STILLPOINT_CORES=1`` forces one: then it writes inline). With ``STILLPOINT_FRAMING_THREAD=1``
it also frames on a thread of its own (off by default: measured slower, see
``FRAMING_THREAD_ENV``): the engine's calls
(``write_slices``, ``write_json``, ``write_metadata``, ...) run in the order made on a framing
thread (engine/mcap/ordered.py: at most ``FRAMING_DEPTH`` steps waiting), which frames a step's
records and builds its chunks while the engine corrects the next step; a writer thread
compresses and writes the chunks (at most one waiting; zstd and most of the framing's numpy
run outside the interpreter lock). One thread runs every call, in the order made, so the file
is the same byte for byte as on one core (same records, chunk boundaries and indexes;
tests/engine/mcap/test_mcap_two_cores.py). A failure on either thread (a full disk, a bad record) is raised
in the engine by its next call, as the exception the inline path raises (one line, exit 2), with
everything written before kept; ``abort`` (an interrupt) drops the steps still waiting and
stops both threads, leaving the ``.part`` file recoverable. With one core, "thread" writes
inline. Records are written in the order of the calls, so the file is deterministic.
"""

from __future__ import annotations

import bisect
import json
from dataclasses import asdict
from typing import Optional

import numpy as np

from ..core.blocks import Block, DeviceInfo, PER_SAMPLE_BUTTON, PER_SAMPLE_LIGHT_RAW
from ..calibration.outcome import CalibrationOutcome
from ..core.jsonsafe import dumps, jsonable
from .schemas import (ACCEL_BATCH, ACCEL_BATCH_RAW, EPOCH_COUNTS, EPOCH_METRICS, EPOCH_MIMS,
                      GYRO_BATCH_RAW, TEMPERATURE, VIEW_SAMPLE, INT32_MAX, max_step_ok, time_deltas)
from ..operators.correction import CorrectedBatch
from ..operators.metrics import EpochMetrics

TOPIC_RAW = "/raw/accel"
TOPIC_GYRO = "/raw/gyro"
TOPIC_CORRECTED = "/corrected/accel"
TOPIC_TEMPERATURE = "/temperature"
TOPIC_METRICS = "/metrics/epoch"
TOPIC_COUNTS = "/metrics/counts"
TOPIC_MIMS = "/metrics/mims"
TOPIC_CALIBRATION = "/calibration"
TOPIC_QC = "/qc"
LEAN_DROPPED = (TOPIC_RAW, TOPIC_GYRO, TOPIC_TEMPERATURE, TOPIC_CORRECTED)  # not in a lean log

from .jsonschemas import CALIBRATION, QC
from .log import McapLog
from .ordered import OrderedWorker
from ..core.prefetch import cores_available
from .view import TOPIC_VIEW, ViewDecimator, view_records
from .writer import CHUNK_SIZE, LIBRARY, ZSTD_LEVEL  # noqa: F401

# Pipeline steps waiting for the framing thread: one framed while up to this many wait, each a
# step's block, corrected batches and epochs (~3 MB at 100 Hz).
FRAMING_DEPTH = 2

# The framing thread is off unless this is "1": on this shared 2-core machine under load
# (load average 18-22), tools/benchmarks/bench_cores.py measured a week's batch run with it
# at 1.18x the CPU and 1.16x the wall time of the run without it (least of 3 alternating
# rounds), and an earlier design that also moved the tables to that thread was slower on an
# idle machine; docs/performance.md, "Two cores for one file".
FRAMING_THREAD_ENV = "STILLPOINT_FRAMING_THREAD"


def framing_thread_on() -> bool:
    """Whether writer="thread" also frames on a thread of its own ($STILLPOINT_FRAMING_THREAD)."""
    import os
    return os.environ.get(FRAMING_THREAD_ENV, "").strip() == "1"


def device_metadata(info: DeviceInfo) -> dict[str, str]:
    """DeviceInfo as an MCAP metadata record (string values; full JSON under ``json``)."""
    d = jsonable(asdict(info))
    rec = {k: (v if isinstance(v, str) else json.dumps(v, sort_keys=True)) for k, v in d.items()}
    rec["json"] = json.dumps(d, sort_keys=True)
    return rec


def raw_message(block: Block, a: int = 0, b: Optional[int] = None, ua: int = 0,
                ub: Optional[int] = None, dt: Optional[np.ndarray] = None) -> bytes:
    """AccelBatchRaw of samples [a, b) whose units are [ua, ub) (whole units; no Block copy)."""
    b = block.n if b is None else b
    ub = block.m if ub is None else ub
    if b <= a:
        return b""
    z = np.zeros(0)
    ps = block.per_sample
    acc = block.accel[a:b]
    t0 = int(block.time_ns[a])
    return ACCEL_BATCH_RAW.encode({
        "stamp": t0, "t0_ns": t0, "segment": block.segment,
        "first_sample": block.first_sample + a, "counts_per_g": block.accel_counts_per_g,
        "zero_counts": block.accel_zero,
        "dt_ns": time_deltas(block.time_ns[a:b]) if dt is None else dt,
        "x": acc[:, 0], "y": acc[:, 1], "z": acc[:, 2],
        "unit_index": block.unit_index[ua:ub], "unit_sequence": block.unit_sequence[ua:ub],
        "unit_start": block.unit_start[ua:ub] - a, "temperature_c": block.temperature_c[ua:ub],
        "temperature_raw": block.temperature_raw[ua:ub], "light": block.light[ua:ub],
        "battery_v": block.battery_v[ua:ub], "events": block.events[ua:ub],
        "light_raw": ps[PER_SAMPLE_LIGHT_RAW][a:b] if PER_SAMPLE_LIGHT_RAW in ps else z,
        "button": ps[PER_SAMPLE_BUTTON][a:b] if PER_SAMPLE_BUTTON in ps else z,
    })


def gyro_message(block: Block, a: int = 0, b: Optional[int] = None,
                 dt: Optional[np.ndarray] = None) -> bytes:
    b = block.n if b is None else b
    g = block.gyro[a:b]
    t0 = int(block.time_ns[a])
    return GYRO_BATCH_RAW.encode({
        "stamp": t0, "t0_ns": t0, "dps_per_count": float(block.gyro_dps_per_count),
        "dt_ns": time_deltas(block.time_ns[a:b]) if dt is None else dt,
        "x": g[:, 0], "y": g[:, 1], "z": g[:, 2]})


def quantize(accel: np.ndarray, quantum_g: float) -> np.ndarray:
    """float32 of ``accel`` rounded to a multiple of ``quantum_g`` (0: plain float32)."""
    if quantum_g:
        t = accel * (1.0 / quantum_g)
        np.round(t, out=t)
        t *= quantum_g
        return t.astype(np.float32)
    return accel.astype(np.float32)


def corrected_message(batch: CorrectedBatch, quantum_g: float) -> bytes:
    a = quantize(batch.accel, quantum_g)
    return ACCEL_BATCH.encode({
        "stamp": int(batch.time_ns[0]), "t0_ns": int(batch.time_ns[0]), "segment": batch.segment,
        "dt_ns": time_deltas(batch.time_ns), "x": a[:, 0], "y": a[:, 1], "z": a[:, 2]})


_EPOCH_DTYPE = np.dtype([("hdr", "V4"), ("sec", "<i4"), ("nsec", "<u4"), ("n", "<i4"),
                         ("enmo", "<f4"), ("bfen", "<f4"), ("mad", "<f4"), ("x", "<f4"),
                         ("y", "<f4"), ("z", "<f4"), ("temp", "<f4")])  # packed, all 4-aligned


def epoch_records(m: EpochMetrics) -> np.ndarray:
    """EPOCH_METRICS payloads of every row as one structured array (one vectorised pass)."""
    k = len(m)
    a = np.zeros(k, _EPOCH_DTYPE)
    a["hdr"] = np.void(b"\x00\x01\x00\x00")
    a["sec"], a["nsec"] = np.divmod(m.start_ns, 10**9)
    a["n"] = m.n
    a["enmo"], a["bfen"], a["mad"] = m.enmo_mg, m.bfen_mg, m.mad_mg
    a["x"], a["y"], a["z"] = m.mean[:, 0], m.mean[:, 1], m.mean[:, 2]
    a["temp"] = m.temperature
    return a


_COUNTS_DTYPE = np.dtype([("hdr", "V4"), ("sec", "<i4"), ("nsec", "<u4"), ("n", "<i4"),
                          ("axis1", "<i4"), ("axis2", "<i4"), ("axis3", "<i4"), ("vm", "<f4")])
_MIMS_DTYPE = np.dtype([("hdr", "V4"), ("sec", "<i4"), ("nsec", "<u4"), ("n", "<i4"),
                        ("mims", "<f4"), ("x", "<f4"), ("y", "<f4"), ("z", "<f4")])


def counts_records(c) -> np.ndarray:
    """EPOCH_COUNTS payloads of an ``EpochCounts`` as one structured array."""
    a = np.zeros(len(c), _COUNTS_DTYPE)
    a["hdr"] = np.void(b"\x00\x01\x00\x00")
    a["sec"], a["nsec"] = np.divmod(c.start_ns, 10**9)
    a["n"] = c.n
    a["axis1"], a["axis2"], a["axis3"] = c.counts[:, 0], c.counts[:, 1], c.counts[:, 2]
    a["vm"] = c.vm
    return a


def mims_records(m) -> np.ndarray:
    """EPOCH_MIMS payloads of an ``EpochMims`` as one structured array."""
    a = np.zeros(len(m), _MIMS_DTYPE)
    a["hdr"] = np.void(b"\x00\x01\x00\x00")
    a["sec"], a["nsec"] = np.divmod(m.start_ns, 10**9)
    a["n"] = m.n
    a["mims"] = m.mims
    a["x"], a["y"], a["z"] = m.axes[:, 0], m.axes[:, 1], m.axes[:, 2]
    return a


def epoch_messages(m: EpochMetrics) -> list[bytes]:
    """EPOCH_METRICS payloads for every row (fixed layout)."""
    buf = epoch_records(m).tobytes()
    w = _EPOCH_DTYPE.itemsize
    return [buf[i * w:(i + 1) * w] for i in range(len(m))]


class _RawCells:
    """A Block's raw messages (one per cell of ``cell_ns``: the whole units that start in it),
    with every array converted to its CDR type once for the block."""

    def __init__(self, block: Block, cell_ns: int):
        self.block = block
        n, m = block.n, block.m
        starts = block.unit_start if m else np.zeros(1, np.int64)
        ucell = block.time_ns[starts] // cell_ns
        first = np.concatenate([[0], np.flatnonzero(ucell[1:] != ucell[:-1]) + 1])
        self.cell = ucell[first]
        self.a = starts[first].tolist()  # sample ranges [a, b) and unit ranges [ua, ub) per cell
        self.b = np.append(starts[first][1:], n).tolist()
        self.ua = first.tolist() if m else [0]
        self.ub = np.append(first[1:], len(starts)).tolist() if m else [0]
        d = np.diff(block.time_ns)
        self.ok = not d.size or (int(d.max()) <= INT32_MAX and int(d.min()) >= -INT32_MAX)
        if not self.ok:
            return  # a clock step that does not fit int32 ns: the general path splits there
        dt = np.empty(n, "<i4")
        dt[0] = 0
        dt[1:] = d
        dt[self.a] = 0  # every message starts its own deltas
        self.dt = dt
        self.xyz = np.ascontiguousarray(block.accel.T, "<i2")
        self.gyro = None if block.gyro is None else np.ascontiguousarray(block.gyro.T, "<i2")
        if m:
            rel = starts - np.repeat(np.asarray(self.a, np.int64), np.diff(first.tolist() + [m]))
            tc = block.temperature_c.astype("<f8")
            fin = np.isfinite(tc)
            cnt = np.add.reduceat(fin.astype(np.int64), first)
            with np.errstate(invalid="ignore", divide="ignore"):
                self.temp = (np.add.reduceat(np.where(fin, tc, 0.0), first) / cnt).tolist()
            self.temp_ok = (cnt > 0).tolist()
            self.units = [block.unit_index.astype("<i8"), block.unit_sequence.astype("<i8"),
                          rel.astype("<i4"), tc, block.temperature_raw.astype("<i4"),
                          block.light.astype("<i4"), block.battery_v.astype("<f8"),
                          block.events.astype("u1")]
        else:
            self.temp_ok = [False]
            self.units = [np.zeros(0, t) for t in ("<i8", "<i8", "<i4", "<f8", "<i4", "<i4", "<f8",
                                                   "u1")]
        ps = block.per_sample
        self.light_raw = ps[PER_SAMPLE_LIGHT_RAW].astype("<u2") if PER_SAMPLE_LIGHT_RAW in ps else None
        self.button = ps[PER_SAMPLE_BUTTON].astype("u1") if PER_SAMPLE_BUTTON in ps else None
        self.head = [block.segment, None, np.ascontiguousarray(block.accel_counts_per_g, "<f8"),
                     np.ascontiguousarray(block.accel_zero, "<f8")]
        self.empty_u2, self.empty_u1 = np.zeros(0, "<u2"), np.zeros(0, "u1")

    def write(self, sink: "McapSink", k: int) -> None:
        """Log the raw (and gyro, temperature) messages of cell number ``k`` of this block."""
        blk = self.block
        a, b, ua, ub = self.a[k], self.b[k], self.ua[k], self.ub[k]
        if not self.ok:
            sink.write_raw(blk, a, b, ua, ub)
            return
        if b <= a:
            return
        t0 = int(blk.time_ns[a])
        x = self.xyz
        u = self.units
        vals = [t0, t0, self.head[0], blk.first_sample + a, self.head[2], self.head[3],
                self.dt[a:b], x[0, a:b], x[1, a:b], x[2, a:b]]
        vals += [arr[ua:ub] for arr in u]
        vals.append(self.light_raw[a:b] if self.light_raw is not None else self.empty_u2)
        vals.append(self.button[a:b] if self.button is not None else self.empty_u1)
        sink._msg(TOPIC_RAW, "cdr", ACCEL_BATCH_RAW.name, t0, ACCEL_BATCH_RAW.encode_values(vals))
        if self.gyro is not None:
            g = self.gyro
            sink._msg(TOPIC_GYRO, "cdr", GYRO_BATCH_RAW.name, t0, GYRO_BATCH_RAW.encode_values(
                [t0, t0, float(blk.gyro_dps_per_count), self.dt[a:b], g[0, a:b], g[1, a:b], g[2, a:b]]))
        if ub > ua and self.temp_ok[k]:
            sink._msg(TOPIC_TEMPERATURE, "cdr", TEMPERATURE.name, t0,
                      TEMPERATURE.encode_values([t0, self.temp[k]]))


class _CorrectedRun:
    """A CorrectedBatch quantised to float32 once; messages slice it. ``words``: (4, n) 4-byte
    rows dt_ns, x, y, z (the layout of a corrected message's arrays, so one copy frames them);
    ``dt``, ``x``, ``y``, ``z`` are its rows. ``words=False`` (a lean log, which frames no
    corrected message): no rows; ``xyz`` quantises only the samples asked for (the view's)."""

    def __init__(self, batch: CorrectedBatch, quantum_g: float, scratch=None, words: bool = True):
        self.batch = batch
        self.quantum_g = quantum_g
        self.words = None
        self.view = None  # None: not framed yet; False: no view sample; else (records, indices)
        self.segment = batch.segment
        self.time_ns = batch.time_ns
        d = np.diff(batch.time_ns)
        dmin = int(d.min()) if d.size else 0
        self.ok = not d.size or (int(d.max()) <= INT32_MAX and dmin >= -INT32_MAX)
        self.sorted = dmin >= 0
        if self.ok and words:
            n = batch.n
            self.words = np.empty((4, n), "<u4")
            self.bytes = self.words.view(np.uint8)  # (4, 4 n)
            self.dt = self.words[0].view("<i4")
            q = self.words[1:].view("<f4")
            a = batch.accel.T
            if quantum_g:  # quantize(), into the rows, a row at a time (float64 scratch
                # reused across blocks)
                t = scratch(n) if scratch is not None else np.empty(n)
                for j in range(3):
                    np.multiply(a[j], 1.0 / quantum_g, out=t)
                    np.round(t, out=t)
                    np.multiply(t, quantum_g, out=q[j], casting="same_kind")
            else:
                np.copyto(q, a, casting="same_kind")
            self.x, self.y, self.z = q
            self.dt[0] = 0
            self.dt[1:] = d

    def tail(self, a: int, quantum_g: float) -> "_CorrectedRun":
        """Samples [a, n) of an already framed run (``a``: a message start, or 0), copied, so
        the step's arrays are not held into the next step (the same words: quantisation is per
        sample, and the copy's first step is 0 as the message start's is)."""
        b = self.batch
        t = _CorrectedRun(CorrectedBatch(b.time_ns[a:].copy(), b.accel[a:].copy(),
                                         b.temperature[a:].copy(), b.segment), quantum_g,
                          words=self.words is not None)
        t.view = self.view
        return t

    def cut(self, starts: list) -> None:
        """Messages will start at these indices: each starts its own deltas."""
        if self.words is not None:
            self.dt[starts] = 0

    def xyz(self, idx: np.ndarray) -> tuple:
        """The float32 x, y, z of samples ``idx``, quantised as the rows are (the same bits:
        the same float64 products, rounded, cast once)."""
        if self.words is not None:
            return self.x[idx], self.y[idx], self.z[idx]
        return tuple(quantize(self.batch.accel[idx], self.quantum_g).T)


class McapSink(McapLog):
    """Writes one run's MCAP (see module docstring) through ``McapLog`` (the one writer path:
    ``<name>.part`` renamed when finished). Use as a context manager or call close().

    ``writer``: "inline" (default), "thread" or "process" (see the module docstring).
    ``view_hz``: rate of the ``/view/accel`` topic (0: off). ``chunk_s``: data time a chunk
    spans (a multiple of ``flush_every_s``; default: one cell), i.e. the most a kill can lose
    beyond the step in progress. ``step_chunks``: also end the chunk at the end of every
    pipeline step, before its last cell (which may still grow), so a kill loses only the step
    in progress and the open cell whatever ``chunk_s`` (the online mode's setting).
    """

    def __init__(self, path, info: DeviceInfo, settings: dict, *, flush_every_s: float = 10.0,
                 fsync_every_wall_s: float = 1.0, compression: str = "zstd",
                 chunk_size: int = CHUNK_SIZE, corrected_quantum_g: float = 2.0 ** -16,
                 message_s: float = 60.0, writer: str = "inline", zstd_level: int = ZSTD_LEVEL,
                 view_hz: float = 0.0, chunk_s: Optional[float] = None,
                 step_chunks: bool = False):
        framing = "inline"
        if writer == "thread":  # compression on a thread, given a second core (and the framing,
            if cores_available() < 2:  # when asked: framing_thread_on)
                writer = "inline"
            elif framing_thread_on():
                framing = "thread"
        super().__init__(path, compression=compression, chunk_size=chunk_size,
                         fsync_every_wall_s=fsync_every_wall_s, writer=writer,
                         zstd_level=zstd_level)
        self.flush_every_ns = int(flush_every_s * 1e9) if flush_every_s else None
        self.quantum = corrected_quantum_g
        self._cell: Optional[int] = None  # data-time cell (flush_every_s) being written
        self.cell_ns = self.flush_every_ns or int(message_s * 1e9)
        # chunks span a whole number of cells on the UTC grid (default: one cell)
        self.cells_per_chunk = max(1, int(round(chunk_s * 1e9 / self.cell_ns))) if chunk_s else 1
        self.step_chunks = bool(step_chunks)
        self._pending_corr: list[CorrectedBatch] = []
        self._corr_cell: Optional[int] = None
        self.flushes = 0
        self.view = ViewDecimator(view_hz) if view_hz else None
        from ..settings import is_lean
        self.lean = is_lean(settings)  # no per-sample topics (LEAN_DROPPED)
        self._framer: Optional[OrderedWorker] = None
        try:
            self.write_metadata("device", device_metadata(info))
            self.write_metadata("settings", {"json": dumps(settings)})
            if framing == "thread":
                self._framer = OrderedWorker("mcap-framing", FRAMING_DEPTH)
        except BaseException:
            self.abort()
            raise

    block_framing = True  # False: always the cell-by-cell path (same bytes; for tests)
    _scratch = None

    def _tmp(self, n: int) -> np.ndarray:
        """An (n,) float64 scratch array, reused from block to block."""
        if self._scratch is None or self._scratch.shape[0] < n:
            self._scratch = np.empty(max(n, 1))
        return self._scratch[:n]

    # ------------------------------------------------------------------ the framing thread
    def _later(self) -> bool:
        """True when calls are to be handed to the framing thread (made by the engine, not by
        a call already running there)."""
        f = getattr(self, "_framer", None)
        return f is not None and not f.on_worker()

    def _stop_framing(self, drain: bool) -> None:
        f = getattr(self, "_framer", None)
        if f is None or f.on_worker():
            return
        if drain:  # raises what a framing call raised (or an interrupt while waiting: then
            f.drain()  # abort() stops the thread before the file is abandoned)
        else:
            f.stop()
        self._framer = None

    def _msg(self, topic, encoding, schema, log_time, data):
        ch = self._chunk
        if ch.add(ch.channel(topic, encoding, schema), log_time, data):
            self._end_chunk(False)

    def _flush_cell(self, fsync: bool = False) -> None:
        self.flushes += 1
        self._end_chunk(fsync)

    # ------------------------------------------------------------------ API
    def write_raw(self, block: Block, a: int = 0, b: Optional[int] = None, ua: int = 0,
                  ub: Optional[int] = None) -> None:
        """Log samples [a, b) of a Block (units [ua, ub), whole) losslessly; a time step that
        does not fit int32 ns splits the message."""
        b = block.n if b is None else b
        ub = block.m if ub is None else ub
        if b <= a:
            return
        d = np.diff(block.time_ns[a:b])
        if d.size and (d.max() > 2**31 - 1 or d.min() < -(2**31 - 1)):
            # rare (a clock jump inside a segment): split where the step does not fit
            cut = a + int(np.argmax(np.abs(d) > 2**31 - 1)) + 1
            self.write_raw(block.slice(a, cut))
            self.write_raw(block.slice(cut, b))
            return
        dt = np.empty(b - a, np.int32)
        dt[0] = 0
        dt[1:] = d
        t0 = int(block.time_ns[a])
        self._msg(TOPIC_RAW, "cdr", ACCEL_BATCH_RAW.name, t0, raw_message(block, a, b, ua, ub, dt))
        if block.gyro is not None:
            self._msg(TOPIC_GYRO, "cdr", GYRO_BATCH_RAW.name, t0, gyro_message(block, a, b, dt))
        if ub > ua:
            tc = block.temperature_c[ua:ub]
            ok = np.isfinite(tc)
            if ok.any():
                self._msg(TOPIC_TEMPERATURE, "cdr", TEMPERATURE.name, t0,
                          TEMPERATURE.encode({"stamp": t0, "celsius": float(tc[ok].mean())}))

    def write_corrected(self, batch: CorrectedBatch) -> None:
        if batch.n == 0:
            return
        if not max_step_ok(batch.time_ns):
            d = np.abs(np.diff(batch.time_ns))
            cut = int(np.argmax(d > 2**31 - 1)) + 1
            for a, b in ((0, cut), (cut, batch.n)):
                self.write_corrected(CorrectedBatch(batch.time_ns[a:b], batch.accel[a:b],
                                                    batch.temperature[a:b], batch.segment))
            return
        self._msg(TOPIC_CORRECTED, "cdr", ACCEL_BATCH.name, int(batch.time_ns[0]),
                  corrected_message(batch, self.quantum))

    def write_epochs(self, m: EpochMetrics) -> None:
        if len(m):
            ch = self._chunk
            if ch.add_fixed(ch.channel(TOPIC_METRICS, "cdr", EPOCH_METRICS.name), m.start_ns,
                            epoch_records(m)):
                self._end_chunk(False)

    def write_extras(self, extras: dict) -> None:
        """Log the optional epoch metrics of one step (``{"counts": EpochCounts, "mims":
        EpochMims}``) on their topics."""
        if self._later():
            self._framer.submit(self.write_extras, extras)
            return
        for key, topic, schema, records in (("counts", TOPIC_COUNTS, EPOCH_COUNTS, counts_records),
                                            ("mims", TOPIC_MIMS, EPOCH_MIMS, mims_records)):
            m = extras.get(key)
            if m is not None and len(m):
                ch = self._chunk
                if ch.add_fixed(ch.channel(topic, "cdr", schema.name), m.start_ns, records(m)):
                    self._end_chunk(False)

    def write_outcome(self, outcome: CalibrationOutcome, log_time_ns: int, **fields) -> None:
        """Log a calibration outcome on ``/calibration`` (``fields`` are added to the message)."""
        self.write_json(TOPIC_CALIBRATION, log_time_ns, outcome.message(**fields),
                        schema=CALIBRATION)

    def write_qc(self, event: dict, log_time_ns: int) -> None:
        self.write_json(TOPIC_QC, log_time_ns, event, schema=QC)

    # the engine's other calls: on the framing thread too, in the order made (JSON and metadata
    # values are encoded here, so a dict the caller changes later is logged as it was)
    def write(self, topic: str, encoding: str, schema, log_time: int, data: bytes) -> None:
        if self._later():
            self._framer.submit(super().write, topic, encoding, schema, log_time, bytes(data))
        else:
            super().write(topic, encoding, schema, log_time, data)

    def write_cdr(self, topic: str, cdr_type, log_time: int, values: dict) -> None:
        self.write(topic, "cdr", cdr_type, log_time, cdr_type.encode(values))

    def write_json(self, topic: str, log_time: int, obj, schema=None) -> None:
        self.write(topic, "json", schema, log_time, dumps(obj).encode())

    def write_metadata(self, name: str, values: dict) -> None:
        values = {k: (v if isinstance(v, str) else dumps(v)) for k, v in values.items()}
        if self._later():
            self._framer.submit(super().write_metadata, name, values)
        else:
            super().write_metadata(name, values)

    def write_slices(self, block: Optional[Block], corrected: list, epochs: EpochMetrics) -> None:
        """Write what one pipeline step produced (see ``_write_slices``; on the framing thread
        when there is one: the engine hands over arrays it does not change afterwards)."""
        if self._later():
            self._framer.submit(self._write_slices, block, corrected, epochs)
        else:
            self._write_slices(block, corrected, epochs)

    def _write_slices(self, block: Optional[Block], corrected: list, epochs: EpochMetrics) -> None:
        """Write what one pipeline step produced, by data time in cells of ``flush_every_s``
        (``message_s`` when flushing is off): the raw samples and epochs of a cell are written
        together and the MCAP is flushed each time a new cell begins, so a killed run loses at
        most the cell in progress (plus the correction's lag of one unit). Corrected samples are
        gathered per cell (and segment) into one message, driven by the corrected stream's own
        time, so the message layout does not depend on how the pipeline was cut (replay
        reproduces it exactly). Arrays are converted to their CDR types once per call
        (``_RawCells``, ``_CorrectedRun``); a message is then a few slices of them. Normally
        every message of the call is framed at once (``_frame_block``); this cell-by-cell
        loop handles the rest, with the same records in the same order. A lean log writes
        neither the block nor the corrected messages (the view stream still comes from them)."""
        if self.lean:
            block = None
        if self.block_framing and _frame_block(self, block, corrected, epochs):
            return
        w = self.cell_ns
        cells = []
        raw = None
        if block is not None and block.n:
            raw = _RawCells(block, w)
            cells.append(raw.cell)
        if len(epochs):
            cells.append(epochs.start_ns // w)
        todo = np.unique(np.concatenate(cells)) if cells else np.zeros(0, np.int64)
        pieces = []  # (cell, corrected run, a, b) in time order
        for c in corrected:
            if c.n == 0:
                continue
            run = _CorrectedRun(c, self.quantum, self._tmp, words=not self.lean)
            cc = c.time_ns // w
            edges = np.concatenate([[0], np.flatnonzero(cc[1:] != cc[:-1]) + 1, [c.n]]).tolist()
            ccl = cc[edges[:-1]].tolist()
            run.cut(edges[:-1])
            for k in range(len(edges) - 1):
                pieces.append((ccl[k], run, edges[k], edges[k + 1]))
        raw_cells = raw.cell.tolist() if raw is not None else []
        ep_lo = np.searchsorted(epochs.start_ns, todo * w).tolist() if len(epochs) else None
        ep_hi = np.searchsorted(epochs.start_ns, (todo + 1) * w).tolist() if len(epochs) else None
        j = 0
        k = 0
        ep_rec = None
        last = todo.shape[0] - 1
        for i, cell in enumerate(todo.tolist()):
            while j < len(pieces) and pieces[j][0] < cell:  # corrected data of earlier cells
                self._take_corrected(*pieces[j])
                j += 1
            if self._cell is None or cell > self._cell:
                if (self._cell is not None and self.flush_every_ns is not None
                        and (cell // self.cells_per_chunk != self._cell // self.cells_per_chunk
                             or (self.step_chunks and i == last))):
                    self._flush_cell(False)
                self._cell = cell
            while k < len(raw_cells) and raw_cells[k] < cell:
                k += 1
            if k < len(raw_cells) and raw_cells[k] == cell:
                raw.write(self, k)
            if ep_lo is not None and ep_hi[i] > ep_lo[i]:
                if ep_rec is None:  # every epoch of this call framed at once, appended per cell
                    ch = self._chunk
                    ep_rec = ch.prepare_fixed(ch.channel(TOPIC_METRICS, "cdr", EPOCH_METRICS.name),
                                              epochs.start_ns, epoch_records(epochs))
                if self._chunk.add_prepared(ep_rec, ep_lo[i], ep_hi[i]):
                    self._end_chunk(False)
        while j < len(pieces):
            self._take_corrected(*pieces[j])
            j += 1

    def _take_corrected(self, cell: int, run: "_CorrectedRun", a: int, b: int) -> None:
        if self.view is not None:
            self._write_view(run, a, b)
        if self._corr_cell is not None and cell != self._corr_cell:
            self._emit_corrected()
        self._corr_cell = cell
        self._pending_corr.append((run, a, b))

    def _prepare_view(self, run: "_CorrectedRun") -> None:
        """Frame the view messages of a whole corrected batch at once (``run.view``: the
        prepared records and, per sample index, how many view samples precede it)."""
        idx = self.view.pick(run.time_ns)
        run.view = False
        if not idx.size:
            return
        if run.ok:
            x, y, z = run.xyz(idx)
        else:
            x, y, z = quantize(run.batch.accel[idx], self.quantum).T
        t = run.time_ns[idx]
        cid = self.channel(TOPIC_VIEW, "cdr", VIEW_SAMPLE)
        run.view = (self._chunk.prepare_fixed(cid, t, view_records(t, x, y, z)), idx)

    def _write_view(self, run: "_CorrectedRun", a: int, b: int) -> None:
        """The view messages among corrected samples [a, b) of ``run`` (framed once per batch,
        when its first piece is written: batches are written in order, so sequence numbers
        follow each other)."""
        if run.view is None:
            self._prepare_view(run)
        if run.view is False:
            return
        fr, idx = run.view
        lo, hi = np.searchsorted(idx, (a, b)).tolist()
        if hi > lo and self._chunk.add_prepared(fr, lo, hi):
            self._end_chunk(False)

    def _emit_corrected(self) -> None:
        parts, self._pending_corr = self._pending_corr, []
        if self.lean:
            return
        i = 0
        while i < len(parts):
            j = i + 1
            while j < len(parts) and parts[j][0].segment == parts[i][0].segment:
                j += 1
            if j == i + 1 and parts[i][0].ok:
                run, a, b = parts[i]
                t0 = int(run.time_ns[a])
                self._msg(TOPIC_CORRECTED, "cdr", ACCEL_BATCH.name, t0, ACCEL_BATCH.encode_values(
                    [t0, t0, run.segment, run.dt[a:b], run.x[a:b], run.y[a:b], run.z[a:b]]))
            else:  # a cell spread over several corrected batches (or a huge time step): rare
                self.write_corrected(CorrectedBatch.concat([CorrectedBatch(
                    r.time_ns[a:b], r.batch.accel[a:b], r.batch.temperature[a:b], r.segment)
                    for r, a, b in parts[i:j]]))
            i = j

    def flush(self, fsync: bool = True) -> None:
        if self._later():
            self._framer.submit(self._flush_cell, fsync)
        else:
            self._flush_cell(fsync)

    def close(self):
        """Finish the file (summary, index, footer), wait for the writer, rename it."""
        self._stop_framing(drain=True)
        self._emit_corrected()
        return super().close()

    def abort(self):
        """Stop without finishing (see ``McapLog.abort``): the framing thread first, dropping
        the steps still waiting for it (the one being framed ends first)."""
        self._stop_framing(drain=False)
        return super().abort()



# ---------------------------------------------------------------------------- per-block framing
_TYPE_RAW, _TYPE_GYRO, _TYPE_TEMP, _TYPE_CORR, _TYPE_VIEW, _TYPE_EPOCH = range(6)
_UNIT_FIELDS = ("unit_index", "unit_sequence", "unit_start", "temperature_c", "temperature_raw",
                "light", "battery_v", "events")  # the raw message's per-unit sequences (_RawCells.units)
_RAW_SEQUENCES = tuple(f for f, t in ACCEL_BATCH_RAW.fields if t.endswith("[]"))
_TEMP_PAYLOAD = np.dtype([("hdr", "V4"), ("sec", "<i4"), ("nsec", "<u4"), ("celsius", "<f8")])
assert _TEMP_PAYLOAD.itemsize == 20, TEMPERATURE.name


def _cell_runs(t: np.ndarray, w: int) -> tuple[np.ndarray, np.ndarray]:
    """Start index and cell of each run of one cell in the nondecreasing times ``t`` (cell
    edges found by binary search, not a division per sample)."""
    c0, c1 = int(t[0]) // w, int(t[-1]) // w
    if c1 == c0:
        return np.zeros(1, np.int64), np.array([c0], np.int64)
    e = np.searchsorted(t, np.arange(c0 + 1, c1 + 1, dtype=np.int64) * w, side="left")
    e = np.unique(np.concatenate([np.zeros(1, np.int64), e]))
    return e, t[e] // w


def _frame_block(sink: "McapSink", block: Optional[Block], corrected: list,
                 epochs: EpochMetrics) -> bool:
    """``McapSink.write_slices`` for one pipeline step with every message of the step framed
    at once: the records of each topic are built back to back in one buffer
    (engine/mcap/blockframe.py: fixed-size ones as one structured array, raw and corrected ones
    from their layouts, per-sample arrays copied one slice per message), then handed to the
    chunk builder as slices of those buffers in the cell-by-cell path's order (so the file is
    byte for byte the same). The cell-by-cell path still handles what this does not: a time
    step that does not fit int32 ns or goes backwards, a step spanning segments, flushing off,
    or a topic's first message (its Schema and Channel records go into the chunk before it).
    Returns False (nothing written, no state changed) in those cases."""
    from . import blockframe as bf

    if sink.flush_every_ns is None:
        return False
    w = sink.cell_ns
    ch = sink._chunk
    ids = ch.channel_ids
    # ------------------------------------------------------------ what the step holds
    raw = None
    if block is not None and block.n:
        raw = _RawCells(block, w)
        if not raw.ok or (raw.cell.shape[0] > 1 and bool(np.any(raw.cell[1:] <= raw.cell[:-1]))):
            return False
    runs = [_CorrectedRun(c, sink.quantum, sink._tmp, words=not sink.lean) for c in corrected if c.n]
    pend = [p for p in sink._pending_corr if p[2] > p[1]]
    if not all(r.ok and r.sorted for r in runs) or not all(r.ok for r, _a, _b in pend):
        return False
    if len({r.segment for r in runs} | {r.segment for r, _a, _b in pend}) > 1:
        return False
    ne = len(epochs)
    if ne > 1 and bool(np.any(epochs.start_ns[1:] < epochs.start_ns[:-1])):
        return False
    last_t = int(pend[-1][0].time_ns[pend[-1][2] - 1]) if pend else None
    for r in runs:  # joins between batches: nondecreasing, int32 steps
        if last_t is not None and not 0 <= int(r.time_ns[0]) - last_t <= INT32_MAX:
            return False
        last_t = int(r.time_ns[-1])
    # pieces of this step: one cell of one batch each
    pa, pc, pr, first_piece, edges = [], [], [], [], []
    for ri, r in enumerate(runs):
        e, c = _cell_runs(r.time_ns, w)
        first_piece.append(sum(len(x) for x in pa))
        edges.append(e)
        pa.append(e)
        pc.append(c)
        pr.append(np.full(e.shape[0], ri, np.int64))
    pa = np.concatenate(pa) if pa else np.zeros(0, np.int64)
    pc = np.concatenate(pc) if pc else np.zeros(0, np.int64)
    pr = np.concatenate(pr) if pr else np.zeros(0, np.int64)
    pb = np.empty_like(pa)  # piece ends
    if pa.shape[0]:
        pb[:-1] = pa[1:]
        last_of_run = np.append(pr[1:] != pr[:-1], True)
        pb[last_of_run] = [r.batch.n for r in runs]
    if pend and pc.shape[0] and int(pc[0]) < sink._corr_cell:
        return False
    # groups (one corrected message each): a piece opens one when its cell differs from the
    # previous piece's (the first piece: from the pending samples' cell)
    newg = np.empty(pc.shape[0], bool)
    if pc.shape[0]:
        newg[0] = not pend or int(pc[0]) != sink._corr_cell
        np.not_equal(pc[1:], pc[:-1], out=newg[1:])
    gj = np.flatnonzero(newg)  # pieces opening a group
    msgs = []  # emitted messages: (piece that emits it, [(run, a, b), ...])
    piece = [(runs[r], a, b) for r, a, b in zip(pr.tolist(), pa.tolist(), pb.tolist())]
    bounds = gj.tolist() + [pa.shape[0]]
    prev = list(pend) + piece[:bounds[0]]
    for q in range(gj.shape[0]):
        if prev:
            msgs.append((bounds[q], prev))
        prev = piece[bounds[q]:bounds[q + 1]]
    new_pending = prev
    # ------------------------------------------------------------ channels in use
    need = []
    if raw is not None:
        need.append(TOPIC_RAW)
        if raw.gyro is not None:
            need.append(TOPIC_GYRO)
    if ne:
        need.append(TOPIC_METRICS)
    if msgs and not sink.lean:
        need.append(TOPIC_CORRECTED)
    if sink.view is not None and runs:
        need.append(TOPIC_VIEW)
    if raw is not None:
        ua, ub = np.asarray(raw.ua, np.int64), np.asarray(raw.ub, np.int64)
        a_, b_ = np.asarray(raw.a, np.int64), np.asarray(raw.b, np.int64)
        rk = np.flatnonzero(b_ > a_)
        temp_cells = np.flatnonzero((b_ > a_) & (ub > ua) & np.asarray(raw.temp_ok, bool))
        if temp_cells.shape[0]:
            need.append(TOPIC_TEMPERATURE)
    if any(t not in ids for t in need):
        return False
    # ------------------------------------------------------------ from here on: writing
    cells = []
    if raw is not None:
        cells.append(raw.cell)
    if ne:
        cells.append(epochs.start_ns // w)
    todo = np.unique(np.concatenate(cells)) if cells else np.zeros(0, np.int64)
    T = todo.shape[0]
    for r, e in zip(runs, edges):
        r.cut(e)
    pit = np.searchsorted(todo, pc, side="right")  # the loop iteration that takes each piece
    # per topic: its records (buffer, record offsets) and their order keys
    topics = []  # (type, buffer (uint8), offsets (k+1), times, key: iteration, phase, piece, sub)

    def add(typ, buf, off, times, it, phase, piece, sub):
        k = times.shape[0]
        topics.append((typ, buf, off, times, np.asarray(it, np.int64), np.full(k, phase, np.int64),
                       np.asarray(piece, np.int64) if np.ndim(piece) else np.full(k, piece, np.int64),
                       np.full(k, sub, np.int64)))

    def fixed(typ, payload, times, it, phase, piece, sub):
        cid = ids[topic_of[typ]]
        a = bf.fixed_records(payload, cid, ch.sequence(cid), times)
        add(typ, a.view(np.uint8).reshape(-1), np.arange(times.shape[0] + 1, dtype=np.int64)
            * a.dtype.itemsize, times, it, phase, piece, sub)

    topic_of = {_TYPE_RAW: TOPIC_RAW, _TYPE_GYRO: TOPIC_GYRO, _TYPE_TEMP: TOPIC_TEMPERATURE,
                _TYPE_CORR: TOPIC_CORRECTED, _TYPE_VIEW: TOPIC_VIEW, _TYPE_EPOCH: TOPIC_METRICS}
    if raw is not None and rk.shape[0]:
        kk = rk.shape[0]
        rit = np.searchsorted(todo, raw.cell[rk])
        s0 = a_[rk]
        t0 = block.time_ns[s0]
        tc = np.maximum(t0, 0)
        n_s, n_u = b_[rk] - s0, ub[rk] - ua[rk]
        z = np.zeros_like(n_s)
        lens = {f: n_s for f in ("dt_ns", "x", "y", "z")}
        lens.update({f: n_u for f in ("unit_index", "unit_sequence", "unit_start", "temperature_c",
                                      "temperature_raw", "light", "battery_v", "events")})
        lens["light_raw"] = n_s if raw.light_raw is not None else z
        lens["button"] = n_s if raw.button is not None else z
        lay = bf.CdrLayout(ACCEL_BATCH_RAW, kk, lens)
        cid = ids[TOPIC_RAW]
        vr = bf.VariableRecords(lay, cid, ch.sequence(cid), tc, slack=8)
        buf, base = vr.buf, vr.base
        lay.put_head(buf, base, {"stamp": t0, "t0_ns": t0, "segment": raw.head[0],
                                 "first_sample": block.first_sample + s0,
                                 "counts_per_g": raw.head[2], "zero_counts": raw.head[3]})
        sl, nl = s0.tolist(), n_s.tolist()
        lay.put_counts_of(buf, base, _RAW_SEQUENCES, [lens[f] for f in _RAW_SEQUENCES])
        for f, src in (("dt_ns", raw.dt), ("light_raw", raw.light_raw), ("button", raw.button)):
            if src is not None:
                lay.put_seq_slices(buf, base, f, src, sl, nl)
        bf.put_rows(buf, base + lay.field["x"][2], lay.field["y"][2] - lay.field["x"][2],
                    raw.xyz, sl, nl)
        u0, u1 = int(ua[rk][0]), int(ub[rk][-1])
        lay.put_seq_runs_of(buf, base, _UNIT_FIELDS, [arr[u0:u1] for arr in raw.units], n_u)
        add(_TYPE_RAW, buf, vr.off, tc, rit, 2, 0, 0)
        if raw.gyro is not None:
            glay = bf.CdrLayout(GYRO_BATCH_RAW, kk, {f: n_s for f in ("dt_ns", "x", "y", "z")})
            cid = ids[TOPIC_GYRO]
            gr = bf.VariableRecords(glay, cid, ch.sequence(cid), tc, slack=8)
            glay.put_head(gr.buf, gr.base, {"stamp": t0, "t0_ns": t0,
                                            "dps_per_count": float(block.gyro_dps_per_count)})
            glay.put_counts_of(gr.buf, gr.base, ("dt_ns", "x", "y", "z"), [n_s] * 4)
            glay.put_seq_slices(gr.buf, gr.base, "dt_ns", raw.dt, sl, nl)
            bf.put_rows(gr.buf, gr.base + glay.field["x"][2], glay.field["y"][2] - glay.field["x"][2],
                        raw.gyro, sl, nl)
            add(_TYPE_GYRO, gr.buf, gr.off, tc, rit, 2, 0, 1)
        if temp_cells.shape[0]:
            tt = block.time_ns[a_[temp_cells]]
            tp = np.zeros(tt.shape[0], _TEMP_PAYLOAD)
            tp["hdr"] = np.void(b"\x00\x01\x00\x00")
            tb = bf.time_bytes(tt).view(np.dtype([("sec", "<i4"), ("nsec", "<u4")])).reshape(-1)
            tp["sec"], tp["nsec"] = tb["sec"], tb["nsec"]
            tp["celsius"] = np.asarray(raw.temp, np.float64)[temp_cells]
            fixed(_TYPE_TEMP, tp, np.maximum(tt, 0), np.searchsorted(todo, raw.cell[temp_cells]),
                  2, 0, 2)
    if msgs and not sink.lean:
        m = len(msgs)
        mj = np.array([j for j, _p in msgs], np.int64)
        n_ml = [sum(b - a for _r, a, b in p) for _j, p in msgs]
        n_m = np.array(n_ml, np.int64)
        t0 = np.array([p[0][0].time_ns[p[0][1]] for _j, p in msgs], np.int64)
        tc = np.maximum(t0, 0)
        clay = bf.CdrLayout(ACCEL_BATCH, m, {f: n_m for f in ("dt_ns", "x", "y", "z")})
        cid = ids[TOPIC_CORRECTED]
        cr = bf.VariableRecords(clay, cid, ch.sequence(cid), tc, slack=8)
        buf, base = cr.buf, cr.base
        clay.put_head(buf, base, {"stamp": t0, "t0_ns": t0, "segment": msgs[0][1][0][0].segment})
        clay.put_counts_of(buf, base, ("dt_ns", "x", "y", "z"), [n_m] * 4)
        # dt_ns, x, y, z: 4-byte rows, each after its count: one (4, n) copy per piece
        fo = (base + clay.field["dt_ns"][2]).tolist()
        for i, (_j, p) in enumerate(msgs):
            stride = 4 * n_ml[i] + 4
            region = buf[fo[i]:fo[i] + 4 * stride].reshape(4, stride)
            if len(p) == 1:  # one piece of one batch (most messages)
                r, a, b = p[0]
                region[:, :4 * (b - a)] = r.bytes[:, 4 * a:4 * b]
                continue
            at = 0
            prev_t = None
            for r, a, b in p:
                region[:, 4 * at:4 * (at + b - a)] = r.bytes[:, 4 * a:4 * b]
                if prev_t is not None:  # a join inside the message: its own step, not 0
                    region[0, 4 * at:4 * at + 4] = np.array([int(r.time_ns[a]) - prev_t], "<i4").view(np.uint8)
                prev_t = int(r.time_ns[b - 1])
                at += b - a
        add(_TYPE_CORR, buf, cr.off, tc, pit[mj], 0, mj, 1)
    if sink.view is not None and runs:
        vidx = [sink.view.pick_sorted(r.time_ns) for r in runs]
        for r in runs:
            r.view = False  # framed here
        vt = np.concatenate([r.time_ns[i] for r, i in zip(runs, vidx)])
        if vt.shape[0]:
            vj = np.concatenate([fp + np.searchsorted(e, i, side="right") - 1
                                 for fp, e, i in zip(first_piece, edges, vidx)])
            vq = [r.xyz(i) for r, i in zip(runs, vidx)]
            vp = view_records(vt, *(np.concatenate([q[k] for q in vq]) for k in range(3)))
            fixed(_TYPE_VIEW, vp, np.maximum(vt, 0), pit[vj], 0, vj, 0)
    if ne:
        fixed(_TYPE_EPOCH, epoch_records(epochs), np.maximum(epochs.start_ns, 0),
              np.searchsorted(todo, epochs.start_ns // w), 3, 0, 0)
    # ------------------------------------------------------------ flushes (new chunk spans)
    flush = np.zeros(T, bool)
    if T:
        prevc = np.empty(T, np.int64)
        prevc[1:] = todo[:-1] if sink._cell is None else np.maximum(todo[:-1], sink._cell)
        prevc[0] = todo[0] if sink._cell is None else sink._cell
        cpc = sink.cells_per_chunk
        flush = (todo > prevc) & (todo // cpc != prevc // cpc)
        if sink.step_chunks:  # the chunk also ends before the step's last cell
            flush[-1] = todo[-1] > prevc[-1]
        if sink._cell is None:
            flush[0] = False
        sink._cell = int(todo[-1]) if sink._cell is None else max(sink._cell, int(todo[-1]))
    # ------------------------------------------------------------ pending corrected samples
    if runs:  # the open cell's samples, copied out of this step's batches (each a run's tail)
        sink._pending_corr = [(r.tail(a, sink.quantum), 0, b - a) if b == r.batch.n else (r, a, b)
                              for r, a, b in new_pending]
        sink._corr_cell = int(pc[-1])
    # ------------------------------------------------------------ records in file order
    if topics:
        typ = np.concatenate([np.full(t[3].shape[0], i, np.int64) for i, t in enumerate(topics)])
        idx = np.concatenate([np.arange(t[3].shape[0], dtype=np.int64) for t in topics])
        it = np.concatenate([t[4] for t in topics])
        ph = np.concatenate([t[5] for t in topics])
        order = np.lexsort((idx, np.concatenate([t[7] for t in topics]),
                            np.concatenate([t[6] for t in topics]), ph, it))
        typ, idx, it, ph = typ[order], idx[order], it[order], ph[order]
        size = np.concatenate([np.diff(t[2]) for t in topics])[order]
        times = np.concatenate([t[3] for t in topics])[order]
        cids = np.array([ids[topic_of[t[0]]] for t in topics], np.int64)[typ]
        # the cell-by-cell path checks the chunk size after each message, but after all the
        # view messages of a piece, or all the epochs of a cell, at once: where may it end?
        kind = np.array([t[0] for t in topics], np.int64)[typ]
        grp = np.where(kind == _TYPE_VIEW, np.concatenate([t[6] for t in topics])[order], it)
        runs_of = (kind == _TYPE_VIEW) | (kind == _TYPE_EPOCH)
        ends = np.ones(typ.shape[0], bool)
        ends[:-1] = ~(runs_of[:-1] & (kind[1:] == kind[:-1]) & (grp[1:] == grp[:-1]))
    else:
        typ = idx = it = ph = size = times = cids = np.zeros(0, np.int64)
        ends = np.zeros(0, bool)
    R = typ.shape[0]
    roff = np.zeros(R + 1, np.int64)
    np.cumsum(size, out=roff[1:])
    views = [memoryview(t[1]) for t in topics]
    offl = [t[2].tolist() for t in topics]
    topic_cids = [ids[topic_of[t[0]]] for t in topics]
    # runs of consecutive records of one topic: each is one slice of that topic's buffer
    rs = np.flatnonzero(np.concatenate([[True], (typ[1:] != typ[:-1]) | (idx[1:] != idx[:-1] + 1)])) \
        if R else np.zeros(0, np.int64)
    rs_l, rt_l, ri_l = rs.tolist() + [R], typ[rs].tolist(), idx[rs].tolist()
    # messages per topic before each record (for the channel counts of each piece appended)
    cum = np.zeros((R + 1, len(topics)), np.int64)
    if R:
        np.cumsum(typ[:, None] == np.arange(len(topics)), axis=0, out=cum[1:])
    roff_l = roff.tolist()

    def pieces(lo, hi):
        """The records [lo, hi): slices of the topic buffers, and the channel of each."""
        k = bisect.bisect_right(rs_l, lo) - 1
        parts, part_cids = [], []
        while rs_l[k] < hi:
            s0, e0 = max(rs_l[k], lo), min(rs_l[k + 1], hi)
            t = rt_l[k]
            a = ri_l[k] + s0 - rs_l[k]
            parts.append(views[t][offl[t][a]:offl[t][a + e0 - s0]])
            part_cids.append(topic_cids[t])
            k += 1
        return parts, part_cids

    def counts(lo, hi):
        n = (cum[hi] - cum[lo]).tolist()
        return {c: k for c, k in zip(topic_cids, n) if k}

    def append(lo, hi):
        """Hand the records [lo, hi) to the chunk builder."""
        parts, part_cids = pieces(lo, hi)
        ch.add_framed(parts, roff_l[hi] - roff_l[lo], cids[lo:hi], times[lo:hi],
                      roff[lo:hi] - roff_l[lo], counts(lo, hi), part_cids)

    def whole(ranges):
        """Flush ranges that are chunks by themselves, all at once (ChunkBuilder.whole_chunks):
        each chunk's records in grouped order (as ChunkBuilder.take orders them: channels by
        first appearance, each in its order), one writer operation for all; the same bytes
        as one chunk after another."""
        lo, hi = ranges[0][0], ranges[-1][1]
        b = np.array([r[0] for r in ranges] + [hi], np.int64)
        n = hi - lo
        k = np.repeat(np.arange(len(ranges), dtype=np.int64), np.diff(b))
        c = cids[lo:hi]
        _u, first, inv = np.unique(k * 65536 + c, return_index=True, return_inverse=True)
        perm = np.lexsort((np.arange(n), first[inv]))  # by chunk, channel's first record, order
        ty, ix, sz = typ[lo:hi][perm], idx[lo:hi][perm], size[lo:hi][perm]
        off = np.zeros(n + 1, np.int64)
        np.cumsum(sz, out=off[1:])
        starts = np.flatnonzero(np.concatenate([[True], (ty[1:] != ty[:-1]) | (ix[1:] != ix[:-1] + 1)]))
        parts = []
        for a, e, t, i in zip(starts.tolist(), starts[1:].tolist() + [n], ty[starts].tolist(),
                              ix[starts].tolist()):
            parts.append(views[t][offl[t][i]:offl[t][i + e - a]])
        op = ch.whole_chunks(b"".join(parts), off[b - lo], c[perm], times[lo:hi][perm], off[:-1],
                             counts(lo, hi))
        sink.flushes += len(ranges)
        sink._send(("chunks", *op, False))

    # records before the flush at iteration f: earlier iterations, and f's phase 0 (pieces)
    key = it * 2 + (ph > 0)
    cut_at = np.searchsorted(key, np.flatnonzero(flush) * 2 + 1, side="left")
    # a flush range is a chunk by itself when it starts an empty chunk and is smaller than a
    # chunk: framed with the others like it at once (``whole``)
    lo_r = np.concatenate([[0], cut_at[:-1]]) if cut_at.shape[0] else cut_at
    whole_ok = ((cut_at > lo_r) & (roff[cut_at] - roff[lo_r] < ch.chunk_size)).tolist()
    cut_at = cut_at.tolist()
    lo = 0
    batch = []  # whole-chunk ranges not yet handed over
    for j, (c, flush_after) in enumerate([(c, True) for c in cut_at] + [(R, False)]):
        if flush_after and whole_ok[j] and (batch or not ch._parts):
            batch.append((lo, c))
            lo = c
            continue
        if batch:
            whole(batch)
            batch = []
        while lo < c:  # records [lo, c); the chunk ends where it reaches chunk_size
            room = ch.chunk_size - ch.size
            hi = c
            if roff_l[c] - roff_l[lo] >= room:
                over = np.flatnonzero(ends[lo:c] & (roff[lo + 1:c + 1] - roff_l[lo] >= room))
                hi = lo + int(over[0]) + 1 if over.shape[0] else c
            append(lo, hi)
            if hi < c or (hi == c and roff_l[hi] - roff_l[lo] >= room and ends[hi - 1]):
                sink._end_chunk(False)
            lo = hi
        if flush_after:
            sink._flush_cell(False)
    ch.detach()  # the open chunk's records, out of this step's buffers
    return True
