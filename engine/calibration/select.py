"""Which 10 s windows the autocalibration may use: pure selection functions on window features.

A window is a **nonmovement (calibration) window** when, on all three axes, its SD is below
``sd_threshold`` (default 13 mg, van Hees 2014) and ``|mean| < max_abs_mean`` (2 g: drops clipped
data). Runs of consecutive windows whose three means are *identical* (a device lying still on a
table, or data a reader repeated) are collapsed to their first window, so a week on a desk cannot
outweigh the worn days. Windows with a non-finite or zero mean vector are never usable.

These functions are the single definition of the selection: the streaming nonmovement operator
(``engine/operators/nonmovement.py``) and the fit both call them. They work on arrays so that a
stream can apply them chunk by chunk (``previous_mean`` carries the last window across chunks).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from ..features import WindowFeatures

SD_THRESHOLD_G = 0.013  # van Hees 2014: just above the ~10 mg baseline noise SD
MAX_ABS_MEAN_G = 2.0  # van Hees 2014 / GGIR g.calibrate: excludes clipped windows


def nonmovement_mask(mean: np.ndarray, sd: np.ndarray, *, sd_threshold: float = SD_THRESHOLD_G,
                     max_abs_mean: float = MAX_ABS_MEAN_G) -> np.ndarray:
    """(k,) bool: SD < sd_threshold and |mean| < max_abs_mean on all three axes, finite, nonzero."""
    mean = np.asarray(mean, np.float64).reshape(-1, 3)
    sd = np.asarray(sd, np.float64).reshape(-1, 3)
    with np.errstate(invalid="ignore"):
        ok = np.all(sd < sd_threshold, axis=1) & np.all(np.abs(mean) < max_abs_mean, axis=1)
    ok &= np.all(np.isfinite(mean), axis=1) & np.any(mean != 0.0, axis=1)
    return ok


def repeat_mask(mean: np.ndarray, previous_mean: Optional[np.ndarray] = None) -> np.ndarray:
    """(k,) bool: True where a window's three means equal those of the window before it.

    ``previous_mean`` is the last window of the previous chunk (None at the start of a stream).
    """
    mean = np.asarray(mean, np.float64).reshape(-1, 3)
    rep = np.zeros(mean.shape[0], bool)
    if mean.shape[0] > 1:
        rep[1:] = np.all(mean[1:] == mean[:-1], axis=1)
    if previous_mean is not None and mean.shape[0] > 0:
        rep[0] = bool(np.all(mean[0] == np.asarray(previous_mean, np.float64).reshape(3)))
    return rep


@dataclass
class Selection:
    """Result of selecting calibration windows: the windows plus the counts behind them."""

    features: WindowFeatures
    windows_in: int  # windows offered
    repeats_dropped: int  # consecutive identical windows collapsed
    nonmovement: int  # windows kept

    def describe(self) -> str:
        return (f"{self.nonmovement} nonmovement windows of {self.windows_in} "
                f"({self.repeats_dropped} repeated windows collapsed)")


def select_calibration_windows(features: WindowFeatures, *, sd_threshold: float = SD_THRESHOLD_G,
                               max_abs_mean: float = MAX_ABS_MEAN_G,
                               previous_mean: Optional[np.ndarray] = None) -> Selection:
    """Collapse repeated windows (on the full window sequence), then keep nonmovement windows.

    Idempotent: selecting an already selected table returns it unchanged (barring repeats).
    """
    k = len(features)
    rep = repeat_mask(features.mean, previous_mean)
    keep = ~rep & nonmovement_mask(features.mean, features.sd, sd_threshold=sd_threshold,
                                   max_abs_mean=max_abs_mean)
    return Selection(features.select(keep), k, int(rep.sum()), int(keep.sum()))
