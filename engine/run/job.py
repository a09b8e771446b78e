"""The per-file job: ``process_file(input, out, settings) -> summary``.

A pure function of (input path, settings): it reads the recording (any Source: .cwa, .bin,
.gt3x or a stillpoint MCAP, which is how ``replay`` works), writes one MCAP and returns a
summary dict; running it twice gives the same MCAP content, so it can run under any scheduler
(a process pool, Dask, Ray) and be re-run after a failure. It changes neither the settings nor
the table options it is given.

The input is opened once (``inputs.open_input``: one sniff, one zone); the mode's schedule
(``batch.run_batch``, ``online.run_online``) runs its passes over the one output pass
(``output.OutputStage``); the end of the log (QC, metadata, the summary) is the same for both.
Both passes hold only bounded state: ring buffers of one window/epoch, the nonmovement windows
(~60k rows a week) and the writer's current chunk.
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Callable, Optional

from stillpoint.engine.core.errors import StillpointError

from ..core.malloc import one_arena
from ..core.pipeline import PipelineStats
from ..core.prefetch import cores_available
from ..operators.filters import band_used
from ..settings import RunSettings
from . import tuning
from .batch import run_batch
from .context import RunContext, abort_log, rate_of, utf8_text
from .inputs import open_input, with_zone
from .online import online_tables, run_online
from .summary import RunSummary, qc_summary


class OutputError(StillpointError):
    """The output cannot be written where asked (missing directory, no permission, ...)."""


def check_output(out: Path) -> None:
    """The log can be written at ``out`` (its directory exists and is writable)."""
    parent = out.parent if str(out.parent) else Path(".")
    if not parent.is_dir():
        raise OutputError(f"{out}: directory {parent} does not exist")
    if out.is_dir():
        raise OutputError(f"{out}: is a directory")
    if not os.access(parent, os.W_OK):
        raise OutputError(f"{out}: directory {parent} is not writable")


def _check_tables(tables) -> None:
    from ..core.outputs import check_output_path
    check_output_path(tables.epochs_path, what="epoch table")
    check_output_path(tables.days_path, what="day table")
    if getattr(tables, "sleep", None) is not None:
        from ..sleep.tap import check_sleep_outputs
        check_sleep_outputs(tables)


def sink_process_for(path: Path, mode: str, writer: str):
    """A started ``SinkProcess`` when this run writes its log in a child process: a batch run
    (writer "thread") with a second core, an input of at least
    ``tuning.SINK_PROCESS_MIN_BYTES`` and $STILLPOINT_SINK_PROCESS not "0"; else None.
    Started before the first pass, so the child's start-up overlaps it."""
    from ..mcap import sinkproc
    if mode != "batch" or writer != "thread" or cores_available() < 2 or not sinkproc.enabled():
        return None
    try:
        if not path.is_file() or path.stat().st_size < tuning.SINK_PROCESS_MIN_BYTES:
            return None
    except OSError:
        return None
    return sinkproc.SinkProcess.start()


def process_file(path, out, settings: Optional[RunSettings] = None, *,
                 progress: Optional[Callable[[str, PipelineStats], None]] = None,
                 writer: Optional[str] = None, source_options: Optional[dict] = None,
                 tables=None, metadata=None,
                 prefetch: Optional[bool] = None) -> dict:
    """Process one recording into ``out`` (MCAP); return the run summary (``RunSummary.as_dict``;
    its fields are documented on the Columns page).

    ``writer``: where chunks are compressed and written (engine/mcap/log.py); default by mode,
    ``tuning.WRITER_BY_MODE``. ``progress(label, stats)`` is called as the passes advance
    (label "pass 1/2", "pass 2/2", or "online"). ``tables``: an ``engine.tables.TablesSettings``
    to write the epoch and day tables during the output pass. ``metadata``: extra MCAP metadata
    records ``{name: {key: str}}`` written with the summary (e.g. the download station's clock
    offset, host time zone and station id), or a function that returns them, called when they
    are written (the station's record of what its verification repaired). ``prefetch``: read
    and decode the next blocks on a thread while the engine works (engine/core/prefetch.py; the
    logs are the same); default: ``tuning.PREFETCH_BY_MODE``, where the process may use more
    than one core. ``prefetch=False`` also means no log child process (``sink_process_for``):
    a caller that runs one job per core (a cohort's workers) has no idle core to give it.
    """
    s = settings or RunSettings()
    writer = writer or tuning.WRITER_BY_MODE[s.mode]
    path, out = Path(path), Path(out)
    check_output(out)
    child = sink_process_for(path, s.mode, writer) if prefetch is not False else None
    if child is not None and tables is not None:  # the tables' writer runs there too
        from .taps import writer_modules
        child.preload(writer_modules(tables))
    try:
        return _process(path, out, s, progress, writer, source_options, tables, metadata,
                        prefetch, child)
    finally:
        if child is not None:  # ended already unless the run failed before its log was open
            child.stop()


