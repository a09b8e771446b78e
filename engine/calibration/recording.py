"""Batch calibration of a recording in one streaming pass: the ``stillpoint calibrate`` fast path.

Blocks from the source go through the engine's window-features and nonmovement operators
(``engine/operators/windows.py``, ``nonmovement.py``); the nonmovement windows feed the
incremental 72 h + 12 h schedule (:class:`BatchSchedule`), and reading **stops as soon as the
schedule is satisfied** (as GGIR's g.calibrate stops loading), unless ``read_all``. Memory is
the reader's block plus the selected windows (~60k rows a week): flat in file length.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import partial
from typing import Callable, Optional

from .outcome import CalibrationOutcome
from ..core.blocks import DeviceInfo, QCReport
from ..features import WindowFeatures
from ..operators.nonmovement import NonmovementOperator
from ..operators.windows import WindowFeaturesOperator
from .estimate import CalibrationEstimate
from .fit import TARGET_ERROR_MG, WINDOW_S
from .schedule import CHUNK_HOURS, FIRST_HOURS, BatchSchedule
from .select import MAX_ABS_MEAN_G, SD_THRESHOLD_G, nonmovement_mask
from .trust import CountStep


@dataclass
class RecordingCalibration:
    """What one calibration pass over a recording produced."""

    estimate: CalibrationEstimate
    info: DeviceInfo
    windows: WindowFeatures  # the nonmovement windows read (for plots)
    windows_total: int  # every 10 s window read
    samples: int  # samples read
    read_to_end: bool  # False when reading stopped early (schedule satisfied)
    qc: Optional[QCReport] = None
    notes: list = field(default_factory=list)


def calibrate_source(source, *, first_hours: float = FIRST_HOURS, chunk_hours: float = CHUNK_HOURS,
                     temperature: bool = True, ggir_compatible: bool = False, variant: str = "auto",
                     target_error_mg: float = TARGET_ERROR_MG, sd_threshold: float = SD_THRESHOLD_G,
                     max_abs_mean: float = MAX_ABS_MEAN_G, read_all: bool = False,
                     progress: Optional[Callable[[int], None]] = None,
                     **fit_options) -> RecordingCalibration:
    """Run the schedule over a Source (any driver); see the module docstring."""
    info: DeviceInfo = source.info
    rate = float(info.sample_rate_nominal or 0.0)
    # the mean norm is kept only with the nonmovement windows: computed for those alone
    wop = WindowFeaturesOperator(rate_hz=rate, window_s=WINDOW_S, norm_for=partial(
        nonmovement_mask, sd_threshold=sd_threshold, max_abs_mean=max_abs_mean))
    nm = NonmovementOperator(sd_threshold=sd_threshold, max_abs_mean=max_abs_mean, keep=True)
    fit_kw = dict(temperature=temperature, ggir_compatible=ggir_compatible, variant=variant,
                  target_error_mg=target_error_mg, sd_threshold=sd_threshold,
                  max_abs_mean=max_abs_mean, device_key=info.device_key, **fit_options)
    sched: Optional[BatchSchedule] = None
    samples, first_ns, last_ns, est = 0, None, None, None
    stopped_early = False

    def feed(feats: WindowFeatures, now_ns: Optional[int]):
        nonlocal sched, first_ns
        if len(feats) == 0 and sched is None:
            return None
        if sched is None:
            first_ns = int(feats.start_ns[0])
            sched = BatchSchedule(first_ns, first_hours=first_hours, chunk_hours=chunk_hours,
                                  window_s=WINDOW_S, **fit_kw)
        selected = nm.push(feats)
        sched.offered = wop.windows
        sched.fit_kw["quantisation_step_g"] = step.step_g
        return sched.add(selected, now_ns=now_ns)

    step = CountStep()  # the stored values' quantisation step, for the fit's warning
    for block in source:
        if block.n == 0:
            continue
        step.push(block)
        samples += block.n
        last_ns = int(block.time_at(block.n - 1))
        if first_ns is None:
            first_ns = int(block.time_at(0))
        est = feed(wop.push(block), last_ns)
        if progress is not None:
            progress(samples)
        if est is not None and not read_all:
            stopped_early = True
            break
    if not stopped_early:
        est = feed(wop.flush(), None)
        if sched is None:  # not a single window in the file
            sched = BatchSchedule(first_ns if first_ns is not None else 0,
                                  first_hours=first_hours, chunk_hours=chunk_hours,
                                  window_s=WINDOW_S, **fit_kw)
        if est is None or read_all:
            period = int(round(1e9 / rate)) if rate > 0 else 1
            end_ns = (last_ns + period) if last_ns is not None else sched.start_ns
            est = sched.finish(end_ns) if not sched.done else sched.result
    est.extra["windows_total"] = wop.windows
    est.extra["samples_read"] = samples
    est.extra["read_to_end"] = not stopped_early
    if info.path:
        est.extra["source"] = str(info.path)
    est.extra["flags"] = list(dict.fromkeys(est.extra.get("flags", [])))
    CalibrationOutcome(est).explain(nm.quietest_sd_g, sd_threshold, rate)
    return RecordingCalibration(estimate=est, info=info, windows=nm.selected,
                                windows_total=wop.windows, samples=samples,
                                read_to_end=not stopped_early, qc=getattr(source, "qc", None))


def calibrate_recording(path, *, open_options: Optional[dict] = None, progress=None,
                        **kwargs) -> RecordingCalibration:
    """Open a recording (``.cwa``, ``.bin``, MCAP) and run :func:`calibrate_source` on it.

    A ``.cwa`` is read without per-sample times (``sample_times=False``: the windows are cut
    at the same samples from the sector anchors, ``drivers.cwa_decode.SampleClock``) and into
    column-major counts (``column_major=True``). ``progress(fraction=...)`` is told the share
    of the file read after each block."""
    from stillpoint.drivers import sniff_format
    from stillpoint.engine.recordings import open_recording

    options = dict(open_options or {})
    if sniff_format(path) == "cwa":
        options.setdefault("sample_times", False)
        options.setdefault("column_major", True)
    src = open_recording(path, **options)
    if progress is not None:
        from ..progress import Reporting
        src = Reporting(src, progress)
    try:
        return calibrate_source(src, **kwargs)
    finally:
        src.close()
