"""Online refitting for streaming mode: refit at every 12 h boundary of data time.

The window features are sufficient statistics of the fit, so the calibrator keeps only the
nonmovement windows seen so far (a week is ~60k rows) and refits each time data time passes a
boundary ``start + j * chunk_hours``.

**What a boundary refit fits** (its cost must not grow with the recording): the *fit set*, the
first ``per_cell`` nonmovement windows (in data time) of every cell of 20 mg per axis of the
window's mean and 0.5 degC of its temperature (``FIT_CELL_G``, ``FIT_CELL_C``,
``FIT_PER_CELL``). A window whose cell is full adds nothing the fit does not already have but
weight on one orientation at one temperature: on wear with long still periods (a device on a
table for hours, a wrist resting through a long evening) most windows fall in a few cells (the
simulator's still wearer, a week: 44,691 nonmovement windows in ~1,100 cells). The set only
grows, so every refit sees the windows the previous one saw, and which windows enter it does not
depend on how the stream is cut. The fit set is bounded by the cells the wear visits, not by its
length. **The end-of-stream fit** (:meth:`OnlineCalibrator.finish`), whose estimate makes the
products (the tables, the store), fits every nonmovement window, as a batch fit does.
``per_cell=None`` fits every window at every boundary (the rule before the fit set). Each fit is published as an estimate with
its fit range (``fit_start_ns``..``fit_end_ns``) and the data time from which it would apply
(``effective_from_ns``: the boundary). It is **accepted** (``extra["accepted"]``) and becomes
``current`` only when its own fit succeeded (sphere covered, error lowered) *and* its error on the
windows so far is below that of the estimate in force; before the first accepted estimate the
prior (the device's stored estimate) or identity is in force.

Each refit starts from the previous fit, moved near the new fixed point by
:func:`refit.extrapolated_start` (``warm_start=False``: from identity, as a lone fit does); the
stopping rule is the fit's own, so both give the same estimate within its 1e-9 parameter
tolerance, and a refit costs ~11 passes over the windows instead of ~45.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from ..features import WindowFeatures
from .estimate import CalibrationEstimate
from .fit import MIN_WINDOWS, WINDOW_S, estimate_error_mg, fit_calibration
from .quantisation import dequantised
from .refit import extrapolated_start
from .schedule import CHUNK_HOURS
from .select import MAX_ABS_MEAN_G, SD_THRESHOLD_G, select_calibration_windows

_NS_PER_HOUR = 3_600_000_000_000
FIT_CELL_G = 0.02  # fit set cells: 20 mg per axis of the window mean ...
FIT_CELL_C = 0.5  # ... by 0.5 degC of its temperature (windows without one: a cell of their own)
FIT_PER_CELL = 16  # the first 16 windows of a cell enter the boundary refits


class OnlineCalibrator:
    """Accumulates nonmovement windows and refits at each ``chunk_hours`` boundary.

    ``prior``: the estimate in force before the first accepted fit (identity when None).
    ``start_ns``: data time the boundaries count from (default: the first window's start).
    Other keyword arguments go to :func:`fit_calibration` (``temperature``, ``variant``, ...).
    ``count_step``: the stream's quantisation step (an ``engine.calibration.trust.CountStep``, or
    set the attribute later): windows are de-biased for it once, as they arrive, and the fits
    warn about it. ``per_cell``: windows per cell of the boundary refits' fit set (module
    docstring; None: every window).
    """

    def __init__(self, prior: Optional[CalibrationEstimate] = None,
                 chunk_hours: float = CHUNK_HOURS, *, start_ns: Optional[int] = None,
                 device_key: Optional[str] = None, sd_threshold: float = SD_THRESHOLD_G,
                 max_abs_mean: float = MAX_ABS_MEAN_G, window_s: float = WINDOW_S,
                 warm_start: bool = True, count_step=None,
                 per_cell: Optional[int] = FIT_PER_CELL, **fit_options):
        if chunk_hours <= 0:
            raise ValueError("chunk_hours must be positive")
        if fit_options.get("ggir_compatible"):
            raise ValueError("online refits use the converged fit (ggir_compatible is batch-only)")
        self.prior = prior
        self.chunk_ns = int(round(chunk_hours * _NS_PER_HOUR))
        self.start_ns = start_ns
        self.device_key = device_key if device_key is not None else (
            prior.device_key if prior is not None else None)
        self.sd_threshold = sd_threshold
        self.max_abs_mean = max_abs_mean
        self.window_s = window_s
        # a fixed step may also come as the fit option (as for fit_calibration); the stream's
        # CountStep, when given, wins
        self._step = fit_options.pop("quantisation_step_g", None)
        self.fit_options = fit_options
        self.count_step = count_step
        self.warm_start = bool(warm_start)
        self._last_fit: Optional[CalibrationEstimate] = None  # the previous refit (warm start)
        if prior is None:
            self.current = CalibrationEstimate.identity("online: no estimate accepted yet")
            self.current.device_key = self.device_key
        else:
            self.current = prior
        self.estimates: list[CalibrationEstimate] = []  # every published estimate, in order
        if per_cell is not None and per_cell < 1:
            raise ValueError("per_cell must be at least 1 (or None: every window)")
        self.per_cell = per_cell
        self._parts: list[WindowFeatures] = []
        self._fit_parts: list[WindowFeatures] = []  # the fit set (per_cell), de-biased
        self._cells: dict[int, int] = {}  # fit set cell -> windows of it in the fit set
        # (windows, their counts' step (g, per axis) or None, which of them join the fit set)
        self._pending: list[tuple] = []
        self._n = 0
        self._n_fit = 0  # windows in the fit set
        self._final_n = -1  # windows of the last fit on every window (finish)
        self._n_at_last_fit = -1
        self._offered = 0
        self._last_mean: Optional[np.ndarray] = None
        self._next_boundary: Optional[int] = None
        self._last_end: Optional[int] = None

    # ------------------------------------------------------------------ state
    @property
    def next_boundary_ns(self) -> Optional[int]:
        """Data time of the next 12 h refit boundary (None until the first window arrives)."""
        return self._next_boundary

    @property
    def windows(self) -> WindowFeatures:
        """The nonmovement windows accumulated so far (means de-biased for the counts' step)."""
        self._settle()
        if len(self._parts) > 1:
            self._parts = [WindowFeatures.concat(self._parts)]
        return self._parts[0] if self._parts else WindowFeatures.empty()

    @property
    def fit_windows(self) -> WindowFeatures:
        """The boundary refits' fit set so far (module docstring), de-biased as ``windows``."""
        if self.per_cell is None:
            return self.windows
        self._settle()
        if len(self._fit_parts) > 1:
            self._fit_parts = [WindowFeatures.concat(self._fit_parts)]
        return self._fit_parts[0] if self._fit_parts else WindowFeatures.empty()

    def _settle(self) -> None:
        """De-bias the windows taken since the last fit, each run of one step at once (the
        de-biasing is per window: the same values as window by window, in far fewer calls)."""
        while self._pending:
            step = self._pending[0][1]
            k = next((i for i, (_f, s, _m) in enumerate(self._pending)
                      if (s is None) != (step is None) or not np.array_equal(s, step)),
                     len(self._pending))
            run = self._pending[:k]
            del self._pending[:k]
            wins = run[0][0] if len(run) == 1 else WindowFeatures.concat([r[0] for r in run])
            wins = wins if step is None else dequantised(wins, step)
            self._parts.append(wins)
            if self.per_cell is not None:
                keep = run[0][2] if len(run) == 1 else np.concatenate([r[2] for r in run])
                if keep.any():
                    self._fit_parts.append(wins if keep.all() else wins.select(keep))

    def _join_fit_set(self, feats: WindowFeatures) -> np.ndarray:
        """Which of these windows (time order) join the fit set: those that find their cell
        with fewer than ``per_cell`` windows, counting the ones before them."""
        with np.errstate(invalid="ignore"):
            ijk = np.floor(feats.mean / FIT_CELL_G)
            t = np.floor(feats.temperature / FIT_CELL_C)
        t = np.where(np.isfinite(t), t, 4095.0)  # no temperature: a cell of its own
        ijk = np.clip(ijk, -1000, 1000).astype(np.int64) + 1024
        key = (((ijk[:, 0] << 11) | ijk[:, 1]) << 11 | ijk[:, 2]) << 13 | \
            (np.clip(t, -4096, 4095).astype(np.int64) + 4096)
        cells, first, inv = np.unique(key, return_index=True, return_inverse=True)
        order = np.argsort(inv, kind="stable")  # windows grouped by cell, time order within
        counts = np.bincount(inv, minlength=len(cells))
        rank = np.empty(len(key), np.int64)  # how many windows of its cell come before it here
        rank[order] = np.arange(len(key)) - np.repeat(np.cumsum(counts) - counts, counts)
        before = np.array([self._cells.get(int(c), 0) for c in cells], np.int64)
        keep = before[inv] + rank < self.per_cell
        for c, b, n in zip(cells.tolist(), before.tolist(), counts.tolist()):
            self._cells[c] = min(b + n, self.per_cell)
        return keep

    def _append(self, feats: WindowFeatures) -> None:
        if len(feats) == 0:
            return
        sel = select_calibration_windows(feats, sd_threshold=self.sd_threshold,
                                         max_abs_mean=self.max_abs_mean,
                                         previous_mean=self._last_mean)
        self._offered += len(feats)
        self._last_mean = feats.mean[-1].copy()
        self._last_end = int(feats.start_ns[-1]) + int(round(self.window_s * 1e9))
        if len(sel.features):
            step = self.count_step.step_g if self.count_step is not None else None
            if step is not None:
                self._step = step
            keep = None
            if self.per_cell is not None:
                keep = self._join_fit_set(sel.features)
                self._n_fit += int(keep.sum())
            self._pending.append((sel.features, self._step, keep))  # de-biased at the next fit
            self._n += len(sel.features)

    # ------------------------------------------------------------------ API
    def add(self, features: WindowFeatures) -> list[CalibrationEstimate]:
        """Take the next windows (in time order); return the estimates published because data
        time passed one or more boundaries (each with ``extra["accepted"]``)."""
        out: list[CalibrationEstimate] = []
        if len(features) == 0:
            return out
        if self.start_ns is None:
            self.start_ns = int(features.start_ns[0])
        if self._next_boundary is None:
            self._next_boundary = self.start_ns + self.chunk_ns
        starts = features.start_ns
        i = 0
        while i < len(features):
            j = i + int(np.searchsorted(starts[i:], self._next_boundary, side="left"))
            self._append(features.select(slice(i, j)))
            if j >= len(features):
                break
            # data time has reached the boundary: fit on everything before it
            boundary = self._next_boundary
            out.extend(self._refit(boundary, boundary))
            k = (int(starts[j]) - self.start_ns) // self.chunk_ns + 1
            self._next_boundary = self.start_ns + k * self.chunk_ns
            i = j
        return out

    def finish(self, end_ns: Optional[int] = None) -> list[CalibrationEstimate]:
        """End of stream: a last fit on every window (for the record and the store); it is
        effective from ``end_ns`` (default: end of the last window), i.e. for data after it."""
        if self._n == 0 and self._last_end is None:
            return []
        end = end_ns if end_ns is not None else self._last_end
        return self._refit(end, end, every_window=True)

    # ------------------------------------------------------------------ internals
    def _refit(self, fit_end_ns: int, effective_ns: int, *,
               every_window: bool = False) -> list[CalibrationEstimate]:
        capped = self.per_cell is not None and self._n_fit < self._n
        if every_window and capped:  # the last boundary refit fitted the fit set only
            if self._n == self._final_n:
                return []
        elif self._n == self._n_at_last_fit:
            return []  # no new windows since the last fit: nothing new to say
        self._n_at_last_fit = self._n
        if every_window:
            self._final_n = self._n
        wins = self.windows if every_window or not capped else self.fit_windows
        start = None
        if self.warm_start and self._last_fit is not None:
            start = extrapolated_start(self._last_fit, wins,
                                       temperature=self.fit_options.get("temperature", True),
                                       variant=self.fit_options.get("variant", "auto"))
        est = fit_calibration(wins, select=False, data_start_ns=self.start_ns,
                              data_end_ns=fit_end_ns, device_key=self.device_key,
                              window_s=self.window_s, sd_threshold=self.sd_threshold,
                              max_abs_mean=self.max_abs_mean, windows_offered=self._offered,
                              start=start, quantisation_step_g=self._step,
                              means_dequantised=self._step is not None, **self.fit_options)
        if est.applied:  # a fit that carries non-identity parameters
            self._last_fit = est
        est.effective_from_ns = int(effective_ns)
        est.extra["mode"] = "online"
        if capped and not every_window:  # the fit set: how many nonmovement windows there were
            est.extra["nonmovement_windows"] = self._n
        if est.applied and len(wins):
            # compare both on the same windows (those with a temperature if either needs it)
            if est.uses_temperature or self.current.uses_temperature:
                with_t = wins.select(np.isfinite(wins.temperature))
                if len(with_t) >= MIN_WINDOWS:
                    wins = with_t
            new_err, _ = estimate_error_mg(est, wins)
            cur_err, _ = estimate_error_mg(self.current, wins)
            est.extra["in_force_error_mg"] = cur_err if np.isfinite(cur_err) else None
            if np.isfinite(new_err) and (not np.isfinite(cur_err) or new_err < cur_err):
                est.extra["accepted"] = True
                est.reason = "accepted: " + est.reason
                self.current = est
            else:
                est.extra["accepted"] = False
                est.reason = (f"not applied: error {new_err:.2f} mg is not below the "
                              f"{cur_err:.2f} mg of the estimate in force; " + est.reason)
        else:
            est.extra["accepted"] = False
            est.reason = "not applied: " + est.reason
        self.estimates.append(est)
        return [est]
