"""How much data the batch fit uses: the paper's schedule (van Hees 2014; GGIR g.calibrate).

Start with the first ``first_hours`` of data time (72 h in the paper; GGIR >= 3.0 defaults to
168 h, see GGIR issue #1101, hence a parameter). If the fit's error is not below the target
(10 mg) or the sphere is not covered, add the next ``chunk_hours`` (12 h) of data time and refit
from the start values on all windows so far; stop when both hold or the recording ends.

Unlike GGIR, chunks are measured in data time (GGIR's AX block count assumes 80 samples per
block, so its "12 h" chunks of packed AX3 files hold ~18 h), and no fit is attempted before the
first load is complete. A recording shorter than the first load is fitted on all of it and
flagged ``short``.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from ..features import WindowFeatures
from .estimate import CalibrationEstimate
from .fit import TARGET_ERROR_MG, WINDOW_S, fit_calibration
from .select import MAX_ABS_MEAN_G, SD_THRESHOLD_G, select_calibration_windows

FIRST_HOURS = 72.0  # van Hees 2014 (GGIR >= 3.0: 168)
CHUNK_HOURS = 12.0  # van Hees 2014
SHORT_RECORDING_HOURS = 24.0  # paper/GGIR: shorter files are not used for summary measures

_NS_PER_HOUR = 3_600_000_000_000


def recording_range(features: WindowFeatures, window_s: float = WINDOW_S):
    """(start_ns, end_ns) of the data the windows cover (first start, last start + window)."""
    if len(features) == 0:
        return None, None
    return (int(features.start_ns.min()),
            int(features.start_ns.max()) + int(round(window_s * 1e9)))


def fit_batch_schedule(features: WindowFeatures, *, first_hours: float = FIRST_HOURS,
                       chunk_hours: float = CHUNK_HOURS, temperature: bool = True,
                       ggir_compatible: bool = False, variant: str = "auto", select: bool = True,
                       recording_start_ns: Optional[int] = None,
                       recording_end_ns: Optional[int] = None,
                       target_error_mg: float = TARGET_ERROR_MG,
                       sd_threshold: float = SD_THRESHOLD_G, max_abs_mean: float = MAX_ABS_MEAN_G,
                       device_key: Optional[str] = None, window_s: float = WINDOW_S,
                       **fit_options) -> CalibrationEstimate:
    """Fit a whole recording's windows by the 72 h + 12 h schedule; returns the final estimate.

    ``features``: every window of the recording (or only its nonmovement windows, then pass
    ``recording_start_ns``/``recording_end_ns`` so the schedule knows the data time). The
    estimate's ``hours_used`` is the data time loaded when the schedule stopped;
    ``extra["schedule"]`` lists every attempt (hours, windows, status, error).
    """
    if first_hours <= 0 or chunk_hours <= 0:
        raise ValueError("first_hours and chunk_hours must be positive")
    start, end = recording_range(features, window_s)
    t0 = recording_start_ns if recording_start_ns is not None else start
    t_end = recording_end_ns if recording_end_ns is not None else end
    if select:
        sel = select_calibration_windows(features, sd_threshold=sd_threshold,
                                         max_abs_mean=max_abs_mean)
        windows, n_in, repeats = sel.features, sel.windows_in, sel.repeats_dropped
    else:
        windows, n_in, repeats = features, len(features), 0
    fit_kw = dict(temperature=temperature, ggir_compatible=ggir_compatible, variant=variant,
                  select=False, target_error_mg=target_error_mg, sd_threshold=sd_threshold,
                  max_abs_mean=max_abs_mean, device_key=device_key, window_s=window_s,
                  **fit_options)
    if t0 is None:  # no windows at all
        est = fit_calibration(windows, **fit_kw)
        est.extra.update(windows_offered=n_in, schedule=[], first_hours=first_hours,
                         chunk_hours=chunk_hours)
        return est

    total_h = (t_end - t0) / _NS_PER_HOUR
    if len(windows) > 1 and np.any(np.diff(windows.start_ns) < 0):
        windows = windows.select(np.argsort(windows.start_ns, kind="stable"))
    starts = windows.start_ns
    load_end = t0 + int(round(first_hours * _NS_PER_HOUR))
    chunk_ns = int(round(chunk_hours * _NS_PER_HOUR))
    attempts, est, n_prev = [], None, -1
    while True:
        stop_at = min(load_end, t_end)
        n_use = int(np.searchsorted(starts, stop_at, side="left"))
        last = load_end >= t_end
        if n_use != n_prev or last:
            est = fit_calibration(windows.select(slice(0, n_use)), data_start_ns=t0,
                                  data_end_ns=stop_at, **fit_kw)
            attempts.append({"hours": round((stop_at - t0) / _NS_PER_HOUR, 6),
                             "windows": est.windows, "status": est.status,
                             "error_before_mg": est.error_before_mg,
                             "error_after_mg": est.error_after_mg})
            n_prev = n_use
            if est.status == "ok" or last:
                break
        load_end += chunk_ns
    est.extra.update(windows_offered=n_in, repeats_collapsed=repeats, schedule=attempts,
                     first_hours=first_hours, chunk_hours=chunk_hours,
                     recording_hours=round(total_h, 6))
    if total_h < first_hours:
        est.extra["flags"].append("short")
        est.reason += (f"; recording only {total_h:.1f} h (< {first_hours:g} h first load): "
                       "flagged short")
        if total_h < SHORT_RECORDING_HOURS:
            est.extra["flags"].append("under_24h")
    elif len(attempts) > 1:
        est.reason += f"; used {est.hours_used:.1f} h after {len(attempts)} fits"
    return est
