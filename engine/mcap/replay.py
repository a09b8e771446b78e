"""``McapRawSource``: the raw channel of a stillpoint MCAP log as a Source.

Replays ``/raw/accel`` (and ``/raw/gyro`` for AX6) message by message and returns exactly the
Blocks that were logged (same samples, times, counts, scales, per-unit arrays, segments). The
``DeviceInfo`` comes from the ``device`` metadata record and ``settings`` (the original run's
settings) is exposed so replay can compare or reuse them. Reader QC events logged on ``/qc``
(``source == "reader"``) are restored into ``qc``. Reads linearly (file order) with
engine/mcap/stream.py, one chunk at a time, guided by the message indexes, so memory stays flat
however long the log; a recovered file replays too. Consecutive raw messages of one segment are
joined into larger Blocks (fewer, larger blocks make replay about as fast as processing the
recording) -- but never two messages of the same data-time cell, so the sink cuts the joined
Blocks into exactly the logged raw messages again.
"""

from __future__ import annotations

from pathlib import Path
from typing import Iterator, Optional

import numpy as np

from stillpoint.drivers import constants as C
from stillpoint.drivers.byteio import check_recording_path
from stillpoint.engine.core.errors import CorruptRecordingError, StillpointError, UnsupportedFormatError
from stillpoint.drivers.sniff import MCAP_MAGIC, sniff_format
from stillpoint.engine.core.blocks import (Block, DeviceInfo, PER_SAMPLE_BUTTON, PER_SAMPLE_IDLE_SLEEP,
                                           PER_SAMPLE_LIGHT_RAW, QCEvent, QCReport)

from .reading import McapReadError, check_raw_message, decode, loads_json
from .schemas import ACCEL_BATCH_RAW, GYRO_BATCH_RAW, times_from_deltas
from .stream import iter_messages, read_metadata

NOT_A_STILLPOINT_LOG = "MCAP has no 'device' metadata record: not a stillpoint log"
LEAN_LOG = ("is a lean log: it keeps the estimates, QC, epoch metrics, sleep and view stream, "
            "not the raw samples this needs; `stillpoint replay LOG --raw RECORDING` re-runs it "
            "from the recording (--log full brings the per-sample streams back)")
TOPIC_RAW = "/raw/accel"
TOPIC_GYRO = "/raw/gyro"
TOPIC_QC = "/qc"
JOIN_FRACTION = 0.5  # a joined Block holds at most this fraction of the pipeline's block bound


_KIND = {"cwa": "AX3/AX6 .cwa", "geneactiv": "GENEActiv .bin", "gt3x": "ActiGraph .gt3x"}


def check_is_log(path) -> None:
    """Refuse, in one line, a file that is not an MCAP at all before any MCAP reader names its
    damage: a recording (``.cwa``, ``.bin``, ``.gt3x``, plain or gzipped) is named as such, with
    the command that makes its log; anything else as not an MCAP file. Every command that reads
    a log (``view``, ``report``, ``replay``, ``recover``, ``export``) starts here."""
    p = Path(path)
    check_recording_path(p)
    with open(p, "rb") as f:
        if f.read(len(MCAP_MAGIC)) == MCAP_MAGIC:
            return
    try:
        fmt = sniff_format(p)
    except Exception:  # noqa: BLE001 - neither a recording nor a log: said below
        fmt = None
    if fmt is not None and fmt != "mcap":
        raise UnsupportedFormatError(
            p, f"is a recording ({_KIND.get(fmt, fmt)}), not a stillpoint log: run "
               f"`stillpoint process {p}` first")
    raise UnsupportedFormatError(p, "not a stillpoint log: an MCAP file starts with the bytes "
                                    "\\x89MCAP0 (this one does not)")


def _qc_event(path, topic: str, i: int, data) -> Optional[QCEvent]:
    """A reader QC event logged on /qc (None for the engine's own events)."""
    ev = loads_json(path, topic, i, data)
    if not isinstance(ev, dict):
        raise McapReadError(path, "QC message is not a JSON object", channel=topic, record=f"message {i}")
    if ev.get("source") != "reader":
        return None
    try:
        t = ev.get("time_ns")
        e = ev.get("end_ns")
        return QCEvent(int(ev.get("index", -1)), str(ev.get("reason", "")), str(ev.get("detail", "")),
                       None if t is None else int(t), int(ev.get("samples", 0)),
                       None if e is None else int(e))
    except (TypeError, ValueError, OverflowError) as e:
        raise McapReadError(path, f"QC event fields are not numbers ({e})", channel=topic,
                            record=f"message {i}") from None


