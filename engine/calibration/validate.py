"""Checks an estimate before it is applied: every number finite and within what a real sensor's
calibration can be. Called wherever an estimate enters from outside a fit (a store record, a
``--prior`` file, an MCAP's logged prior), so a NaN or absurd value is refused with one line
instead of being applied to every sample.

Ranges (generous: they separate damage from any real calibration):
* offset: |o| <= 0.5 g per axis. MEMS zero-g offsets are tens of mg (ADXL345/BMI160 datasheets:
  +-150 mg worst case); fits on real wear data stay within +-0.1 g.
* scale: 0.5..2.0 per axis. Gains are off by a few percent at most.
* tempoffset: |t| <= 0.05 g/degC per axis. Datasheets give <= +-1.5 mg/degC; fits stay < 5 mg/degC.
* temperature_ref: finite, -40..125 degC (the MCP9700 sensor's span, as the readers use).
"""

from __future__ import annotations

import math
from typing import Any, Mapping, Union

import numpy as np

from stillpoint.drivers.constants import PLAUSIBLE_TEMPERATURE_C
from stillpoint.engine.core.errors import StillpointError

from .estimate import CalibrationEstimate

OFFSET_MAX_G = 0.5
SCALE_RANGE = (0.5, 2.0)
TEMPOFFSET_MAX_G_PER_C = 0.05


class InvalidEstimateError(StillpointError):
    """A calibration estimate (store record, prior file) holds values no sensor can have."""


def validate_estimate(est: Union[CalibrationEstimate, Mapping[str, Any]], source: str) -> CalibrationEstimate:
    """The estimate (built from a dict if needed), or ``InvalidEstimateError`` naming ``source``
    and the first value that is missing, not finite or out of range."""
    def bad(why: str):
        raise InvalidEstimateError(f"{source}: calibration estimate refused: {why}")

    if not isinstance(est, CalibrationEstimate):
        if not isinstance(est, Mapping):
            bad(f"expected a JSON object, found {type(est).__name__}")
        for name in ("offset", "scale", "tempoffset"):
            v = est.get(name)
            if v is not None and not (isinstance(v, (list, tuple)) and len(v) == 3 and all(
                    isinstance(x, (int, float)) and not isinstance(x, bool) for x in v)):
                bad(f"{name} {v!r} is not three numbers")
        try:
            est = CalibrationEstimate.from_dict(dict(est))
        except (TypeError, ValueError) as e:
            bad(f"fields are not numbers of the right shape ({e})")
    for name in ("offset", "scale", "tempoffset"):
        v = getattr(est, name)
        if v.shape != (3,) or not np.isfinite(v).all():
            bad(f"{name} {v.tolist()} is not three finite numbers")
    if (np.abs(est.offset) > OFFSET_MAX_G).any():
        bad(f"offset {est.offset.tolist()} g exceeds +-{OFFSET_MAX_G} g")
    lo, hi = SCALE_RANGE
    if ((est.scale < lo) | (est.scale > hi)).any():
        bad(f"scale {est.scale.tolist()} is outside {lo}..{hi}")
    if (np.abs(est.tempoffset) > TEMPOFFSET_MAX_G_PER_C).any():
        bad(f"tempoffset {est.tempoffset.tolist()} g/degC exceeds +-{TEMPOFFSET_MAX_G_PER_C}")
    tr = est.temperature_ref
    tlo, thi = PLAUSIBLE_TEMPERATURE_C
    if not isinstance(tr, (int, float)) or not math.isfinite(tr) or not tlo <= tr <= thi:
        if est.uses_temperature or not (isinstance(tr, (int, float)) and math.isfinite(tr)):
            bad(f"temperature_ref {tr!r} is not a temperature in {tlo:g}..{thi:g} degC")
    for name in ("fit_start_ns", "fit_end_ns", "effective_from_ns"):
        v = getattr(est, name)
        if v is not None and (not isinstance(v, int) or isinstance(v, bool)):
            bad(f"{name} {v!r} is not an integer time")
    return est
