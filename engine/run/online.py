"""The online schedule: one pass, as a station corrects while it downloads.

Window features feed ``OnlineCalibrator`` (a refit at each 12 h boundary); every published
estimate is logged; accepted ones take effect from their boundary. The correction waits (a few
seconds of data at most) until the estimate schedule is final for the samples it corrects, so the
output does not depend on block cuts. The epoch and day tables (when asked for) come from a
second pass over the input with the final estimate applied from the first sample
(``online_tables``); the log is the online one.
"""

from __future__ import annotations

from ..calibration import OnlineCalibrator
from ..calibration.estimate import CalibrationEstimate
from ..calibration.outcome import CalibrationOutcome
from ..calibration.validate import validate_estimate
from ..core.blocks import Block
from ..core.malloc import tune_for_blocks
from ..core.pipeline import Pipeline
from ..mcap.sink import McapSink
from ..timezones import CLOCK_RECORD
from .context import RunContext, ScheduleResult, abort_log, abort_taps, rate_of
from .features import FeatureStage
from .output import OutputStage
from .static import static_estimate


class LogPrior:
    """Log the prior on ``/calibration`` at the first sample's time."""

    def __init__(self, sink: McapSink, prior: CalibrationEstimate, applied: bool):
        self.sink, self.prior, self.applied = sink, prior, applied

    def push(self, block: Block) -> None:
        """At the first block with samples, log the prior once."""
        if self.prior is not None and block.n:
            self.sink.write_outcome(CalibrationOutcome(self.prior, self.applied),
                                    int(block.time_ns[0]), prior=True)
            self.prior = None

    def flush(self) -> None:
        """Nothing is left at the end."""


class FinishCalibrator:
    """At the end of the stream, after the last windows, ask for the final fit."""

    def __init__(self, cal: OnlineCalibrator, publish):
        self.cal, self.publish = cal, publish

    def push(self, block) -> None:
        """Nothing to do until the end."""

    def flush(self) -> None:
        """Publish the final fit."""
        self.publish(self.cal.finish())


def run_online(ctx: RunContext, src) -> ScheduleResult:
    """The one pass; ``src`` is the opened input (closed by the run)."""
    s, rate, info = ctx.settings, ctx.rate_hz, src.info
    # with glibc's dynamic thresholds the block-sized arrays of this pass and of the tables'
    # second pass were trimmed off the heap and faulted in afresh every step (a week: 976 k page
    # faults, 30.1 CPU-s; with block thresholds 156 k and 24.3 CPU-s; same bytes)
    tune_for_blocks()
    prior = validate_estimate(s.prior, "prior estimate") if s.prior else None
    static = bool(s.static_calibration) and s.calibrate
    if static:
        prior = static_estimate(s.static_calibration, info, None, ctx.summary)
    cal = OnlineCalibrator(prior, s.chunk_hours, device_key=info.device_key,
                           sd_threshold=s.sd_threshold_g, max_abs_mean=s.max_abs_mean_g,
                           window_s=s.window_s, temperature=s.temperature)
    sink = ctx.open_log(info, step_chunks=True)
    sink.write_metadata(CLOCK_RECORD, ctx.clock.record())
    window_ns = int(round(s.window_s * 1e9))
    outst = None
    estimates: list[dict] = []

    def publish(ests):
        for e in ests:
            accepted = bool(e.diagnostics.accepted) and s.calibrate and not static
            sink.write_outcome(CalibrationOutcome(e, accepted), e.effective_from_ns or 0)
            estimates.append({"status": e.status, "applied": accepted,
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
    # no malloc_trim every few steps: with the block thresholds the freed pages are reused, and
    # trimming them only made the next steps fault them in again (a week: 155 k -> 13 k page
    # faults, 24.55 -> 22.03 CPU-s; peak RSS 70 MB either way, 77 MB at 14 days)
    outst = OutputStage(s, rate, sink, src, initial, gate=gate)
    # the tables are made after the pass, from the final estimate (``online_tables``)
    stages = [feat, FinishCalibrator(cal, publish), outst]
    if prior is not None:  # logged at the first sample's time (no message before the data)
        stages.insert(0, LogPrior(sink, prior, s.calibrate))
    try:
        st = Pipeline(src, stages, rate_hz=rate,
                      max_block_s=s.max_block_s).run(ctx.progress_for("online"))
    except BaseException as e:
        abort_log(sink, e)
        abort_taps(outst)
        src.close()
        raise
    outcome = CalibrationOutcome(outst.correction.schedule.current).explain(
        feat.nonmovement.quietest_sd_g, s.sd_threshold_g, rate_of(src.info))
    return ScheduleResult(st, outst, sink, src, feat.windows.windows, feat.nonmovement.count,
                          outcome, estimates)


def online_tables(ctx: RunContext, final: CalibrationEstimate, sink) -> dict:
    """An online run's tables: a second pass over the input (read again, as a batch run's second
    pass; a followed file is complete by now) corrected with the run's final estimate from the
    first sample (``engine.tables.estimate_pass``), so they do not depend on when the refits
    came. The log keeps what was applied live; sleep's topics go into it."""
    from ..tables.estimate_pass import tables_with_estimate
    src = ctx.input.open(follow=False, tables=True)
    try:
        return tables_with_estimate(src, final, ctx.settings, ctx.tables, sink=sink)
    finally:
        src.close()
