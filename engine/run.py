"""The per-file job: ``process_file(input, out, settings) -> summary``.

A pure function of (input path, settings): it reads the recording (any Source: .cwa, .bin or a
stillpoint MCAP, which is how ``replay`` works), writes one MCAP and returns a summary dict;
running it twice gives the same MCAP content, so it can run under any scheduler (a process pool,
Dask, Ray) and be re-run after a failure.

Modes (same operators, different schedules):

* ``batch``: pass 1 streams window features and nonmovement windows (a ``.cwa`` read without
  per-sample times, as ``calibrate`` reads it), then fits by the 72 h + 12 h schedule
  (engine.calibration.fit_batch_schedule); pass 2 streams the file again and logs raw, corrected
  (final estimate from the first sample), temperature and epoch metrics.
* ``online``: one pass. Window features feed ``OnlineCalibrator`` (refit at each 12 h boundary);
  every published estimate is logged; accepted ones take effect from their boundary. The
  correction waits (a few seconds of data at most) until the estimate schedule is final for
  the samples it corrects, so the output does not depend on block cuts. The epoch and day
  tables (when asked for) come from a second pass over the input with the final estimate applied
  from the first sample (``_online_tables``); the log is the online one.

Both passes hold only bounded state: ring buffers of one window/epoch, the nonmovement windows
(~60k rows a week) and the writer's current chunk.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Callable, Optional

import numpy as np

from stillpoint.engine.recordings import open_recording
from stillpoint.engine.core.errors import StillpointError

from .core.blocks import Block
from .calibration import OnlineCalibrator, fit_batch_schedule
from .calibration.trust import CountStep
from .calibration.estimate import CalibrationEstimate, calibration_source
from .calibration.outcome import CalibrationOutcome
from .calibration.quantisation import release_tables
from .calibration.validate import validate_estimate
from .clipping import ClippingMonitor
from .features import WindowFeatures
from .core.malloc import one_arena, trim
from .mcap.sink import McapSink

from .operators.correction import CorrectionOperator
from .operators.filters import band_used
from .operators.extras import ExtraMetrics
from .operators.metrics import EpochMetrics, MetricsOperator
from .operators.nonmovement import NonmovementOperator
from .operators.windows import WindowFeaturesOperator
from .core.pipeline import Pipeline, PipelineStats
from .core.prefetch import Prefetched, cores_available
# the settings of a run live beside it; callers take them from here with process_file
from .settings import RunSettings


class OutputError(StillpointError):
    """The output cannot be written where asked (missing directory, no permission, ...)."""


def check_output(out: Path) -> None:
    import os
    parent = out.parent if str(out.parent) else Path(".")
    if not parent.is_dir():
        raise OutputError(f"{out}: directory {parent} does not exist")
    if out.is_dir():
        raise OutputError(f"{out}: is a directory")
    if not os.access(parent, os.W_OK):
        raise OutputError(f"{out}: directory {parent} is not writable")


# ---------------------------------------------------------------------------- stages
class FeatureStage:
    """Block -> window features -> nonmovement windows (and, online, the calibrator)."""

    def __init__(self, s: RunSettings, rate_hz: float,
                 on_features: Optional[Callable[[WindowFeatures], None]] = None):
        self.windows = WindowFeaturesOperator(rate_hz, s.window_s, s.min_fill)
        # batch: the fit reads the nonmovement windows and every window's start time (8 bytes a
        # window), not the whole window table (11 values a window)
        self.keep = on_features is None
        self.nonmovement = NonmovementOperator(s.sd_threshold_g, s.max_abs_mean_g, keep=self.keep)
        self.on_features = on_features
        self._starts: list[np.ndarray] = []
        self.last_block_ns: Optional[int] = None
        self.count_step = CountStep()  # quantisation step of the counts (calibration)

    @property
    def all_starts(self) -> np.ndarray:
        """Start times of every window seen (batch), in stream order."""
        if len(self._starts) != 1:
            self._starts = [np.concatenate(self._starts) if self._starts else np.zeros(0, np.int64)]
        return self._starts[0]

    def _take(self, f: WindowFeatures) -> None:
        if self.keep and len(f):
            self._starts.append(np.array(f.start_ns, np.int64))
        self.nonmovement.push(f)
        if self.on_features is not None:
            self.on_features(f)

    def push(self, block: Block) -> None:
        self.last_block_ns = int(block.time_at(0))
        self.count_step.push(block)
        self._take(self.windows.push(block))

    def flush(self) -> None:
        self._take(self.windows.flush())


class OutputStage:
    """Block -> MCAP raw + correction -> MCAP corrected -> epoch metrics -> MCAP metrics."""

    def __init__(self, s: RunSettings, rate_hz: float, sink: McapSink, source,
                 initial: CalibrationEstimate, gate=None):
        self.sink = sink
        self.source = source
        self.correction = CorrectionOperator(initial, rate_hz=rate_hz, gate=gate)
        self.metrics = MetricsOperator(rate_hz, s.epoch_s, s.bfen_band_hz)
        # counts, MIMS-units (when on)
        self.extras = ExtraMetrics(s, rate_hz, getattr(getattr(source, "info", None),
                                                       "accel_range_g", None))
        self.epochs = 0
        self.enmo_weighted = 0.0
        self.samples_metrics = 0
        self._qc_logged = 0
        self._last_ns = 0
        self._segment = None
        info = getattr(source, "info", None)
        self.clipping = ClippingMonitor(getattr(info, "accel_range_g", None), rate_hz)
        self.taps: list = []  # extra consumers of (block, corrected batches, epoch metrics)
        self._steps = 0

    def _log_reader_qc(self) -> None:
        events = getattr(getattr(self.source, "qc", None), "events", [])
        while self._qc_logged < len(events):
            e = events[self._qc_logged]
            t = e.time_ns if e.time_ns is not None else self._last_ns
            # an event without a time of its own is pinned to the data time it was logged at, so
            # a replay (which may see it at another block boundary) logs it at the same time
            d = dict(e.as_dict(), source="reader", time_ns=t)
            self.sink.write_qc(d, t)
            self._qc_logged += 1

    def _step(self, block: Optional[Block], batches) -> None:
        ms = [self.metrics.push(b) for b in batches]
        m = EpochMetrics.concat(ms) if len(ms) != 1 else ms[0]
        if len(m):
            self.epochs += len(m)
            self.enmo_weighted += float(np.dot(m.enmo_mg, m.n))
            self.samples_metrics += int(m.n.sum())
        self.sink.write_slices(block, batches, m)
        ex = self.extras.push(batches)
        if ex:
            self.sink.write_extras(ex)
        for tap in self.taps:
            tap.push(block, batches, m, ex)

    def push(self, block: Block) -> None:
        self._last_ns = int(block.time_ns[0])
        self._log_reader_qc()
        if block.segment != self._segment:
            self._segment = block.segment
            self.sink.write_qc({"source": "engine", "reason": "segment_start",
                                "segment": block.segment, "index": int(block.unit_index[0])
                                if block.m else -1, "time_ns": self._last_ns}, self._last_ns)
        self.clipping.observe(block)
        self._step(block, self.correction.push(block))
        self._steps += 1
        if self._steps % TRIM_EVERY_STEPS == 0:
            trim()

    def flush(self) -> None:
        self._log_reader_qc()
        self._step(None, self.correction.flush())
        m = self.metrics.flush()
        if len(m):
            self.epochs += len(m)
            self.enmo_weighted += float(np.dot(m.enmo_mg, m.n))
            self.samples_metrics += int(m.n.sum())
            self.sink.write_slices(None, [], m)
        ex = self.extras.flush()
        if ex:
            self.sink.write_extras(ex)
        for tap in self.taps:
            tap.flush(m, ex)

    @property
    def enmo_mean_mg(self) -> Optional[float]:
        return self.enmo_weighted / self.samples_metrics if self.samples_metrics else None


# ---------------------------------------------------------------------------- helpers
def _rate(info) -> float:
    r = float(info.sample_rate_nominal or 0.0)
    if r <= 0:
        raise ValueError(f"{info.path}: the header gives no sample rate")
    return r


def _utf8_text(text: str) -> str:
    """A file name that is not valid UTF-8 (bytes the file system allowed) with U+FFFD in place
    of the undecodable bytes: the MCAP log holds UTF-8 text only."""
    try:
        text.encode("utf-8")
        return text
    except UnicodeEncodeError:
        return text.encode("utf-8", "surrogateescape").decode("utf-8", "replace")


def _loggable(info):
    """The DeviceInfo with its file name as UTF-8 text (see ``_utf8_text``)."""
    if info.path is None or _utf8_text(info.path) == info.path:
        return info
    from dataclasses import replace
    return replace(info, path=_utf8_text(info.path))


def _static_estimate(d: dict, info, first_ns, summary: dict) -> CalibrationEstimate:
    """The static calibration to apply: same device only; the gap to the recording is logged."""
    from .calibration.estimate import STATIC_METHOD
    from .calibration.static import StaticCalibrationError
    est = CalibrationEstimate.from_dict(dict(d))
    if est.method != STATIC_METHOD:
        raise StaticCalibrationError(f"the static calibration given has method {est.method!r}, "
                                     f"not {STATIC_METHOD!r}")
    if est.device_key and est.device_key != info.device_key:
        raise StaticCalibrationError(
            f"{info.path}: the static calibration is for device {est.device_key}, the recording is "
            f"from {info.device_key}")
    if est.status != "ok":
        raise StaticCalibrationError(f"the static calibration has status {est.status!r}: not applied")
    gap_h = None
    if first_ns is not None and est.fit_end_ns is not None:
        gap_h = (int(first_ns) - int(est.fit_end_ns)) / 3.6e12
    full = bool((est.extra.get("static") or {}).get("matrix"))
    est.effective_from_ns = None
    est.extra = dict(est.extra, applied_as="static", gap_hours=gap_h)
    summary["static_calibration"] = {"device_key": est.device_key, "fit_end_ns": est.fit_end_ns,
                                     "gap_hours": gap_h, "full_matrix_not_applied": full}
    return est


def _progress_wrapper(progress, label):
    if progress is None:
        return None
    return lambda st: progress(label, st)


QC_DETAILS = 10  # QC events described in the run summary (all are counted, and logged on /qc)


def _qc_summary(source) -> dict:
    qc = getattr(source, "qc", None)
    if qc is None:
        return {}
    d = qc.as_dict()
    events = d.pop("events")
    d["events"] = len(events)
    reasons: dict[str, int] = {}
    for e in events:
        reasons[e["reason"]] = reasons.get(e["reason"], 0) + 1
    d["reasons"] = reasons
    # what was wrong, in the reader's words, for the tables a study reads (the cohort summary):
    # the first QC_DETAILS events that carry a description (no key when there are none)
    details = [f"{e['reason']} at {d.get('unit', 'unit')} {e['index']}: {e['detail']}"
               for e in events if e.get("detail")][:QC_DETAILS]
    if details:
        d["details"] = details
    return d


# ---------------------------------------------------------------------------- the job
def process_file(path, out, settings: Optional[RunSettings] = None, *,
                 progress: Optional[Callable[[str, PipelineStats], None]] = None,
                 writer: Optional[str] = None, source_options: Optional[dict] = None,
                 tables=None, metadata=None,
                 prefetch: Optional[bool] = None) -> dict:
    """Process one recording into ``out`` (MCAP); return the run summary (see module docstring).

    ``writer``: where chunks are compressed and written (engine/mcap/log.py); default by mode,
    ``WRITER_BY_MODE``. ``progress(label, stats)`` is called as the passes advance (label "pass 1/2", "pass 2/2",
    or "online"). ``tables``: an ``engine.tables.TablesSettings`` to write the epoch and day
    tables during the output pass. ``metadata``: extra MCAP metadata records
    ``{name: {key: str}}`` written with the summary (e.g. the download station's clock offset,
    host time zone and station id), or a function that returns them, called when they are
    written (the station's record of what its verification repaired). ``prefetch``: read and decode the next blocks on a thread
    while the engine works (engine/core/prefetch.py; the logs are the same); default:
    ``PREFETCH_BY_MODE``, where the process may use more than one core.
    """
    s = settings or RunSettings()
    writer = writer or WRITER_BY_MODE[s.mode]
    path, out = Path(path), Path(out)
    opts = dict(source_options or {})
    check_output(out)
    from stillpoint.drivers import sniff_format
    from .timezones import CLOCK_RECORD, clock_record, reader_timezone
    # the zone of the times (unknown for a .cwa without one): logged as the ``clock`` record
    tz, zone = reader_timezone(path, sniff_format(path), s.timezone, s.timezone_override)
    if tz is not None and "timezone" not in opts:
        opts["timezone"] = tz
    if tables is not None:
        from stillpoint.engine.core.outputs import check_output_path
        check_output_path(tables.epochs_path, what="epoch table")
        check_output_path(tables.days_path, what="day table")
        if not tables.zone.known:
            tables.zone = zone
        if getattr(tables, "sleep", None) is not None:
            from .sleep.tap import check_sleep_outputs
            check_sleep_outputs(tables)
    t_start = time.perf_counter()
    # raises a StillpointError (exit 2) on unreadable input; a batch run's pass 1 (window
    # features only) reads a .cwa without per-sample times, as calibrate does
    if prefetch is None:
        prefetch = PREFETCH_BY_MODE[s.mode] and cores_available() > 1
    if prefetch:
        one_arena()

    def source(**options):
        src = open_recording(path, **options)
        return Prefetched(src) if prefetch else src

    src = source(**_reader_options(path, opts, features_only=s.mode == "batch"))
    info = src.info
    rate = _rate(info)
    summary: dict = {"input": _utf8_text(str(path)), "mode": s.mode,
                     "device": {"type": info.device_type, "id": info.device_id,
                                "session": info.session_id, "rate_hz": rate,
                                "range_g": info.accel_range_g}}
    band = band_used(rate, s.bfen_band_hz)
    meta_settings = dict(s.to_dict(), bfen_band_used_hz=list(band))
    estimates_log: list[dict] = []

    if s.mode == "batch":
        # ---------------------------------------------------------------- pass 1
        feat = FeatureStage(s, rate)
        try:
            st1 = Pipeline(src, [feat], rate_hz=rate, max_block_s=None).run(
                _progress_wrapper(progress, "pass 1/2"))  # the reader's blocks (flat memory)
        finally:
            src.close()
        if not s.calibrate:
            est = CalibrationEstimate.identity("calibration switched off (--no-calibrate)")
        elif s.static_calibration:
            est = _static_estimate(s.static_calibration, info, st1.first_ns, summary)
        elif st1.samples == 0:
            est = CalibrationEstimate.identity("no samples: not calibrated")
        else:
            est = fit_batch_schedule(
                feat.nonmovement.selected, select=False, all_starts=feat.all_starts,
                repeats_collapsed=feat.nonmovement.repeats_dropped,
                recording_start_ns=st1.first_ns, recording_end_ns=st1.last_ns,
                first_hours=s.first_hours, chunk_hours=s.chunk_hours, temperature=s.temperature,
                ggir_compatible=s.ggir_compatible, sd_threshold=s.sd_threshold_g,
                max_abs_mean=s.max_abs_mean_g, device_key=info.device_key, window_s=s.window_s,
                quantisation_step_g=feat.count_step.step_g)
        est.effective_from_ns = None
        windows, nonmove = feat.windows.windows, feat.nonmovement.count
        quietest = feat.nonmovement.quietest_sd_g
        del feat  # its nonmovement windows (up to ~0.8 MB a day) are not needed in pass 2
        release_tables()
        # ---------------------------------------------------------------- pass 2
        src = source(**_reader_options(path, opts))
        sink = McapSink(out, _loggable(src.info), meta_settings, flush_every_s=s.flush_every_s,
                        compression=s.compression, chunk_size=s.chunk_size,
                        corrected_quantum_g=s.corrected_quantum_g, writer=writer,
                        zstd_level=s.zstd_level, view_hz=s.view_hz, chunk_s=chunk_span(s))
        try:
            sink.write_metadata(CLOCK_RECORD, clock_record(zone, src.info.timezone_offset_s))
            # explained before it is logged: the message, the record and the summary agree
            outcome = CalibrationOutcome(est).explain(quietest, s.sd_threshold_g,
                                                      _rate(src.info))
            initial = est if outcome.applied else CalibrationEstimate.identity(est.reason)
            sink.write_outcome(outcome, st1.first_ns or 0)
            sink.write_qc(outcome.qc_event(), st1.first_ns or 0)
            estimates_log.append({"status": est.status, "applied": outcome.applied})
            outst = OutputStage(s, rate, sink, src, initial)
            _add_tables(outst, tables, s, rate, band, src, corrected=outcome.applied,
                        calibration_source=calibration_source(est, outcome.applied, st1.first_ns))
            st = Pipeline(src, [outst], rate_hz=rate, max_block_s=s.max_block_s).run(
                _progress_wrapper(progress, "pass 2/2"))
        except BaseException as e:
            _abort(sink, e)
            _abort_tables(outst if "outst" in locals() else None)
            src.close()
            raise
    else:
        # ---------------------------------------------------------------- online
        prior = validate_estimate(s.prior, "prior estimate") if s.prior else None
        static = bool(s.static_calibration) and s.calibrate
        if static:
            prior = _static_estimate(s.static_calibration, info, None, summary)
        cal = OnlineCalibrator(prior, s.chunk_hours, device_key=info.device_key,
                               sd_threshold=s.sd_threshold_g, max_abs_mean=s.max_abs_mean_g,
                               window_s=s.window_s, temperature=s.temperature)
        sink = McapSink(out, _loggable(info), meta_settings, flush_every_s=s.flush_every_s,
                        compression=s.compression, chunk_size=s.chunk_size,
                        corrected_quantum_g=s.corrected_quantum_g, writer=writer,
                        zstd_level=s.zstd_level, view_hz=s.view_hz, chunk_s=chunk_span(s),
                        step_chunks=True)
        sink.write_metadata(CLOCK_RECORD, clock_record(zone, info.timezone_offset_s))
        window_ns = int(round(s.window_s * 1e9))
        outst = None

        def publish(ests):
            for e in ests:
                accepted = bool(e.diagnostics.accepted) and s.calibrate and not static
                sink.write_outcome(CalibrationOutcome(e, accepted), e.effective_from_ns or 0)
                estimates_log.append({"status": e.status, "applied": accepted,
                                      "effective_from_ns": e.effective_from_ns})
                if accepted:
                    outst.correction.add_estimate(e)

        feat = FeatureStage(s, rate, on_features=lambda f: publish(cal.add(f)))
        cal.count_step = feat.count_step

        def gate():
            nb = cal.next_boundary_ns
            if nb is None:  # no window yet: the first boundary is at least a chunk away
                return (feat.last_block_ns or 0) - window_ns + cal.chunk_ns
            return nb

        initial = (prior if (prior is not None and s.calibrate)
                   else CalibrationEstimate.identity("online: no estimate accepted yet"))
        outst = OutputStage(s, rate, sink, src, initial, gate=gate)
        # the tables are made after the pass, from the final estimate (``_online_tables``)
        stages = [feat, _FinishCalibrator(cal, publish, feat), outst]
        if prior is not None:  # logged at the first sample's time (no message before the data)
            stages.insert(0, _LogPrior(sink, prior, s.calibrate))
        try:
            st = Pipeline(src, stages, rate_hz=rate,
                          max_block_s=s.max_block_s).run(_progress_wrapper(progress, "online"))
        except BaseException as e:
            _abort(sink, e)
            _abort_tables(outst)
            src.close()
            raise
        windows, nonmove = feat.windows.windows, feat.nonmovement.count
        outcome = CalibrationOutcome(outst.correction.schedule.current).explain(
            feat.nonmovement.quietest_sd_g, s.sd_threshold_g, _rate(src.info))
        summary["estimates"] = estimates_log
    # ---------------------------------------------------------------- wrap up
    src.close()
    summary.update({
        "samples": st.samples,
        "duration_s": st.data_s,
        "segments": len(st.segments),
        "windows": windows,
        "nonmovement_windows": nonmove,
        "epochs": outst.epochs,
        **({"mims_near_range_epochs": outst.extras.near_range_epochs,
            "mims_unextrapolated_epochs": outst.extras.unextrapolated_epochs} if s.mims else {}),
        "calibration": outcome.summary(),
        "enmo_mean_mg": outst.enmo_mean_mg,
        "qc": _qc_summary(src),
        "clipping": outst.clipping.as_dict(),
        "outputs": {"mcap": str(out)},
        "estimates_logged": len(estimates_log),
        "wall_s": round(time.perf_counter() - t_start, 3),
    })
    if st.first_ns is not None:
        summary["start_ns"], summary["end_ns"] = st.first_ns, st.last_ns
        sc = summary.get("static_calibration")
        if sc and sc.get("fit_end_ns") is not None:
            sc["gap_hours"] = (int(st.first_ns) - int(sc["fit_end_ns"])) / 3.6e12
    summary["timezone"] = zone.label
    if s.timezone_override and zone.known:  # a GENEActiv header's zone replaced on request
        summary["timezone_override"] = True
    for tap in outst.taps:  # the epoch and day tables
        try:
            summary["tables"] = tap.close(outcome.table_status)
        except BaseException as e:
            _abort(sink, e)
            tap.abort()
            raise
    if s.mode == "online" and tables is not None:
        try:
            summary["tables"] = _online_tables(path, opts, s, tables, outcome.estimate, sink,
                                               prefetch)
        except BaseException as e:
            _abort(sink, e)
            raise
    if "tables" in summary:
        summary["outputs"].update(epochs=summary["tables"]["epochs"], days=summary["tables"]["days"])
    try:
        if outst.clipping.flagged:  # logged on /qc too, so the log itself says so
            sink.write_qc({"source": "engine", "reason": "clipping",
                           "detail": outst.clipping.describe(), **outst.clipping.as_dict()},
                          st.last_ns or 0)
        for name, values in ((metadata() if callable(metadata) else metadata) or {}).items():
            sink.write_metadata(name, {str(k): str(v) for k, v in values.items()})
        sink.write_metadata("calibration", outcome.record())
        sink.write_metadata("summary", {k: v for k, v in summary.items() if k != "wall_s"})
        sink.close()
    except BaseException as e:
        _abort(sink, e)
        raise
    if sink.set_aside is not None:  # a killed earlier run's partial log, kept under a new name
        summary["outputs"]["earlier_partial_log"] = str(sink.set_aside)
    summary["mcap_messages"] = sink.messages
    summary["mcap_flushes"] = sink.flushes
    from .mcap.writer import peak_rss_mb
    summary["peak_rss_mb"] = {"engine": peak_rss_mb(), "writer": sink.writer_maxrss_mb}
    return summary


# MCAP chunk span when RunSettings.chunk_s is None, in both modes (against one chunk per
# 10 s cell, a week online: 9 % fewer bytes and 0.4-1.8 s less CPU of ~18 s, in-process with
# process_file(..., writer="inline")). An
# online run (a station correcting while it downloads) also ends its chunk at the end of every
# pipeline step, before the step's last cell (McapSink ``step_chunks``), so a kill loses only the
# step in progress and the open cell, as with one chunk per cell; a batch run, whose input
# stays on disk and can be run again, does not.
CHUNK_S = 60.0

# MCAP writer by mode when process_file is given none: a batch run compresses and writes each
# pipeline step's chunks on a writer thread while the engine works on the next step (zstd
# releases the GIL; on an idle 2-core machine a 7-day batch run took ~28 % less wall time for
# at most 2 % more CPU, /usr/bin/time of process_file(..., writer=...), two runs each); an online run
# writes inline, so a kill loses only the step in progress, never a queued one too.
WRITER_BY_MODE = {"batch": "thread", "online": "inline"}

# Free heap pages go back to the system every this many pipeline steps of pass 2 (glibc
# malloc_trim: engine/core/malloc.py). Without it, the heap's resident size creeps up with the
# file's length (arrays freed around longer-lived ones). process_file on the bench files, peak
# RSS at 1 / 7 / 14 days: 69.3 / 71.3 / 73.7 MB without, 68.5 / 71.3 / 72.3 MB trimming every 16
# steps (~2.7 h of data); a trim takes ~1 ms (63 ms a week).
TRIM_EVERY_STEPS = 16

# Reader thread (engine/core/prefetch.py) by mode when process_file is not told, on a machine with more
# than one core. `stillpoint process` on the week's bench file, /usr/bin/time, runs alternating
# with and without it (means over the runs): a batch run 13.41 s against 13.85 s wall (4 runs
# each), for 19.53 s against 18.50 s CPU (+6 %); an online run, which compresses inline, 19.37 s
# against 19.17 s wall (3 runs each) for 20.25 s against 18.97 s CPU (+7 %) and 2-5 MB more
# peak RSS. So only
# a batch run reads ahead; an online run (the station's) reads in the engine's thread.
PREFETCH_BY_MODE = {"batch": True, "online": False}


def _reader_options(path, opts: dict, *, features_only: bool = False) -> dict:
    """Reader options of a run's passes: a ``.cwa`` is decoded column-major (each axis
    contiguous, the layout the window features, the correction and the raw messages' x/y/z
    sequences read; the same values); a pass that only needs window features (``features_only``)
    also reads it without per-sample times (a sample clock cuts the windows at the same samples);
    the other passes read ``OUTPUT_BATCH_SECTORS`` at a time. The logs are the same, byte for
    byte, as with the per-sample, row-major read. Options the caller gives win."""
    from stillpoint.drivers import sniff_format
    if sniff_format(path) != "cwa":
        return opts
    extra = ({"column_major": True, "sample_times": False} if features_only
             else {"column_major": True, "batch_sectors": OUTPUT_BATCH_SECTORS})
    return dict(extra, **opts)


# .cwa sectors a pass that writes the log reads at a time: 500 packed sectors hold 60,000
# samples, 10 min at 100 Hz, about one pipeline step (RunSettings.max_block_s), so the blocks the
# reader thread decodes ahead are a step's size rather than four steps' (the reader's default is
# 2,048). A week's batch run with the reader thread, in-process, three runs each: peak RSS 92-95
# -> 79-80 MB, wall and CPU time the same within the runs' spread (13.45-13.85 s against
# 13.57-13.71 s wall). The samples, epochs and estimates are the same; a raw message whose 10 s
# cell a block boundary crosses is written as two (as at any block boundary) and the run's mean
# ENMO, summed block by block, can differ in its last bits, so the log is not byte for byte the
# one the default batch gives. The window-feature pass keeps the default (its blocks are not cut
# into steps; smaller ones cost ~2 s of CPU a week in per-block work).
OUTPUT_BATCH_SECTORS = 500


def chunk_span(s: RunSettings) -> Optional[float]:
    return s.chunk_s if s.chunk_s is not None else CHUNK_S


def _abort(sink: McapSink, exc: BaseException) -> None:
    """Stop the log after a failure or interrupt; the partial file (if any) is named on the
    exception (``partial_output``) so the command line can say where it is."""
    kept = sink.abort()
    if kept is not None and not getattr(exc, "partial_output", None):
        try:
            exc.partial_output = str(kept)
        except AttributeError:
            pass


class _LogPrior:
    """Online: log the prior on ``/calibration`` at the first sample's time."""

    def __init__(self, sink: McapSink, prior: CalibrationEstimate, applied: bool):
        self.sink, self.prior, self.applied = sink, prior, applied

    def push(self, block: Block) -> None:
        if self.prior is not None and block.n:
            self.sink.write_outcome(CalibrationOutcome(self.prior, self.applied),
                                    int(block.time_ns[0]), prior=True)
            self.prior = None

    def flush(self) -> None:
        pass


