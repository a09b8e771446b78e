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
from .quantisation import dequantised
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


class BatchSchedule:
    """The schedule in incremental form, for a reader pass that stops as soon as it is satisfied.

    Feed nonmovement windows in time order with :meth:`add` (``now_ns``: the data time reached,
    so that a boundary passes even when no selected window follows it); it fits at each load
    boundary (``start + first_hours``, then every ``chunk_hours``) and returns the final
    estimate once the fit is ``ok`` (error below target, sphere covered), else None. At the end of
    the data call :meth:`finish`. Keyword arguments go to :func:`fit_calibration`.

    How many windows (selected or not) the data held, for reasons and ``extra``: either the
    sorted start times of every window (``all_starts``) or, in a stream, set ``offered``.
    """

    def __init__(self, start_ns: int, *, first_hours: float = FIRST_HOURS,
                 chunk_hours: float = CHUNK_HOURS, window_s: float = WINDOW_S,
                 all_starts: Optional[np.ndarray] = None, **fit_kw):
        if first_hours <= 0 or chunk_hours <= 0:
            raise ValueError("first_hours and chunk_hours must be positive")
        self.start_ns = int(start_ns)
        self.first_hours = float(first_hours)
        self.chunk_hours = float(chunk_hours)
        self.boundary_ns = self.start_ns + int(round(first_hours * _NS_PER_HOUR))
        self.chunk_ns = int(round(chunk_hours * _NS_PER_HOUR))
        self.window_s = window_s
        self.fit_kw = dict(fit_kw, select=False, window_s=window_s)
        self.attempts: list[dict] = []
        self.result: Optional[CalibrationEstimate] = None
        self.done = False
        self._parts: list[WindowFeatures] = []
        self._n = 0
        self._n_fitted = -1
        self._all_starts = all_starts
        self.offered: Optional[int] = None

    @property
    def windows(self) -> WindowFeatures:
        if len(self._parts) > 1:
            self._parts = [WindowFeatures.concat(self._parts)]
        return self._parts[0] if self._parts else WindowFeatures.empty()

    def _append(self, w: WindowFeatures) -> None:
        """Keep selected windows, their means de-biased for the counts' step once, here."""
        if len(w):
            step = self.fit_kw.get("quantisation_step_g")
            if step is not None and not self.fit_kw.get("ggir_compatible"):
                w = dequantised(w, step)
                self.fit_kw["means_dequantised"] = True
            self._parts.append(w)
            self._n += len(w)

    def _fit(self, end_ns: int) -> CalibrationEstimate:
        if self._n == self._n_fitted and self.result is not None:
            est = self.result  # same windows: same fit; only the loaded range grew
            est.fit_end_ns = int(end_ns)
            est.hours_used = (int(end_ns) - self.start_ns) / _NS_PER_HOUR
            return est
        offered = self.offered
        if self._all_starts is not None:
            offered = int(np.searchsorted(self._all_starts, int(end_ns), side="left"))
        est = fit_calibration(self.windows, data_start_ns=self.start_ns, data_end_ns=int(end_ns),
                              windows_offered=offered, **self.fit_kw)
        self._n_fitted = self._n
        self.attempts.append({"hours": round((int(end_ns) - self.start_ns) / _NS_PER_HOUR, 6),
                              "windows": est.windows, "status": est.status,
                              "error_before_mg": est.error_before_mg,
                              "error_after_mg": est.error_after_mg})
        self.result = est
        return est

    def add(self, windows: WindowFeatures, now_ns: Optional[int] = None
            ) -> Optional[CalibrationEstimate]:
        """Take selected windows (time order); return the final estimate once satisfied."""
        if self.done:
            return self.result
        starts = windows.start_ns
        i = 0
        while True:
            j = i + int(np.searchsorted(starts[i:], self.boundary_ns, side="left"))
            self._append(windows.select(slice(i, j)))
            reached = j < len(windows) or (now_ns is not None and now_ns >= self.boundary_ns)
            if not reached:
                return None
            if self._n != self._n_fitted:
                est = self._fit(self.boundary_ns)
                if est.status == "ok":
                    return self._finalise(recording_end_ns=None)
            self.boundary_ns += self.chunk_ns
            i = j

    def finish(self, end_ns: int) -> CalibrationEstimate:
        """End of data at ``end_ns``: the last fit on every window (if not already satisfied)."""
        if self.done:
            return self.result
        self._fit(end_ns)
        return self._finalise(recording_end_ns=int(end_ns))

    def _finalise(self, recording_end_ns: Optional[int]) -> CalibrationEstimate:
        self.done = True
        est = self.result
        est.extra.update(schedule=list(self.attempts), first_hours=self.first_hours,
                         chunk_hours=self.chunk_hours)
        if recording_end_ns is not None:
            total_h = (recording_end_ns - self.start_ns) / _NS_PER_HOUR
            est.extra["recording_hours"] = round(total_h, 6)
            if total_h < self.first_hours:
                est.extra["flags"].append("short")
                dur = f"{total_h:.1f} h" if total_h >= 1 else f"{total_h * 60:.1f} min"
                if round(total_h, 1) >= self.first_hours:  # not "72.0 h (< 72 h ...)"
                    dur = f"{total_h:.3f} h, {(self.first_hours - total_h) * 60:.1f} min short"
                est.reason += (f"; recording only {dur} (< {self.first_hours:g} h "
                               "first load): flagged short")
                if total_h < SHORT_RECORDING_HOURS:
                    est.extra["flags"].append("under_24h")
                return est
        if len(self.attempts) > 1:
            est.reason += f"; used {est.hours_used:.1f} h after {len(self.attempts)} fits"
        return est


