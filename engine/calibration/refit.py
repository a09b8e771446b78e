"""Warm starts for repeated fits on a growing window table (online refits every 12 h).

The ICP converges linearly: near its fixed point every iteration shrinks the distance to it by a
nearly constant factor (~0.7 on wrist data), so a fit from identity to the 1e-9 parameter
tolerance takes ~45 iterations, each over every window seen so far. A refit 12 h later has a
few percent more windows and a fixed point a few 1e-5 away from the previous one.

:func:`extrapolated_start` starts from the previous fit (re-referenced to the new mean
temperature), runs a few single ICP iterations and extrapolates their geometric sequence to its
limit (Aitken's delta-squared along the step direction), three times. The fit proper then runs
from that point with its usual stopping rule, typically for one or two iterations, so the
result is the same fixed point within the fit's tolerance; only the path to it is shorter
(~11 iterations in all instead of ~45). Pure functions; the online calibrator keeps the state.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Optional

import numpy as np

from ..features import WindowFeatures
from .estimate import CalibrationEstimate
from .fit import icp_sphere_fit, rereference, temperature_check

APPLICABLE = ("ok", "high_error")  # fit outcomes with parameters worth starting from
ROUNDS = 3  # extrapolation rounds
STEPS = 3  # single iterations per round (two steps give the ratio, the third checks it)
MAX_RATIO = 0.98  # a step ratio at or above this is not a geometric sequence: no extrapolation


def fit_inputs(windows: WindowFeatures, *, temperature: bool = True, variant: str = "auto"):
    """(mean, temperature - T_ref or None, T_ref) as :func:`fit_calibration` will fit them
    (usable windows; those without temperature dropped when the term is used)."""
    mean, temps = windows.mean, windows.temperature
    usable = np.all(np.isfinite(mean), axis=1) & np.any(mean != 0.0, axis=1)
    mean, temps = mean[usable], temps[usable]
    if temperature and variant in ("auto", "c2") and temperature_check(temps)[0]:
        ok = np.isfinite(temps)
        mean, temps = mean[ok], temps[ok]
        t_ref = float(np.mean(temps))
        return mean, temps - t_ref, t_ref
    return mean, None, 0.0


def _step_ratio(d1: np.ndarray, d2: np.ndarray) -> float:
    den = float(np.dot(d1, d1))
    return float(np.dot(d2, d1)) / den if den > 0 else 0.0


def extrapolated_start(previous: CalibrationEstimate, windows: WindowFeatures, *,
                       temperature: bool = True, variant: str = "auto",
                       rounds: int = ROUNDS) -> Optional[CalibrationEstimate]:
    """A start for the fit on ``windows`` near its fixed point, from ``previous`` (a fit on a
    subset of them); None when ``previous`` is not a usable start."""
    if previous is None or previous.status not in APPLICABLE:
        return None
    if variant not in ("auto", "c1", "c2"):
        return previous  # offset- or scale-only fits: plain warm start
    mean, tc, t_ref = fit_inputs(windows, temperature=temperature, variant=variant)
    if mean.shape[0] < 3:
        return None
    x = previous
    if tc is not None and x.uses_temperature:
        x = rereference(x, t_ref)
    v = np.concatenate([x.offset, x.scale, x.tempoffset if tc is not None else np.zeros(3)])
    for _ in range(rounds):
        seq = [v]
        for _ in range(STEPS):
            r = icp_sphere_fit(mean, tc, max_iter=1, start=(v[:3], v[3:6], v[6:]))
            if r.failed:
                return previous
            v = np.concatenate([r.offset, r.scale, r.tempoffset])
            seq.append(v)
            if r.converged:
                break
        if len(seq) < STEPS + 1:
            break  # already within the tolerance
        d1, d2 = seq[-2] - seq[-3], seq[-1] - seq[-2]
        rho = _step_ratio(d1, d2)
        if 0.0 < rho < MAX_RATIO:
            v = seq[-1] + d2 * (rho / (1.0 - rho))
    if not np.all(np.isfinite(v)):
        return previous
    return replace(previous, offset=v[:3].copy(), scale=v[3:6].copy(), tempoffset=v[6:].copy(),
                   temperature_ref=t_ref if tc is not None else previous.temperature_ref,
                   extra={})
