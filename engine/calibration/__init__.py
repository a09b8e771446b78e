"""Autocalibration (van Hees et al. 2014): fit on nonmovement window features, the batch
72 h + 12 h schedule, online refits, and the per-device calibration store.

    from stillpoint.engine.calibration import (fit_calibration, fit_batch_schedule,
                                               OnlineCalibrator, CalibrationStore)

Every result is a :class:`CalibrationEstimate` (GGIR-form offset/scale/tempoffset with status,
one-line reason and provenance).
"""

from .estimate import CalibrationEstimate
from .fit import (apply_model, calibration_error_g, estimate_error_mg, fit_calibration,
                  icp_sphere_fit, sphere_coverage, temperature_check)
from .online import OnlineCalibrator
from .schedule import fit_batch_schedule
from .select import nonmovement_mask, repeat_mask, select_calibration_windows
from .store import CalibrationStore, CalibrationStoreError

__all__ = [
    "CalibrationEstimate", "fit_calibration", "fit_batch_schedule", "OnlineCalibrator",
    "CalibrationStore", "CalibrationStoreError", "icp_sphere_fit", "apply_model",
    "calibration_error_g", "estimate_error_mg", "sphere_coverage", "temperature_check",
    "nonmovement_mask", "repeat_mask", "select_calibration_windows",
]