def idle_mask(t: np.ndarray, periods: list) -> np.ndarray:
    """(n,) uint8: 1 for the times inside one of the [start, end) periods."""
    out = np.zeros(t.shape[0], np.uint8)
    for a, b in periods:
        if a <= t[-1] and b > t[0]:
            i, j = np.searchsorted(t, [a, b])
            out[i:j] = 1
    return out


def block_from_message(raw: dict, gyro: Optional[dict] = None) -> Block:
    """The Block of one decoded ``/raw/accel`` message (and its ``/raw/gyro`` twin)."""
    t = times_from_deltas(raw["t0_ns"], raw["dt_ns"])
    accel = np.stack([raw["x"], raw["y"], raw["z"]], axis=1).astype(np.int16)
    per = {}
    if len(raw["light_raw"]):
        per[PER_SAMPLE_LIGHT_RAW] = raw["light_raw"].copy()
    if len(raw["button"]):
        per[PER_SAMPLE_BUTTON] = raw["button"].copy()
    return Block(
        time_ns=t, accel=accel,
        accel_counts_per_g=raw["counts_per_g"].astype(np.float64),
        accel_zero=raw["zero_counts"].astype(np.float64),
        gyro=(None if gyro is None else np.stack([gyro["x"], gyro["y"], gyro["z"]], axis=1).astype(np.int16)),
        gyro_dps_per_count=(None if gyro is None else float(gyro["dps_per_count"])),
        unit_index=raw["unit_index"].astype(np.int64), unit_sequence=raw["unit_sequence"].astype(np.int64),
        unit_start=raw["unit_start"].astype(np.int64), temperature_c=raw["temperature_c"].astype(np.float64),
        temperature_raw=raw["temperature_raw"].astype(np.int32), light=raw["light"].astype(np.int32),
        battery_v=raw["battery_v"].astype(np.float64), events=raw["events"].astype(np.uint8),
        per_sample=per, segment=int(raw["segment"]), first_sample=int(raw["first_sample"]))


def _device_info(meta: dict, path: Path) -> DeviceInfo:
    """The ``device`` metadata record as a DeviceInfo, every field checked (a typed error names
    the field: a damaged record must not reach the engine)."""
    d = loads_json(path, None, "device", meta.get("json", ""), what="metadata")

    def bad(why: str):
        raise McapReadError(path, f"device metadata: {why}", record="metadata 'device'")

    if not isinstance(d, dict):
        bad("not a JSON object")
    known = DeviceInfo.__dataclass_fields__
    d = {k: v for k, v in d.items() if k in known}
    kind = d.get("device_type")
    if kind not in ("AX3", "AX6", "GENEActiv", "ActiGraph"):
        bad(f"device_type {kind!r} is not AX3, AX6, GENEActiv or ActiGraph")
    rate = d.get("sample_rate_nominal")
    lo, hi = (C.CWA_RATE_RANGE_HZ if kind.startswith("AX") else C.PLAUSIBLE_RATE_HZ)
    if not isinstance(rate, (int, float)) or isinstance(rate, bool) or not lo <= rate <= hi:
        bad(f"sample_rate_nominal {rate!r} is not a rate a {kind} records at ({lo:g}..{hi:g} Hz)")
    rng = d.get("accel_range_g")
    if not isinstance(rng, (int, float)) or not 0 < rng <= 1000:
        bad(f"accel_range_g {rng!r} is not a range in g")
    gyro = d.get("gyro_range_dps")
    if gyro is not None and (not isinstance(gyro, (int, float)) or not 0 < gyro <= 100_000):
        bad(f"gyro_range_dps {gyro!r} is not a range in dps")
    ch = d.get("channels", ())
    if not isinstance(ch, (list, tuple)) or not all(isinstance(c, str) for c in ch):
        bad("channels is not a list of names")
    tz = d.get("timezone_offset_s", 0)
    if not isinstance(tz, int) or abs(tz) > 86_400:
        bad(f"timezone_offset_s {tz!r} is not an offset in seconds")
    for k in ("device_id", "firmware"):
        if k in d and not isinstance(d[k], (str, int)):
            bad(f"{k} {d[k]!r} is not text")
        if k in d:
            d[k] = str(d[k])
    for k in ("metadata", "header"):
        if k in d and not isinstance(d[k], dict):
            bad(f"{k} is not an object")
    d["channels"] = tuple(ch)
    d["path"] = str(path)
    try:
        return DeviceInfo(**d)
    except TypeError as e:
        bad(str(e))


