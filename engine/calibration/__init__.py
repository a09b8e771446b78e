"""Autocalibration (van Hees et al. 2014): fit on nonmovement window features, the batch
72 h + 12 h schedule, online refits, and the per-device calibration store.

    from stillpoint.engine.calibration import (fit_calibration, fit_batch_schedule,
                                               OnlineCalibrator, CalibrationStore,
                                               calibrate_recording, read_features_csv)

Every result is a :class:`CalibrationEstimate` (GGIR-form offset/scale/tempoffset with status,
one-line reason and provenance).
"""

from .estimate import CalibrationEstimate
from .fit import (apply_model, calibration_error_g, estimate_error_mg, fit_calibration,
                  icp_sphere_fit, sphere_coverage, temperature_check)
from .schedule import BatchSchedule, fit_batch_schedule
from .select import nonmovement_mask, repeat_mask, select_calibration_windows

__all__ = [
    "CalibrationEstimate", "fit_calibration", "fit_batch_schedule", "OnlineCalibrator",
    "CalibrationStore", "CalibrationStoreError", "icp_sphere_fit", "apply_model",
    "calibration_error_g", "estimate_error_mg", "sphere_coverage", "temperature_check",
    "nonmovement_mask", "repeat_mask", "select_calibration_windows", "BatchSchedule",
    "calibrate_recording", "calibrate_source", "plot_calibration", "read_features_csv",
]

_LAZY = {  # imported on first use: recording pulls in the engine's operators (which import
    # .select from this package), plot pulls in matplotlib; the online calibrator and the store
    # are not needed by a batch fit (``stillpoint calibrate`` without --store)
    "calibrate_recording": ".recording", "calibrate_source": ".recording",
    "plot_calibration": ".plot", "read_features_csv": ".table",
    "OnlineCalibrator": ".online", "CalibrationStore": ".store",
    "CalibrationStoreError": ".store",
}


def __getattr__(name):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name], __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
