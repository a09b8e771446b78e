"""Fit a sensor model of named effects to the means of nonmovement windows (robust least squares).

Forward model (what the sensor reads, in g, for true acceleration ``u`` in g, temperature T in degC,
time t in days since the start of the recording):

    T_eff = T + thermal_lag * dT/dt                      (accelerometer die leads the temperature sensor)
    read  = (I + S) @ diag(gain * (1 + temperature_gain * (T_eff - T_ref))) @ u
            + offset + temperature_offset * (T_eff - T_ref) + offset_drift * t

``S`` is symmetric with zero diagonal, ``S[a, b] = misalignment[ab]``: the part of a cross-axis
coupling that the norm of gravity can see (a common rotation cannot be seen by a norm and is not
modelled). Every term is affine in ``u``, so the model inverts exactly:

    a = diag(1 / gain(T)) @ (I + S)^-1 @ (read - offset(T, t))

For a still window ``u`` is 1 g in an unknown direction, so the residual of window i is
``r_i = ||a_i|| - 1`` (g). The fit minimises a soft-L1 (Huber-like) loss of r with a 10 mg scale over
the free parameters, so a few windows that were not quite still do not steer it. Parameters of
inactive terms stay fixed at their values (normally zero).

Pure functions on plain arrays; no I/O. Units inside: g, degC, seconds, days.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Dict, List, Optional, Tuple

import numpy as np
from scipy.optimize import least_squares

AXES = ("x", "y", "z")
PAIRS = ("xy", "xz", "yz")
PAIR_INDEX = {"xy": (0, 1), "xz": (0, 2), "yz": (1, 2)}

# effect -> (component labels, neutral value, shape)
EFFECT_COMPONENTS: Dict[str, Tuple[str, ...]] = {
    "offset": AXES,
    "gain": AXES,
    "temperature_offset": AXES,
    "temperature_gain": AXES,
    "misalignment": PAIRS,
    "thermal_lag": ("all",),
    "offset_drift": AXES,
}
NEUTRAL = {"gain": 1.0}
TEMPERATURE_EFFECTS = ("temperature_offset", "temperature_gain")
LOSS_SCALE_G = 0.010  # soft-L1 scale: residuals below ~10 mg count as squared (van Hees weights cap)


def component_index(effect: str, comp: str) -> int:
    return EFFECT_COMPONENTS[effect].index(comp)


@dataclass
class WindowData:
    """Nonmovement windows as the fit sees them (plain arrays, one row per window)."""

    mean: np.ndarray  # (n, 3) g
    temperature: np.ndarray  # (n,) degC (NaN when unknown)
    dtdt: np.ndarray  # (n,) degC / s of the temperature sensor
    t_days: np.ndarray  # (n,) days since the start of the recording
    sd: Optional[np.ndarray] = None  # (n, 3) g, for the distribution checks

    def __len__(self):
        return int(self.mean.shape[0])

    def take(self, idx) -> "WindowData":
        return WindowData(self.mean[idx], self.temperature[idx], self.dtdt[idx], self.t_days[idx],
                          None if self.sd is None else self.sd[idx])

    @property
    def has_temperature(self) -> bool:
        return bool(np.all(np.isfinite(self.temperature))) and float(np.std(self.temperature)) > 0.01


@dataclass
class SensorModel:
    """Parameter values of every effect plus the set of free (switched-on) components."""

    values: Dict[str, np.ndarray] = field(default_factory=dict)
    active: List[Tuple[str, str]] = field(default_factory=list)  # [(effect, component)]
    temperature_ref: float = 25.0

    def __post_init__(self):
        for eff, comps in EFFECT_COMPONENTS.items():
            v = self.values.get(eff)
            if v is None:
                v = np.full(len(comps), NEUTRAL.get(eff, 0.0))
            self.values[eff] = np.asarray(v, np.float64).reshape(len(comps)).copy()

    @staticmethod
    def baseline(temperature_ref: float = 25.0) -> "SensorModel":
        """Offset + gain on every axis: the van Hees C1 model."""
        act = [("offset", a) for a in AXES] + [("gain", a) for a in AXES]
        return SensorModel(active=act, temperature_ref=temperature_ref)

    def copy(self) -> "SensorModel":
        return SensorModel({k: v.copy() for k, v in self.values.items()}, list(self.active),
                           self.temperature_ref)

    def with_component(self, effect: str, comp: str) -> "SensorModel":
        m = self.copy()
        if (effect, comp) not in m.active:
            m.active.append((effect, comp))
        return m

    def effects_on(self) -> List[str]:
        seen = []
        for e, _ in self.active:
            if e not in seen:
                seen.append(e)
        return seen

    def has_temperature_terms(self) -> bool:
        return any(e in TEMPERATURE_EFFECTS for e, _ in self.active)

    # -- packing of the free parameters ------------------------------------------------------
    def theta(self) -> np.ndarray:
        return np.array([self.values[e][component_index(e, c)] for e, c in self.active])

    def set_theta(self, theta) -> None:
        for (e, c), x in zip(self.active, theta):
            self.values[e][component_index(e, c)] = x

    def with_theta(self, theta) -> "SensorModel":
        m = self.copy()
        m.set_theta(theta)
        return m

    def shift_temperature_ref(self, new_ref: float) -> "SensorModel":
        """The same physical model written about another reference temperature."""
        m = self.copy()
        d = float(new_ref) - self.temperature_ref
        tg = self.values["temperature_gain"]
        m.values["gain"] = self.values["gain"] * (1.0 + tg * d)
        m.values["temperature_gain"] = tg / (1.0 + tg * d)
        m.values["offset"] = self.values["offset"] + self.values["temperature_offset"] * d
        m.temperature_ref = float(new_ref)
        return m


def _coupling(values) -> np.ndarray:
    s = np.eye(3)
    for p, (a, b) in PAIR_INDEX.items():
        s[a, b] = s[b, a] = values["misalignment"][PAIRS.index(p)]
    return s


def _temperature_term(model: SensorModel, data: WindowData) -> np.ndarray:
    """T_eff - T_ref per window (0 where temperature is unknown)."""
    t = np.nan_to_num(data.temperature - model.temperature_ref)
    lag = model.values["thermal_lag"][0]
    if lag:
        t = t + lag * np.nan_to_num(data.dtdt)
    return t


def forward(model: SensorModel, u: np.ndarray, data: WindowData) -> np.ndarray:
    """What the sensor reads (n, 3) for true acceleration u (n, 3) under the model."""
    v = model.values
    dt = _temperature_term(model, data)[:, None]
    g = v["gain"] * (1.0 + v["temperature_gain"] * dt)
    return (g * u) @ _coupling(v).T + v["offset"] + v["temperature_offset"] * dt \
        + v["offset_drift"] * data.t_days[:, None]


def invert(model: SensorModel, data: WindowData, mean: Optional[np.ndarray] = None) -> np.ndarray:
    """Corrected acceleration (n, 3): the model solved for u given what was read."""
    v = model.values
    m = data.mean if mean is None else mean
    dt = _temperature_term(model, data)[:, None]
    b = v["offset"] + v["temperature_offset"] * dt + v["offset_drift"] * data.t_days[:, None]
    w = (m - b) @ np.linalg.inv(_coupling(v)).T
    return w / (v["gain"] * (1.0 + v["temperature_gain"] * dt))


def norm_residual(model: SensorModel, data: WindowData) -> np.ndarray:
    """r = ||corrected|| - 1 per window (g)."""
    return np.linalg.norm(invert(model, data), axis=1) - 1.0


def soft_l1(r: np.ndarray, scale: float = LOSS_SCALE_G) -> np.ndarray:
    """Per-window loss, in g^2: r^2 for small r, growing like 2 * scale * |r| for large r."""
    z = (r / scale) ** 2
    return 2.0 * scale ** 2 * (np.sqrt(1.0 + z) - 1.0)


@dataclass
class FitResult:
    model: SensorModel
    residual: np.ndarray  # (n,) g at the solution
    loss: float  # sum of soft-L1 loss (g^2)
    n: int
    n_eff: float
    k: int  # free parameters
    stderr: Dict[Tuple[str, str], float]  # standard error per free component (internal units)
    success: bool
    message: str

    @property
    def gap_mg(self) -> float:
        return float(np.mean(np.abs(self.residual)) * 1000.0)

    def bic(self, n_eff: Optional[float] = None) -> float:
        """BIC with n counted as independent windows: n_eff * ln(loss / n) + k * ln(n_eff)."""
        ne = self.n_eff if n_eff is None else n_eff
        return ne * np.log(max(self.loss, 1e-300) / self.n) + self.k * np.log(ne)


def effective_n(residual: np.ndarray, t_days: np.ndarray, max_gap_s: float = 60.0) -> float:
    """Number of independent windows: n (1 - rho) / (1 + rho), rho the lag-1 autocorrelation of the
    residual between windows that follow each other within ``max_gap_s`` (same still bout)."""
    n = residual.shape[0]
    if n < 3:
        return float(max(n, 1))
    order = np.argsort(t_days, kind="stable")
    r = residual[order] - np.mean(residual)
    adj = np.diff(t_days[order]) * 86400.0 <= max_gap_s
    if adj.sum() < 10 or np.dot(r, r) == 0:
        return float(n)
    a, b = r[:-1][adj], r[1:][adj]
    rho = float(np.dot(a, b) / np.sqrt(np.dot(a, a) * np.dot(b, b)))
    rho = min(max(rho, 0.0), 0.99)
    return float(max(n * (1.0 - rho) / (1.0 + rho), min(n, 10)))


def fit(model: SensorModel, data: WindowData, loss_scale: float = LOSS_SCALE_G,
        max_nfev: int = 200) -> FitResult:
    """Fit the free components of ``model`` to the windows; returns a new model and diagnostics."""
    if len(data) < max(10, 2 * len(model.active)):
        raise ValueError(f"too few nonmovement windows to fit ({len(data)})")
    work = model.copy()

    def fun(theta):
        work.set_theta(theta)
        return norm_residual(work, data)

    x0 = model.theta()
    res = least_squares(fun, x0, loss="soft_l1", f_scale=loss_scale, x_scale="jac",
                        method="trf", max_nfev=max_nfev, xtol=1e-12, ftol=1e-12, gtol=1e-12)
    out = model.with_theta(res.x)
    r = norm_residual(out, data)
    n = r.shape[0]
    n_eff = effective_n(r, data.t_days)
    stderr = {}
    try:
        jtj = res.jac.T @ res.jac
        dof = max(n - len(x0), 1)
        s2 = float(np.sum(soft_l1(r, loss_scale))) / dof
        cov = np.linalg.pinv(jtj) * s2 * (n / n_eff)
        for i, key in enumerate(out.active):
            stderr[key] = float(np.sqrt(max(cov[i, i], 0.0)))
    except (np.linalg.LinAlgError, ValueError):
        pass
    return FitResult(out, r, float(np.sum(soft_l1(r, loss_scale))), n, n_eff, len(x0), stderr,
                     bool(res.success), str(res.message))