def _check_order(prev: Optional[tuple], b: Block, path, i: int) -> tuple:
    """A logged raw stream is in order: sample numbers rise from message to message (a recovered
    log may miss some), segments never go back, and times never go back inside a segment (a
    message's own times included). Anything else is a damaged log: a typed error naming the
    message, never a buffer overflow in the engine or a silently reordered stream. Returns the
    state for the next message."""
    def bad(why: str):
        raise McapReadError(path, f"raw messages out of order: {why}; the log is damaged",
                            channel=TOPIC_RAW, record=f"message {i}")

    t = b.time_ns
    if b.n > 1 and (t[1:] < t[:-1]).any():
        k = int(np.flatnonzero(t[1:] < t[:-1])[0])
        bad(f"time goes back {int(t[k] - t[k + 1])} ns after sample {k} of the message")
    if prev is not None:
        seg, end, last = prev
        if b.first_sample < end:
            bad(f"it starts at sample {b.first_sample}, before the end of the previous message "
                f"(sample {end})")
        if b.segment < seg:
            bad(f"segment {b.segment} after segment {seg}")
        if b.n and b.segment == seg and last is not None and int(t[0]) < last:
            bad(f"its first time is {last - int(t[0])} ns before the previous message's last, "
                f"in the same segment {seg}")
    last = int(t[-1]) if b.n else (prev[2] if prev is not None else None)
    return b.segment, b.first_sample + b.n, last


def _cell(b: Block, cell_ns: int) -> int:
    return int(b.time_ns[b.unit_start[0] if b.m else 0]) // cell_ns


def _joinable(a: Block, b: Block, cell_ns: int) -> bool:
    """``b`` continues ``a`` in another cell: same segment, scales and per-sample channels,
    next sample (two messages of one cell were cut apart by the logged run: keep them apart)."""
    return (a.segment == b.segment and b.first_sample == a.first_sample + a.n
            and _cell(a, cell_ns) != _cell(b, cell_ns)
            and (a.gyro is None) == (b.gyro is None) and set(a.per_sample) == set(b.per_sample)
            and a.gyro_dps_per_count == b.gyro_dps_per_count
            and np.array_equal(a.accel_counts_per_g, b.accel_counts_per_g)
            and np.array_equal(a.accel_zero, b.accel_zero))


