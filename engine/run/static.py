"""The static (six-orientation) calibration a run applies instead of fitting its own."""

from __future__ import annotations

from ..calibration.estimate import CalibrationEstimate


def static_estimate(d: dict, info, first_ns, summary) -> CalibrationEstimate:
    """The static calibration to apply: same device only; the gap to the recording is logged
    (the run summary's ``static_calibration``)."""
    from ..calibration.estimate import STATIC_METHOD
    from ..calibration.static import StaticCalibrationError
    est = CalibrationEstimate.from_dict(dict(d))
    if est.method != STATIC_METHOD:
        raise StaticCalibrationError(f"the static calibration given has method {est.method!r}, "
                                     f"not {STATIC_METHOD!r}")
    if est.device_key and est.device_key != info.device_key:
        raise StaticCalibrationError(
            f"{info.path}: the static calibration is for device {est.device_key}, the recording is "
            f"from {info.device_key}")
    if est.status != "ok":
        raise StaticCalibrationError(f"the static calibration has status {est.status!r}: not applied")
    gap_h = None
    if first_ns is not None and est.fit_end_ns is not None:
        gap_h = (int(first_ns) - int(est.fit_end_ns)) / 3.6e12
    full = bool((est.extra.get("static") or {}).get("matrix"))
    est.effective_from_ns = None
    est.extra = dict(est.extra, applied_as="static", gap_hours=gap_h)
    summary.static_calibration = {"device_key": est.device_key, "fit_end_ns": est.fit_end_ns,
                                  "gap_hours": gap_h, "full_matrix_not_applied": full}
    return est
