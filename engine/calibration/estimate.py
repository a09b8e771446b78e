"""A calibration estimate: the GGIR-form model plus its provenance (value with a history).

Model, per axis k (van Hees 2014; GGIR g.calibrate):

    cal_k = (raw_k + offset_k) * scale_k + (T - temperature_ref) * tempoffset_k

``raw`` in g, T in degC. Estimates are produced by the fit (engine.calibration), logged to MCAP,
kept per device in the calibration store, and applied by the correction operator.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from typing import Optional

import numpy as np

STATIC_METHOD = "static-6"  # the method of an estimate from a six-orientation session (static.py)


@dataclass
class CalibrationEstimate:
    offset: np.ndarray = field(default_factory=lambda: np.zeros(3))
    scale: np.ndarray = field(default_factory=lambda: np.ones(3))
    tempoffset: np.ndarray = field(default_factory=lambda: np.zeros(3))
    temperature_ref: float = 0.0
    status: str = "identity"  # "ok", "identity", "reverted", "no_nonmovement", "sphere_not_covered", ...
    reason: str = "no calibration applied"  # one line for humans
    method: str = "identity"  # "autocal-c1", "autocal-c2", "static-6", "identity", ...
    error_before_mg: Optional[float] = None
    error_after_mg: Optional[float] = None
    windows: int = 0
    iterations: int = 0
    hours_used: Optional[float] = None
    fit_start_ns: Optional[int] = None  # data range the estimate was fitted on
    fit_end_ns: Optional[int] = None
    effective_from_ns: Optional[int] = None  # data time from which it is applied (None: from start)
    device_key: Optional[str] = None
    extra: dict = field(default_factory=dict)
    # one standard error per coefficient, same units: {"offset": [3], "scale": [3],
    # "tempoffset": [3], "temperature_ref": x} (None for a coefficient not fitted; the whole
    # field None when nothing was fitted). See engine/calibration/uncertainty.py.
    uncertainty: Optional[dict] = None

    def __post_init__(self):
        self.offset = np.asarray(self.offset, np.float64).reshape(3)
        self.scale = np.asarray(self.scale, np.float64).reshape(3)
        self.tempoffset = np.asarray(self.tempoffset, np.float64).reshape(3)

    @staticmethod
    def identity(reason: str = "no calibration applied") -> "CalibrationEstimate":
        return CalibrationEstimate(reason=reason)

    @property
    def uses_temperature(self) -> bool:
        return bool(np.any(self.tempoffset != 0))

    def apply(self, accel_g: np.ndarray, temperature_c=None, out=None) -> np.ndarray:
        """Calibrated acceleration (n, 3) from raw g (n, 3) and per-sample temperature (n,)."""
        a = np.add(accel_g, self.offset, out=out)
        a *= self.scale
        if self.uses_temperature:
            if temperature_c is None:
                raise ValueError("this estimate has a temperature term; temperature is required")
            a += (np.asarray(temperature_c, np.float64) - self.temperature_ref)[:, None] * self.tempoffset
        return a

    def to_dict(self) -> dict:
        d = asdict(self)
        for k in ("offset", "scale", "tempoffset"):
            d[k] = [float(x) for x in getattr(self, k)]
        return d

    @staticmethod
    def from_dict(d: dict) -> "CalibrationEstimate":
        known = CalibrationEstimate.__dataclass_fields__
        return CalibrationEstimate(**{k: v for k, v in d.items() if k in known})

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), sort_keys=True)
