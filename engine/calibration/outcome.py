"""A run's calibration outcome: one value from which every place that reports it is produced.

``CalibrationOutcome(estimate, applied)`` gives the ``/calibration`` message, the ``/qc`` event,
the ``calibration`` metadata record, the run summary's ``calibration`` entry and the day table's
``calibration`` column, so they cannot disagree (the same status, reason and coefficients);
``from_record`` reads the record back from a log (old logs included). ``store_refusal`` is the one
rule for adding a run's final estimate to the calibration store (``process --store`` and the
station).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Optional

from .estimate import STATIC_METHOD, CalibrationEstimate


@dataclass
class CalibrationOutcome:
    """An estimate as a run reports it: ``applied`` says whether the corrected stream uses it
    (by default: whether its status is applied)."""

    estimate: CalibrationEstimate
    applied: Optional[bool] = None

    def __post_init__(self):
        if self.applied is None:
            self.applied = self.estimate.applied
        self.applied = bool(self.applied)

    @property
    def status(self):
        """The estimate's ``CalibrationStatus``."""
        return self.estimate.status

    def explain(self, quietest_sd_g: float, sd_threshold_g: float,
                rate_hz: Optional[float] = None) -> "CalibrationOutcome":
        """Say why no window was still when even the quietest one is noisier than the threshold
        (in the estimate's reason, so every report below gives the same reason). Once only."""
        est = self.estimate
        if (est.status != "no_nonmovement" or not math.isfinite(quietest_sd_g)
                or quietest_sd_g < sd_threshold_g or "quietest_window_sd_mg" in est.extra):
            return self
        rate_text = (f"{rate_hz:,.6g} Hz" if rate_hz and math.isfinite(rate_hz) and rate_hz > 0
                     else "this sample rate")
        est.reason += (f"; even the quietest window has an SD of {quietest_sd_g * 1000:.1f} mg on "
                       f"its noisiest axis, above the {sd_threshold_g * 1000:g} mg threshold: if "
                       f"the device ever lay still, its noise at {rate_text} exceeds the "
                       "threshold (--sd-threshold-mg sets it)")
        est.extra["quietest_window_sd_mg"] = round(quietest_sd_g * 1000, 3)
        return self

    def message(self, **fields) -> dict:
        """The ``/calibration`` message: the estimate, whether it is applied, and
        ``fitted_at_ns`` (the end of the data it was fitted on); ``fields`` are added."""
        d = self.estimate.to_dict()
        d["applied"] = self.applied
        d["fitted_at_ns"] = self.estimate.fit_end_ns
        d.update(fields)
        return d

    def qc_event(self) -> dict:
        """The ``/qc`` event a batch run logs at its first sample."""
        est = self.estimate
        return {"source": "engine", "reason": "calibration", "status": est.status,
                "applied": self.applied, "method": est.method, "detail": est.reason}

    def record(self) -> dict:
        """The ``calibration`` metadata record."""
        return {"json": self.estimate.to_json()}

    def summary(self) -> dict:
        """The run summary's ``calibration`` entry."""
        est = self.estimate
        return {"offset": est.offset.tolist(), "scale": est.scale.tolist(),
                "tempoffset": est.tempoffset.tolist(), "temperature_ref": est.temperature_ref,
                "error_before_mg": est.error_before_mg, "error_after_mg": est.error_after_mg,
                "hours_used": est.hours_used, "status": est.status, "reason": est.reason,
                "method": est.method, "windows": est.windows,
                "fit_start_ns": est.fit_start_ns, "fit_end_ns": est.fit_end_ns,
                "uncertainty": est.uncertainty, "warnings": list(est.diagnostics.warnings or ())}

    @property
    def table_status(self) -> str:
        """The day table's ``calibration`` column."""
        return str(self.estimate.status)

    @staticmethod
    def from_record(record: dict) -> "CalibrationOutcome":
        """The outcome of a log's ``calibration`` metadata record (unchecked; the log readers
        check it, ``engine/mcap/replay.py``); an identity estimate when the log has none."""
        if "json" not in (record or {}):
            return CalibrationOutcome(CalibrationEstimate.identity("no calibration record"))
        return CalibrationOutcome(CalibrationEstimate.from_dict(json.loads(record["json"])))


def store_refusal(est: CalibrationEstimate) -> Optional[str]:
    """Why a run's final estimate is not added to the calibration store (None: it is added).
    Only an applied autocalibration is stored: an estimate that was not applied holds no fit
    worth keeping, and a six-orientation calibration came from the store (or is added to it by
    `static-calibrate --store`) already."""
    if not est.applied:
        return f"final estimate {est.status}: not stored"
    if est.method == STATIC_METHOD:
        return "final estimate is a six-orientation calibration: not stored again"
    return None