def _add_tables(outst: OutputStage, tables, s: RunSettings, rate: float, band, src, *,
                corrected: bool, calibration_source: str) -> None:
    if tables is not None:
        from .tables import TablesTap
        outst.taps.append(TablesTap(tables, rate, s.epoch_s, band, src, src.info, sink=outst.sink,
                                    extras=outst.extras.keys, corrected=corrected,
                                    calibration_source=calibration_source))


def _online_tables(path, opts: dict, s: RunSettings, tables, final: CalibrationEstimate, sink,
                   prefetch: bool) -> dict:
    """An online run's tables: a second pass over the input (read again, as a batch run's second
    pass; a followed file is complete by now) corrected with the run's final estimate from the
    first sample (``engine.tables.estimate_pass``), so they do not depend on when the refits
    came. The log keeps what was applied live; sleep's topics go into it."""
    from .tables.estimate_pass import tables_with_estimate
    options = {k: v for k, v in opts.items() if not k.startswith("follow")}
    src = open_recording(path, **_reader_options(path, options))
    if prefetch:
        src = Prefetched(src)
    try:
        return tables_with_estimate(src, final, s, tables, sink=sink)
    finally:
        src.close()


def _abort_tables(outst) -> None:
    for tap in getattr(outst, "taps", []):
        tap.abort()


class _FinishCalibrator:
    """Online only: at the end of the stream, after the last windows, ask for the final fit."""

    def __init__(self, cal: OnlineCalibrator, publish, feat: FeatureStage):
        self.cal, self.publish, self.feat = cal, publish, feat

    def push(self, block) -> None:
        pass

    def flush(self) -> None:
        self.publish(self.cal.finish())
