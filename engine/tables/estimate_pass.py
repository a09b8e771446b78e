"""The tables of a recording corrected with one estimate from its first sample:
``tables_with_estimate(source, est, settings, ts, sink=None) -> dict`` (the tables summary).

One pass over a source's raw blocks (a recording read again, or a log's raw stream): the run's
output pass (``engine.run.output.OutputPass``: correction with ``est`` from the first sample,
the epoch metrics, counts and MIMS-units) with the table writer (``TablesTap``) as its tap. The
blocks are first joined into runs of one segment of up to ``step_s(rate)`` of data (every
operator's output is independent of block cuts, so the tables equal those written during a run
that applied the same estimate from the first sample; longer steps cost less). Used for

* a batch log's tables (``engine.workflows.tables_from_mcap``: the run's one estimate);
* the products of an online run (``process --mode online`` after its pass, the station after a
  verified download, ``export`` from an online log): the run's final estimate, applied from the
  first sample instead of the identity (or prior) that was in force until the first accepted
  refit, so the numbers do not depend on when the refits came. The log keeps what was applied
  live.

With ``sink`` (an open ``McapSink``) sleep's ``/sleep/night`` and ``/sleep/sib`` go into that log.
"""

from __future__ import annotations

from dataclasses import replace

from ..calibration.estimate import CalibrationEstimate, calibration_source
from ..calibration.outcome import CalibrationOutcome
from ..core.blocks import coalesce_blocks
from ..core.malloc import tune_for_blocks
from ..operators.correction import CorrectionOperator
from ..operators.filters import band_used
from ..run import tuning
from ..run.output import OutputPass
from .writer import TablesTap


def step_s(rate_hz: float) -> float:
    """The longest step of the pass (s of data): ``tuning.TABLES_PASS_STEP_S``, or less at a rate
    where that would hold more than ``tuning.TABLES_PASS_SAMPLES`` samples (the step's arrays,
    not its length in time, decide the pass's memory)."""
    return min(tuning.TABLES_PASS_STEP_S, tuning.TABLES_PASS_SAMPLES / max(float(rate_hz), 1.0))


def tables_with_estimate(source, est: CalibrationEstimate, settings, ts, *, sink=None) -> dict:
    """Write the tables ``ts`` of ``source`` corrected with ``est`` from its first sample (module
    docstring); return the tables summary (its day rows name the estimate:
    ``calibration_source``)."""
    tune_for_blocks()  # the pass's block-sized arrays stay on the heap (engine/core/malloc.py)
    applied = est.applied and bool(settings.calibrate)
    initial = replace(est, effective_from_ns=None) if applied else CalibrationEstimate.identity(est.reason)
    rate = float(source.info.sample_rate_nominal or 0) or 100.0
    band = band_used(rate, settings.bfen_band_hz)
    output = OutputPass(CorrectionOperator(initial, rate_hz=rate), settings, rate,
                        source.info.accel_range_g)
    tap = TablesTap(ts, rate, settings.epoch_s, band, source, source.info, sink=sink,
                    extras=output.extras.keys, corrected=applied,
                    calibration_source=calibration_source(est, applied))
    output.taps.append(tap)
    try:
        first = True
        for block in coalesce_blocks(source, step_s(rate)):
            if first:  # a fit that ended before the recording began is a prior
                tap.calibration_source = calibration_source(est, applied, int(block.time_ns[0]))
                first = False
            output.push(block)
        output.flush()
        return tap.close(CalibrationOutcome(est, applied).table_status)
    except BaseException:
        tap.abort()
        raise
