"""Plain-language reasons added to a calibration status after the fit."""

from __future__ import annotations

import math


def explain_no_nonmovement(est, quietest_sd_g: float, sd_threshold_g: float) -> None:
    """When no window was still because even the quietest one is noisier than the threshold (the
    sensor's own noise at a high rate, e.g. 3,200 Hz), say so in ``est.reason``."""
    if est.status != "no_nonmovement" or not math.isfinite(quietest_sd_g):
        return
    if quietest_sd_g < sd_threshold_g:
        return
    est.reason += (f"; even the quietest window has an SD of {quietest_sd_g * 1000:.1f} mg on its "
                   f"noisiest axis, above the {sd_threshold_g * 1000:g} mg threshold: if the device "
                   "ever lay still, its noise at this sample rate (e.g. 3,200 Hz) exceeds the "
                   "threshold (--sd-threshold-mg sets it)")
    est.extra["quietest_window_sd_mg"] = round(quietest_sd_g * 1000, 3)
