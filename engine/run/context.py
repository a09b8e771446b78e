"""What a mode's schedule is given (``RunContext``) and gives back (``ScheduleResult``).

A schedule (``batch.run_batch``, ``online.run_online``) decides when the calibration is fitted
and from when it applies; the rest of a run (the input, the log's framing, the summary) is the
same for both and stays in ``job.process_file``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Optional

from ..calibration.outcome import CalibrationOutcome
from ..core.pipeline import PipelineStats
from ..mcap.sink import McapSink
from ..settings import RunSettings
from . import tuning
from .inputs import ClockZone, RunInput
from .output import OutputStage


@dataclass
class RunContext:
    """One run's fixed inputs, shared by its passes."""

    settings: RunSettings
    input: RunInput
    clock: ClockZone
    out: Path
    rate_hz: float
    band: tuple
    writer: str
    tables: Any = None  # engine.tables.TablesSettings (with the run's zone), or None
    progress: Optional[Callable[[str, PipelineStats], None]] = None
    summary: Any = None  # the RunSummary (a schedule fills static_calibration)
    sink_process: Any = None  # engine.mcap.sinkproc.SinkProcess: the log is written there


    @property
    def meta_settings(self) -> dict:
        """The ``settings`` record of the log: the settings and the band-pass actually used."""
        return dict(self.settings.to_dict(), bfen_band_used_hz=list(self.band))

    def progress_for(self, label: str):
        """The progress callback of one pass (``label``: "pass 1/2", "pass 2/2", "online")."""
        if self.progress is None:
            return None
        progress = self.progress
        return lambda st: progress(label, st)

    def open_log(self, info, *, step_chunks: bool = False) -> McapSink:
        """Open the MCAP log for the recording ``info`` describes and write its clock record."""
        s = self.settings
        kw = dict(flush_every_s=s.flush_every_s, compression=s.compression,
                  chunk_size=s.chunk_size, corrected_quantum_g=s.corrected_quantum_g,
                  writer=self.writer, zstd_level=s.zstd_level, view_hz=s.view_hz,
                  chunk_s=chunk_span(s), **({"step_chunks": True} if step_chunks else {}))
        if self.sink_process is not None:  # the same sink, in the child process
            return self.sink_process.open(self.out, loggable(info), self.meta_settings, **kw)
        return McapSink(self.out, loggable(info), self.meta_settings, **kw)


@dataclass
class ScheduleResult:
    """What a schedule's passes leave for the summary and the end of the log."""

    stats: PipelineStats  # the output pass's pipeline statistics
    output: OutputStage
    sink: McapSink
    source: Any  # the output pass's source (closed by the run)
    windows: int
    nonmovement_windows: int
    outcome: CalibrationOutcome  # the estimate in force at the end, and whether it was applied
    estimates: list = field(default_factory=list)  # every logged estimate: status, applied, ...


def chunk_span(s: RunSettings) -> Optional[float]:
    """The log's chunk span (s): the settings', else ``tuning.CHUNK_S``."""
    return s.chunk_s if s.chunk_s is not None else tuning.CHUNK_S


def rate_of(info) -> float:
    """The nominal sample rate (Hz) a run works at; a header without one is an error."""
    r = float(info.sample_rate_nominal or 0.0)
    if r <= 0:
        raise ValueError(f"{info.path}: the header gives no sample rate")
    return r


def utf8_text(text: str) -> str:
    """A file name that is not valid UTF-8 (bytes the file system allowed) with U+FFFD in place
    of the undecodable bytes: the MCAP log holds UTF-8 text only."""
    try:
        text.encode("utf-8")
        return text
    except UnicodeEncodeError:
        return text.encode("utf-8", "surrogateescape").decode("utf-8", "replace")


def loggable(info):
    """The DeviceInfo with its file name as UTF-8 text (see ``utf8_text``)."""
    if info.path is None or utf8_text(info.path) == info.path:
        return info
    from dataclasses import replace
    return replace(info, path=utf8_text(info.path))


def abort_log(sink: McapSink, exc: BaseException) -> None:
    """Stop the log after a failure or interrupt; the partial file (if any) is named on the
    exception (``partial_output``) so the command line can say where it is."""
    kept = sink.abort()
    if kept is not None and not getattr(exc, "partial_output", None):
        try:
            exc.partial_output = str(kept)
        except AttributeError:
            pass


def abort_taps(output) -> None:
    """Drop the partial tables of a failed run."""
    for tap in getattr(output, "taps", []):
        tap.abort()
