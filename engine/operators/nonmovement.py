"""Nonmovement accumulator: keeps the calibration windows of a stream of window features.

Selection rule (engine.calibration.select, the single definition shared with the fit): SD below
``sd_threshold`` (13 mg) and |mean| below ``max_abs_mean`` (2 g) on all axes; runs of consecutive
windows with identical means collapsed to their first window. The last window seen is carried
across pushes, so the result does not depend on how the feature stream was cut.

``push(features)`` returns the newly selected windows and also appends them to ``selected``
(a week is ~60k rows at most: tiny), which the batch fit reads at the end of pass 1.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from ..calibration.select import MAX_ABS_MEAN_G, SD_THRESHOLD_G, select_calibration_windows
from ..features import WindowFeatures


class NonmovementOperator:
    def __init__(self, sd_threshold: float = SD_THRESHOLD_G, max_abs_mean: float = MAX_ABS_MEAN_G,
                 keep: bool = True):
        self.sd_threshold = float(sd_threshold)
        self.max_abs_mean = float(max_abs_mean)
        self.keep = keep
        self._prev: Optional[np.ndarray] = None
        self._parts: list[WindowFeatures] = []
        self.windows_in = 0
        self.repeats_dropped = 0
        self.selected_total = 0
        self.quietest_sd_g = float("inf")  # smallest noisiest-axis SD of any window seen

    def push(self, features: WindowFeatures) -> WindowFeatures:
        if len(features) == 0:
            return WindowFeatures.empty()
        q = np.max(features.sd, axis=1)
        q = q[np.isfinite(q)]
        if q.size:
            self.quietest_sd_g = min(self.quietest_sd_g, float(q.min()))
        sel = select_calibration_windows(features, sd_threshold=self.sd_threshold,
                                         max_abs_mean=self.max_abs_mean, previous_mean=self._prev)
        self._prev = np.array(features.mean[-1])
        self.windows_in += sel.windows_in
        self.repeats_dropped += sel.repeats_dropped
        self.selected_total += len(sel.features)
        if self.keep and len(sel.features):
            self._parts.append(sel.features)
        return sel.features

    def flush(self) -> WindowFeatures:
        return WindowFeatures.empty()

    @property
    def selected(self) -> WindowFeatures:
        if len(self._parts) > 1:
            self._parts = [WindowFeatures.concat(self._parts)]
        return self._parts[0] if self._parts else WindowFeatures.empty()

    @property
    def count(self) -> int:
        return self.selected_total
