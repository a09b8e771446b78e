"""A calibration estimate: the GGIR-form model plus its provenance (value with a history).

Model, per axis k (van Hees 2014; GGIR g.calibrate):

    cal_k = (raw_k + offset_k) * scale_k + (T - temperature_ref) * tempoffset_k

``raw`` in g, T in degC. Estimates are produced by the fit (engine.calibration), logged to MCAP,
kept per device in the calibration store, and applied by the correction operator.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from enum import Enum
from typing import Optional, Union

import numpy as np

STATIC_METHOD = "static-6"  # the method of an estimate from a six-orientation session (static.py)

# Which estimate a table's numbers were corrected with (the day table's ``calibration_source``):
# the recording's own final fit, a prior fitted on an earlier recording of the device (``--prior``
# or the calibration store, kept where the trust rules prefer it to the recording's fits), a
# six-orientation static calibration, or none (identity: nothing could be applied).
SOURCE_RECORDING = "recording_final"
SOURCE_PRIOR = "prior"
SOURCE_STATIC = "static"
SOURCE_NONE = "none"


def calibration_source(est: "CalibrationEstimate", applied: bool, first_ns=None) -> str:
    """The ``SOURCE_*`` of an estimate applied to a recording whose first sample is at
    ``first_ns``: a fit that ended before the recording began is a prior from an earlier one."""
    if not applied:
        return SOURCE_NONE
    if est.method == STATIC_METHOD:
        return SOURCE_STATIC
    if first_ns is not None and est.fit_end_ns is not None and int(est.fit_end_ns) <= int(first_ns):
        return SOURCE_PRIOR
    return SOURCE_RECORDING


class CalibrationStatus(str, Enum):
    """The outcome of a calibration fit (the ``status`` of an estimate, its logs and its tables).

    A text enum: a member equals, hashes, formats and serialises as its value, so ``"ok"`` in a
    log and ``CalibrationStatus.OK`` are the same thing. ``applied`` says whether a run applies an
    estimate with this status: a converged fit whose residual error is high is still better than
    none, so it is applied (and its status says so); every other outcome leaves the data
    uncorrected."""

    OK = "ok"
    HIGH_ERROR = "high_error"  # converged, residual error above the bound: applied, flagged
    IDENTITY = "identity"  # no calibration (switched off, no samples, online before a refit)
    REVERTED = "reverted"  # the fit made the error worse: not applied
    NO_NONMOVEMENT = "no_nonmovement"
    SPHERE_NOT_COVERED = "sphere_not_covered"
    TOO_FEW_WINDOWS = "too_few_windows"
    FAILED = "failed"
    INCOMPLETE = "incomplete"  # a six-orientation session missing a face

    __str__ = str.__str__
    __format__ = str.__format__

    @property
    def applied(self) -> bool:
        """Whether a run applies an estimate with this status."""
        return self in (CalibrationStatus.OK, CalibrationStatus.HIGH_ERROR)

    @classmethod
    def parse(cls, value) -> Union["CalibrationStatus", str]:
        """The member for a status text; a text no member has (a log written by another
        version) is kept as it is, and is never applied."""
        try:
            return cls(value)
        except ValueError:
            return value


def status_applied(status) -> bool:
    """Whether a run applies an estimate of this status (a text from a log, or a member)."""
    s = CalibrationStatus.parse(status)
    return isinstance(s, CalibrationStatus) and s.applied




@dataclass
class CalibrationEstimate:
    offset: np.ndarray = field(default_factory=lambda: np.zeros(3))
    scale: np.ndarray = field(default_factory=lambda: np.ones(3))
    tempoffset: np.ndarray = field(default_factory=lambda: np.zeros(3))
    temperature_ref: float = 0.0
    status: str = CalibrationStatus.IDENTITY  # a CalibrationStatus (a text no member has is kept)
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
    extra: dict = field(default_factory=dict)  # the fit's diagnostics: FitDiagnostics.to_extra()
    # one standard error per coefficient, same units: {"offset": [3], "scale": [3],
    # "tempoffset": [3], "temperature_ref": x} (None for a coefficient not fitted; the whole
    # field None when nothing was fitted). See engine/calibration/uncertainty.py.
    uncertainty: Optional[dict] = None

    def __post_init__(self):
        self.offset = np.asarray(self.offset, np.float64).reshape(3)
        self.scale = np.asarray(self.scale, np.float64).reshape(3)
        self.tempoffset = np.asarray(self.tempoffset, np.float64).reshape(3)
        self.status = CalibrationStatus.parse(self.status)

    @staticmethod
    def identity(reason: str = "no calibration applied") -> "CalibrationEstimate":
        return CalibrationEstimate(reason=reason)

    @property
    def applied(self) -> bool:
        """Whether a run applies this estimate (its status; see ``CalibrationStatus.applied``)."""
        return status_applied(self.status)

    @property
    def diagnostics(self) -> "FitDiagnostics":
        """The fit's diagnostics (``extra``) as typed fields (a copy: assign it back to keep a
        change)."""
        return FitDiagnostics.from_extra(self.extra)

    @diagnostics.setter
    def diagnostics(self, d: "FitDiagnostics") -> None:
        self.extra = d.to_extra()

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


@dataclass
class FitDiagnostics:
    """What a fit reports beside its coefficients, typed. The fit (engine/calibration/fit.py)
    fills one and the estimate keeps it as ``extra`` (``to_extra``), the form logs, the store
    and old logs hold; ``from_extra`` reads it back. A field that is None was not reported (its
    key is absent from ``extra``); keys this class does not name are kept in ``other``.

    ``warnings``: (code, message) dicts, most important first; ``flags``: their codes and other
    conditions (``short``, ``not_converged``, ...); ``accepted``: online, whether the refit took
    effect (None in batch); ``schedule``: batch, every attempt (hours, windows, status, errors).
    ``res_final`` (the last residual, possibly None) is reported whenever ``converged`` is."""

    variant: Optional[str] = None
    ggir_compatible: Optional[bool] = None
    windows_offered: Optional[int] = None
    flags: Optional[list] = None
    warnings: Optional[list] = None
    repeats_collapsed: Optional[int] = None
    windows_unusable: Optional[int] = None
    means_dequantised: Optional[bool] = None
    sphere_min_g: Optional[list] = None
    sphere_max_g: Optional[list] = None
    windows_without_temperature: Optional[int] = None
    temperature_used: Optional[bool] = None
    temperature_reason: Optional[str] = None
    warm_start: Optional[bool] = None
    converged: Optional[bool] = None
    stop_rule: Optional[str] = None
    res_final: Optional[float] = None
    rejected_fit: Optional[dict] = None
    error_before_g: Optional[float] = None
    error_after_g: Optional[float] = None
    uncertainty_blocks: Optional[int] = None
    temperature_dropped: Optional[dict] = None
    temperature_fallback_failed: Optional[str] = None
    accepted: Optional[bool] = None
    mode: Optional[str] = None
    schedule: Optional[list] = None
    quietest_window_sd_mg: Optional[float] = None
    other: dict = field(default_factory=dict)

    def flag(self, code: str) -> None:
        """Add a flag."""
        self.flags = [*(self.flags or ()), code]

    def to_extra(self) -> dict:
        """The ``extra`` dict of an estimate: every reported field, then ``other``."""
        out = {}
        for name in _DIAGNOSTIC_FIELDS:
            v = getattr(self, name)
            if v is not None or (name == "res_final" and self.converged is not None):
                out[name] = list(v) if isinstance(v, (list, tuple)) else v
        out.update(self.other)
        return out

    @staticmethod
    def from_extra(extra: Optional[dict]) -> "FitDiagnostics":
        """The typed view of an estimate's ``extra`` dict (lists are copied)."""
        e = dict(extra or {})
        known = {k: (list(e.pop(k)) if isinstance(e.get(k), (list, tuple)) else e.pop(k))
                 for k in _DIAGNOSTIC_FIELDS if k in e}
        return FitDiagnostics(**known, other=e)


_DIAGNOSTIC_FIELDS = tuple(n for n in FitDiagnostics.__dataclass_fields__ if n != "other")