class McapRawSource:
    """Source over a stillpoint MCAP's raw topics (single pass; open again for another)."""

    def __init__(self, path, **_options):
        self.path = Path(path)
        check_is_log(self.path)
        self._f = open(self.path, "rb")
        self.settings: Optional[dict] = None
        self.metadata: dict[str, dict] = {}
        try:
            self.metadata = read_metadata(self._f)  # through the summary's metadata index
        except Exception as e:
            self._f.close()
            raise CorruptRecordingError(
                self.path, f"cannot read the MCAP index ({type(e).__name__}); if the run was "
                           f"interrupted, run `stillpoint recover` on it first") from None
        if "device" not in self.metadata:
            self._f.close()
            raise UnsupportedFormatError(self.path, NOT_A_STILLPOINT_LOG)
        self.info = _device_info(self.metadata["device"], self.path)
        if "settings" in self.metadata:
            self.settings = loads_json(self.path, None, "settings",
                                       self.metadata["settings"].get("json", ""), what="metadata")
            from ..settings import settings_problem
            problem = settings_problem(self.settings)
            if problem:
                self._f.close()
                raise McapReadError(self.path, f"settings metadata: {problem}",
                                    record="metadata 'settings'")
        self.qc = QCReport(unit="sector" if self.info.device_type.startswith("AX") else
                           "second" if self.info.device_type == "ActiGraph" else "page")

    def logged_calibration(self):
        """The ``calibration`` metadata record (the estimate the logged run applied) as a
        CalibrationEstimate, checked: an estimate the run applied must hold usable coefficients
        (engine/calibration/validate.py), any other only its status and reason. An identity
        estimate when the log has none. A damaged record is a typed error naming it."""
        from ..calibration.estimate import CalibrationEstimate, status_applied
        from ..calibration.validate import validate_estimate
        cal = self.metadata.get("calibration") or {}
        if "json" not in cal:
            return CalibrationEstimate.identity("no calibration record")
        d = loads_json(self.path, None, "calibration", cal["json"], what="metadata")
        where = "metadata 'calibration'"
        if not isinstance(d, dict) or not isinstance(d.get("status", ""), str) \
                or not isinstance(d.get("reason", ""), str):
            raise McapReadError(self.path, "calibration metadata: not an estimate (a JSON object "
                                           "with a text status and reason)", record=where)
        if not status_applied(d.get("status")):
            return CalibrationEstimate(status=d.get("status", "identity"),
                                       reason=d.get("reason", "no calibration applied"))
        try:
            return validate_estimate(d, "calibration metadata")
        except StillpointError as e:
            raise McapReadError(self.path, str(e), record=where) from None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self) -> None:
        """Close the log."""
        self._f.close()

    def progress(self) -> Optional[float]:
        """Share of the log's samples handed out so far (the run summary's sample count; None
        without one): for progress bars. The messages are read in time order, not in file
        order, so the file position would not tell."""
        try:
            total = int((self.metadata.get("summary") or {}).get("samples") or 0)
        except (TypeError, ValueError):
            return None
        return min(1.0, getattr(self, "_handed", 0) / total) if total > 0 else None

    def __iter__(self) -> Iterator[Block]:
        from ..settings import is_lean
        if is_lean(self.settings):
            raise UnsupportedFormatError(self.path, LEAN_LOG)
        yield from self._blocks()

    def _blocks(self) -> Iterator[Block]:
        pending_raw: list[tuple] = []
        pending_gyro: list[tuple] = []
        has_gyro = self.info.gyro_range_dps is not None
        path = self.path
        group: list[Block] = []
        st = self.settings or {}
        # the logged run's raw-message cells (engine/mcap/sink.py) and pipeline block bound
        cell_ns = int(float(st.get("flush_every_s") or 60.0) * 1e9)
        rate = float(self.info.sample_rate_nominal or 0.0)
        max_join = int(JOIN_FRACTION * float(st.get("max_block_s") or 0.0) * rate)
        n_group = 0
        order = None  # (segment, end of the samples, last time) of the last raw message
        # ActiGraph: the idle-sleep periods the reader logged (QC events with an end, logged
        # before the samples they cover) mark the samples again (per_sample idle_sleep)
        idle = [] if self.info.device_type == "ActiGraph" else None

        def joined():
            nonlocal n_group
            b = group[0] if len(group) == 1 else Block.concat(group)
            group.clear()
            self._handed = getattr(self, "_handed", 0) + n_group
            n_group = 0
            return b

        for topic, i, message in iter_messages(path, [TOPIC_RAW, TOPIC_GYRO, TOPIC_QC]):
            if topic == TOPIC_RAW:
                m = decode(ACCEL_BATCH_RAW, path, topic, i, message.data)
                pending_raw.append((i, m, check_raw_message(m, path, topic, i)))
            elif topic == TOPIC_GYRO:
                m = decode(GYRO_BATCH_RAW, path, topic, i, message.data)
                pending_gyro.append((i, m, check_raw_message(m, path, topic, i, gyro=True)))
            else:
                ev = _qc_event(path, topic, i, message.data)
                if ev is not None:
                    if group:  # the blocks logged before this event go first, as in the run
                        yield joined()
                    self.qc.add(ev)
                    if idle is not None and ev.reason == "idle_sleep" and ev.end_ns is not None \
                            and ev.time_ns is not None:
                        idle.append((ev.time_ns, ev.end_ns))
            while pending_raw and (not has_gyro or pending_gyro):
                i, raw, n = pending_raw.pop(0)
                gyro = None
                if has_gyro:
                    j, gyro, ng = pending_gyro.pop(0)
                    if ng != n:
                        raise McapReadError(path, f"gyro message {j} holds {ng} samples, its accel "
                                                  f"message {i} {n}", channel=TOPIC_GYRO,
                                            record=f"message {j}")
                b = block_from_message(raw, gyro)
                if idle is not None:
                    b.per_sample[PER_SAMPLE_IDLE_SLEEP] = idle_mask(b.time_ns, idle)
                order = _check_order(order, b, path, i)
                self.qc.total += b.m
                self.qc.valid += b.m
                if group and (not _joinable(group[-1], b, cell_ns) or n_group + b.n > max_join):
                    yield joined()
                group.append(b)
                n_group += b.n
        if group:
            yield joined()
        # a gyro-less tail (should not happen in a complete log): yield accel only
        for i, raw, _n in pending_raw:
            b = block_from_message(raw, None)
            order = _check_order(order, b, path, i)
            yield b
        qc_meta = self.metadata.get("summary")
        if qc_meta and "qc" in qc_meta:
            q = loads_json(path, None, "summary", qc_meta["qc"], what="metadata")
            counts = {k: q.get(k) if isinstance(q, dict) else None
                      for k in ("total", "valid", "skipped", "segments")}
            if not all(isinstance(v, int) and v >= 0 for v in counts.values() if v is not None):
                raise McapReadError(path, f"summary qc counts {counts} are not counts",
                                    record="metadata 'summary'")
            self.qc.total = counts["total"] if counts["total"] is not None else self.qc.total
            self.qc.valid = counts["valid"] if counts["valid"] is not None else self.qc.valid
            self.qc.skipped, self.qc.segments = counts["skipped"] or 0, counts["segments"] or 0
