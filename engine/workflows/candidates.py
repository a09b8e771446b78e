"""The library of candidate effects: each one a named term of the simulator's sensor model, with the
covariate whose pattern in the residual would name it, its display units and when it applies.

For a window with corrected direction u (unit vector) the norm residual r = ||a|| - 1 responds to a
small error dp in one parameter as r ~ -dp * weight(u) * x, where x is the naming covariate:

=====================  ======  ===================  ====================  ================
effect                 axis    x (covariate)        weight(u)             units shown
=====================  ======  ===================  ====================  ================
offset                 k       1 (constant)         u_k                   mg
gain                   k       1                    u_k^2                 % (gain - 1)
temperature_offset     k       T - T_ref            u_k                   mg/degC
temperature_gain       k       T - T_ref            u_k^2                 %/degC
misalignment           a,b     1                    2 u_a u_b             % coupling
nonlinearity           k       1                    u_k^3                 mg/g^2
thermal_lag            all     dT/dt                sum_k u_k dread_k/dT  s
offset_drift           k       t since start        u_k                   mg/day
=====================  ======  ===================  ====================  ================
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import List, Optional, Tuple

import numpy as np

from .sensor_fit import AXES, PAIR_INDEX, PAIRS, SensorModel, WindowData


LIBRARY = ("temperature_offset", "temperature_gain", "misalignment", "thermal_lag", "offset_drift",
           "nonlinearity", "offset", "gain")


@dataclass(frozen=True)
class Unit:
    name: str  # shown to users
    factor: float  # display = factor * (internal - origin)
    origin: float = 0.0

    def show(self, internal: float) -> float:
        return self.factor * (internal - self.origin)

    def show_se(self, se: float) -> float:
        return abs(self.factor) * se


UNITS = {
    "offset": Unit("mg", 1000.0),
    "gain": Unit("%", 100.0, 1.0),
    "temperature_offset": Unit("mg/degC", 1000.0),
    "temperature_gain": Unit("%/degC", 100.0),
    "misalignment": Unit("%", 100.0),
    "nonlinearity": Unit("mg/g^2", 1000.0),
    "thermal_lag": Unit("s", 1.0),
    "offset_drift": Unit("mg/day", 1000.0),
}

DESCRIPTION = {
    "offset": "zero-g offset",
    "gain": "sensitivity (gain) error",
    "temperature_offset": "temperature-dependent offset",
    "temperature_gain": "temperature-dependent gain",
    "misalignment": "cross-axis misalignment (non-orthogonality)",
    "nonlinearity": "quadratic nonlinearity",
    "thermal_lag": "thermal lag of the temperature sensor behind the accelerometer",
    "offset_drift": "slow offset drift over the recording",
}

COVARIATE_NAME = {
    "offset": "orientation u_{axis}",
    "gain": "orientation u_{axis}^2",
    "temperature_offset": "temperature (degC)",
    "temperature_gain": "temperature (degC)",
    "misalignment": "orientation u_{a}*u_{b}",
    "nonlinearity": "orientation u_{axis}^3",
    "thermal_lag": "dT/dt (degC/min)",
    "offset_drift": "time since start (days)",
}


@dataclass(frozen=True)
class Candidate:
    effect: str
    component: str  # "x", "y", "z", "xy", "xz", "yz" or "all"

    @property
    def label(self) -> str:
        return f"{self.effect}[{self.component}]"

    @property
    def unit(self) -> Unit:
        return UNITS[self.effect]

    def applies(self, model: SensorModel, data: WindowData) -> Tuple[bool, str]:
        if (self.effect, self.component) in model.active:
            return False, "already in the model"
        if self.effect in ("temperature_offset", "temperature_gain", "thermal_lag") \
                and not data.has_temperature:
            return False, "no usable temperature"
        if self.effect == "thermal_lag":
            if not model.has_temperature_terms():
                return False, "needs a temperature term in the model first"
            if not np.any(data.dtdt):
                return False, "no temperature change in the data"
        if self.effect == "offset_drift" and np.ptp(data.t_days) < 0.5:
            return False, "recording shorter than 12 h"
        return True, ""

    def covariate_name(self) -> str:
        n = COVARIATE_NAME[self.effect]
        if self.effect == "misalignment":
            a, b = self.component
            return n.format(a=a, b=b)
        return n.format(axis=self.component)

    def covariate(self, model: SensorModel, data: WindowData, u: np.ndarray
                  ) -> Tuple[np.ndarray, np.ndarray]:
        """(x, sign-and-weight w) per window so that r * sign(w) against x shows the effect
        where |w| is large; see the module table."""
        e, c = self.effect, self.component
        if e == "nonlinearity":
            k = AXES.index(c)
            return u[:, k] ** 3, np.ones(u.shape[0])
        if e in ("offset", "gain", "temperature_offset", "temperature_gain", "offset_drift"):
            k = AXES.index(c)
            w = u[:, k] if e in ("offset", "temperature_offset", "offset_drift") else u[:, k] ** 2
            x = {"offset": u[:, k], "gain": u[:, k] ** 2,
                 "temperature_offset": data.temperature, "temperature_gain": data.temperature,
                 "offset_drift": data.t_days}[e]
            if e in ("offset", "gain"):
                w = np.ones_like(w)
            return x, w
        if e == "misalignment":
            a, b = PAIR_INDEX[c]
            return u[:, a] * u[:, b], np.ones(u.shape[0])
        if e == "thermal_lag":
            v = model.values
            dread = v["temperature_offset"] + v["temperature_gain"] * v["gain"] * u
            return data.dtdt * 60.0, np.sum(u * dread, axis=1) * 1000.0
        raise KeyError(e)

    def regressor(self, model: SensorModel, data: WindowData, u: np.ndarray) -> np.ndarray:
        """Linearised response of r to this parameter (for the locate table)."""
        x, w = self.covariate(model, data, u)
        e = self.effect
        if e in ("offset", "gain", "misalignment", "nonlinearity"):
            return x
        if e in ("temperature_offset", "temperature_gain"):
            return w * np.nan_to_num(x - model.temperature_ref)
        return w * x


def library(model: SensorModel, data: WindowData, effects: Optional[List[str]] = None
            ) -> Tuple[List[Candidate], List[Tuple[Candidate, str]]]:
    """Every candidate (effect, component) not yet in the model: (applicable, [(skipped, why)])."""
    names = effects or list(LIBRARY)
    comps = {"misalignment": PAIRS, "thermal_lag": ("all",)}
    ok, skipped = [], []
    for e in names:
        for c in comps.get(e, AXES):
            cand = Candidate(e, c)
            good, why = cand.applies(model, data)
            if good:
                ok.append(cand)
            elif why != "already in the model":
                skipped.append((cand, why))
    return ok, skipped