def fit_batch_schedule(features: WindowFeatures, *, first_hours: float = FIRST_HOURS,
                       chunk_hours: float = CHUNK_HOURS, temperature: bool = True,
                       ggir_compatible: bool = False, variant: str = "auto", select: bool = True,
                       recording_start_ns: Optional[int] = None,
                       recording_end_ns: Optional[int] = None,
                       target_error_mg: float = TARGET_ERROR_MG,
                       sd_threshold: float = SD_THRESHOLD_G, max_abs_mean: float = MAX_ABS_MEAN_G,
                       device_key: Optional[str] = None, window_s: float = WINDOW_S,
                       all_starts: Optional[np.ndarray] = None, repeats_collapsed: int = 0,
                       **fit_options) -> CalibrationEstimate:
    """Fit a whole recording's windows by the 72 h + 12 h schedule; returns the final estimate.

    ``features``: every window of the recording (or only its nonmovement windows, then pass
    ``select=False`` and ``recording_start_ns``/``recording_end_ns`` so the schedule knows the
    data time). A stream that selected the windows as it went (``NonmovementOperator``) passes
    the start times of every window it saw as ``all_starts`` and the repeats it collapsed as
    ``repeats_collapsed``: the estimate is then the one the whole table gives, without holding
    the table. The estimate's ``hours_used`` is the data time loaded when the schedule stopped;
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
    elif all_starts is not None:
        windows, n_in, repeats = features, len(all_starts), int(repeats_collapsed)
    else:
        windows, n_in, repeats = features, len(features), 0
    fit_kw = dict(temperature=temperature, ggir_compatible=ggir_compatible, variant=variant,
                  target_error_mg=target_error_mg, sd_threshold=sd_threshold,
                  max_abs_mean=max_abs_mean, device_key=device_key, **fit_options)
    if t0 is None:  # no windows at all
        est = fit_calibration(windows, select=False, window_s=window_s, **fit_kw)
        est.extra.update(windows_offered=n_in, schedule=[], first_hours=first_hours,
                         chunk_hours=chunk_hours)
        return est
    if len(windows) > 1 and np.any(np.diff(windows.start_ns) < 0):
        windows = windows.select(np.argsort(windows.start_ns, kind="stable"))
    if select:
        all_starts = np.sort(features.start_ns)
    elif all_starts is not None:
        all_starts = np.sort(np.asarray(all_starts, np.int64))
    sched = BatchSchedule(t0, first_hours=first_hours, chunk_hours=chunk_hours,
                          window_s=window_s, all_starts=all_starts, **fit_kw)
    est = sched.add(windows)
    if est is None:
        est = sched.finish(t_end)
    est.extra["repeats_collapsed"] = repeats
    return est
