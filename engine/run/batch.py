"""The batch schedule: two passes over the input.

Pass 1 streams window features and nonmovement windows (a ``.cwa`` read without per-sample
times, as ``calibrate`` reads it), then fits by the 72 h + 12 h schedule
(``engine.calibration.fit_batch_schedule``); pass 2 streams the file again and logs raw,
corrected (the final estimate from the first sample), temperature and epoch metrics, with the
tables' taps on the same output pass.
"""

from __future__ import annotations

from ..calibration import fit_batch_schedule
from ..calibration.estimate import CalibrationEstimate, calibration_source
from ..calibration.outcome import CalibrationOutcome
from ..calibration.quantisation import release_tables
from ..core.malloc import tune_for_blocks
from ..core.pipeline import Pipeline
from ..timezones import CLOCK_RECORD
from .context import RunContext, ScheduleResult, abort_log, abort_taps, rate_of
from .features import FeatureStage
from .output import OutputStage
from .static import static_estimate
from .taps import add_tables


def fit(ctx: RunContext, feat: FeatureStage, st1, info) -> CalibrationEstimate:
    """The estimate pass 2 applies: none (calibration off), the static one, or the batch fit."""
    s = ctx.settings
    if not s.calibrate:
        return CalibrationEstimate.identity("calibration switched off (--no-calibrate)")
    if s.static_calibration:
        return static_estimate(s.static_calibration, info, st1.first_ns, ctx.summary)
    if st1.samples == 0:
        return CalibrationEstimate.identity("no samples: not calibrated")
    return fit_batch_schedule(
        feat.nonmovement.selected, select=False, all_starts=feat.all_starts,
        repeats_collapsed=feat.nonmovement.repeats_dropped,
        recording_start_ns=st1.first_ns, recording_end_ns=st1.last_ns,
        first_hours=s.first_hours, chunk_hours=s.chunk_hours, temperature=s.temperature,
        ggir_compatible=s.ggir_compatible, sd_threshold=s.sd_threshold_g,
        max_abs_mean=s.max_abs_mean_g, device_key=info.device_key, window_s=s.window_s,
        quantisation_step_g=feat.count_step.step_g)


def run_batch(ctx: RunContext, src) -> ScheduleResult:
    """Both passes; ``src`` is the input opened for pass 1 (closed here)."""
    s, rate = ctx.settings, ctx.rate_hz
    info = src.info
    # block-sized arrays stay on the heap and are not trimmed every few steps, as in an online run
    # (engine/core/malloc.py): a week, 274-298 k minor page faults and 1.65-1.68 s of system CPU
    # -> 30-32 k and 0.64-1.00 s; peak RSS 104.5 -> 107-109 MB; same bytes
    tune_for_blocks()
    feat = FeatureStage(s, rate)
    try:
        st1 = Pipeline(src, [feat], rate_hz=rate, max_block_s=None).run(
            ctx.progress_for("pass 1/2"))  # the reader's blocks (flat memory)
    finally:
        src.close()
    est = fit(ctx, feat, st1, info)
    est.effective_from_ns = None
    windows, nonmove = feat.windows.windows, feat.nonmovement.count
    quietest = feat.nonmovement.quietest_sd_g
    del feat  # its nonmovement windows (up to ~0.8 MB a day) are not needed in pass 2
    release_tables()
    # ---------------------------------------------------------------- pass 2
    src = ctx.input.open()
    sink = ctx.open_log(src.info)
    outst = None
    try:
        sink.write_metadata(CLOCK_RECORD, ctx.clock.record())
        # explained before it is logged: the message, the record and the summary agree
        outcome = CalibrationOutcome(est).explain(quietest, s.sd_threshold_g, rate_of(src.info))
        initial = est if outcome.applied else CalibrationEstimate.identity(est.reason)
        sink.write_outcome(outcome, st1.first_ns or 0)
        sink.write_qc(outcome.qc_event(), st1.first_ns or 0)
        estimates = [{"status": est.status, "applied": outcome.applied}]
        outst = OutputStage(s, rate, sink, src, initial)
        add_tables(outst, ctx, src, corrected=outcome.applied,
                   calibration_source=calibration_source(est, outcome.applied, st1.first_ns))
        st = Pipeline(src, [outst], rate_hz=rate, max_block_s=s.max_block_s).run(
            ctx.progress_for("pass 2/2"))
    except BaseException as e:
        abort_log(sink, e)
        abort_taps(outst)
        src.close()
        raise
    return ScheduleResult(st, outst, sink, src, windows, nonmove, outcome, estimates)