def _process(path: Path, out: Path, s: RunSettings, progress, writer: str, source_options,
             tables, metadata, prefetch, child) -> dict:
    """``process_file``'s run (``child``: the SinkProcess its log is written in, or None)."""
    if prefetch is None:
        prefetch = tuning.PREFETCH_BY_MODE[s.mode] and cores_available() > 1
    t_start = time.perf_counter()
    if prefetch:  # before the reader thread starts
        one_arena()
    # raises a StillpointError (exit 2) on unreadable input or a zone its header contradicts; a
    # batch run's pass 1 (window features only) reads a .cwa without per-sample times
    opened = open_input(path, s, source_options, features_only=s.mode == "batch",
                        prefetch=prefetch)
    src = opened.source
    try:
        tables = with_zone(tables, opened.clock)
        if tables is not None:
            _check_tables(tables)
        rate = rate_of(src.info)
    except BaseException:
        src.close()
        raise
    info = src.info
    summary = RunSummary(input=utf8_text(str(path)), mode=s.mode,
                         device={"type": info.device_type, "id": info.device_id,
                                 "session": info.session_id, "rate_hz": rate,
                                 "range_g": info.accel_range_g})
    ctx = RunContext(s, opened.input, opened.clock, out, rate, band_used(rate, s.bfen_band_hz),
                     writer, tables, progress, summary, child)
    res = run_batch(ctx, src) if s.mode == "batch" else run_online(ctx, src)
    if s.mode == "online":
        summary.estimates = res.estimates
    st, outst, sink, outcome = res.stats, res.output, res.sink, res.outcome
    # ---------------------------------------------------------------- wrap up
    res.source.close()
    summary.samples = st.samples
    summary.duration_s = st.data_s
    summary.segments = len(st.segments)
    summary.windows = res.windows
    summary.nonmovement_windows = res.nonmovement_windows
    summary.epochs = outst.epochs
    if s.mims:
        summary.mims_near_range_epochs = outst.extras.near_range_epochs
        summary.mims_unextrapolated_epochs = outst.extras.unextrapolated_epochs
    summary.calibration = outcome.summary()
    summary.enmo_mean_mg = outst.enmo_mean_mg
    summary.qc = qc_summary(res.source)
    summary.clipping = outst.clipping.as_dict()
    summary.outputs = {"mcap": str(out)}
    summary.estimates_logged = len(res.estimates)
    summary.wall_s = round(time.perf_counter() - t_start, 3)
    if st.first_ns is not None:
        summary.start_ns, summary.end_ns = st.first_ns, st.last_ns
        sc = summary.static_calibration
        if sc and sc.get("fit_end_ns") is not None:
            sc["gap_hours"] = (int(st.first_ns) - int(sc["fit_end_ns"])) / 3.6e12
    zone = opened.clock.zone
    summary.timezone = zone.label
    if s.timezone_override and zone.known:  # a GENEActiv header's zone replaced on request
        summary.timezone_override = True
    for tap in outst.taps:  # the epoch and day tables
        try:
            summary.tables = tap.close(outcome.table_status)
        except BaseException as e:
            abort_log(sink, e)
            tap.abort()
            raise
    if s.mode == "online" and tables is not None:
        try:
            summary.tables = online_tables(ctx, outcome.estimate, sink)
        except BaseException as e:
            abort_log(sink, e)
            raise
    if summary.tables is not None:
        summary.outputs.update(epochs=summary.tables["epochs"], days=summary.tables["days"])
    try:
        if outst.clipping.flagged:  # logged on /qc too, so the log itself says so
            sink.write_qc({"source": "engine", "reason": "clipping",
                           "detail": outst.clipping.describe(), **outst.clipping.as_dict()},
                          st.last_ns or 0)
        for name, values in ((metadata() if callable(metadata) else metadata) or {}).items():
            sink.write_metadata(name, {str(k): str(v) for k, v in values.items()})
        sink.write_metadata("calibration", outcome.record())
        sink.write_metadata("summary", summary.as_dict(log=True))
        sink.close()
    except BaseException as e:
        abort_log(sink, e)
        raise
    if sink.set_aside is not None:  # a killed earlier run's partial log, kept under a new name
        summary.outputs["earlier_partial_log"] = str(sink.set_aside)
    summary.mcap_messages = sink.messages
    summary.mcap_flushes = sink.flushes
    from ..mcap.writer import peak_rss_mb
    summary.peak_rss_mb = {"engine": peak_rss_mb(), "writer": sink.writer_maxrss_mb}
    return summary.as_dict()
