"""Fit a sensor model of named effects to the means of nonmovement windows (robust least squares).

The model is the deterministic part of the simulator's sensor model (engine.sim.model, steps 1-8,
same order, same effect names), for true acceleration u (g), temperature-sensor reading T (degC)
and time t since the start of the recording:

    T_a = first-order lag of T with time constant thermal_lag   (T itself when the lag is off)
    a = M u                          misalignment: M = I + S, S symmetric, S[a,b] = coupling(ab)
    a *= gain * (1 + temperature_gain * (T_a - T_ref))
    a += offset + temperature_offset * (T_a - T_ref)
    a += nonlinearity * a^2
    a += offset_drift * t_days

Only the symmetric part of the cross-axis terms changes the norm of gravity (a common rotation does
not), so misalignment is fitted as one coupling per axis pair. Every step inverts exactly, so for a
still window (u = 1 g in an unknown direction) the residual is r = ||a^-1(read)|| - 1 (g), the
calibration error of van Hees 2014. The fit minimises a soft-L1 (Huber-like) loss of r with a 10 mg
scale over the free parameters, so a few windows that were not quite still do not steer it.
Parameters of components not switched on stay fixed (normally at their neutral value).

Pure functions on plain arrays; no I/O. Units inside: g, degC, seconds, days.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Dict, List, Optional, Tuple

import numpy as np

from stillpoint.engine.sim.model import first_order_lag

AXES = ("x", "y", "z")
PAIRS = ("xy", "xz", "yz")
PAIR_INDEX = {"xy": (0, 1), "xz": (0, 2), "yz": (1, 2)}

EFFECT_COMPONENTS: Dict[str, Tuple[str, ...]] = {
    "offset": AXES,
    "gain": AXES,
    "temperature_offset": AXES,
    "temperature_gain": AXES,
    "misalignment": PAIRS,
    "nonlinearity": AXES,
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
    """Nonmovement windows as the fit sees them (plain arrays, one row per window).

    ``series_t_s``/``series_temp`` hold the temperature of every window of the recording (moving
    ones too, when the input has them) in time order and ``series_index`` the position of each row
    in it: the thermal lag is a filter over that whole series.
    """

    mean: np.ndarray  # (n, 3) g
    temperature: np.ndarray  # (n,) degC (NaN when unknown)
    dtdt: np.ndarray  # (n,) degC / s of the temperature sensor
    t_days: np.ndarray  # (n,) days since the start of the recording
    sd: Optional[np.ndarray] = None  # (n, 3) g, for the distribution checks
    series_t_s: Optional[np.ndarray] = None
    series_temp: Optional[np.ndarray] = None
    series_index: Optional[np.ndarray] = None
    _lag_cache: dict = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self):
        if self.series_t_s is None:
            self.series_t_s = self.t_days * 86400.0
            self.series_temp = np.nan_to_num(self.temperature, nan=25.0)
            self.series_index = np.arange(self.t_days.shape[0])

    def __len__(self):
        return int(self.mean.shape[0])

    def take(self, idx) -> "WindowData":
        d = WindowData(self.mean[idx], self.temperature[idx], self.dtdt[idx], self.t_days[idx],
                       None if self.sd is None else self.sd[idx], self.series_t_s, self.series_temp,
                       self.series_index[idx])
        d._lag_cache = self._lag_cache  # shared: keyed by tau over the whole series
        return d

    @property
    def has_temperature(self) -> bool:
        return bool(len(self)) and bool(np.all(np.isfinite(self.temperature))) \
            and float(np.std(self.temperature)) > 0.01

    def accel_temperature(self, tau_s: float) -> np.ndarray:
        """T_a at the rows: the temperature series through a first-order lag of ``tau_s``."""
        if tau_s <= 0:
            return self.temperature
        full = self._lag_cache.get(tau_s)
        if full is None:
            full = first_order_lag(self.series_temp, self.series_t_s, float(tau_s))
            if len(self._lag_cache) > 64:
                self._lag_cache.clear()
            self._lag_cache[tau_s] = full
        return full[self.series_index]


@dataclass
class SensorModel:
    """Parameter values of every effect (internal units) plus the free (switched-on) components."""

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

    def uses_temperature(self) -> bool:
        return bool(np.any(self.values["temperature_offset"]) or np.any(self.values["temperature_gain"]))

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


def coupling_matrix(values) -> np.ndarray:
    s = np.eye(3)
    for p, (a, b) in PAIR_INDEX.items():
        s[a, b] = s[b, a] = values["misalignment"][PAIRS.index(p)]
    return s


def _rowmat(a: np.ndarray, m: np.ndarray) -> np.ndarray:
    """a @ m.T for (n, 3) rows and a 3x3 matrix, without BLAS (whose threads stall on a busy
    2-core machine for such thin products)."""
    return a[:, 0:1] * m[:, 0] + a[:, 1:2] * m[:, 1] + a[:, 2:3] * m[:, 2]


def _dot(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sum(a * b))


def _dtemp(model: SensorModel, data: WindowData) -> np.ndarray:
    """(T_a - T_ref) per window, 0 where temperature is unknown or unused."""
    if not model.uses_temperature() and not model.has_temperature_terms():
        return np.zeros(len(data))
    ta = data.accel_temperature(float(model.values["thermal_lag"][0]))
    return np.nan_to_num(ta - model.temperature_ref)


def forward(model: SensorModel, u: np.ndarray, data: WindowData) -> np.ndarray:
    """What the sensor reads (n, 3) for true acceleration u (n, 3) under the model."""
    v = model.values
    dt = _dtemp(model, data)[:, None]
    a = _rowmat(u, coupling_matrix(v))
    a = a * (v["gain"] * (1.0 + v["temperature_gain"] * dt))
    a = a + v["offset"] + v["temperature_offset"] * dt
    a = a + v["nonlinearity"] * a * a
    return a + v["offset_drift"] * data.t_days[:, None]


def _invert_parts(model: SensorModel, data: WindowData):
    """Intermediate values of the inversion (for the residual and its analytic Jacobian)."""
    v = model.values
    y = data.mean
    if np.any(v["offset_drift"]):
        y = y - v["offset_drift"] * data.t_days[:, None]
    nl = v["nonlinearity"]
    if np.any(nl):
        # a + k a^2 = y  ->  a = 2 y / (1 + sqrt(1 + 4 k y))  (the root near y; stable for k -> 0)
        y = 2.0 * y / (1.0 + np.sqrt(np.maximum(1.0 + 4.0 * nl * y, 1e-12)))
    dt = _dtemp(model, data)[:, None]
    q = 1.0 + v["temperature_gain"] * dt
    G = v["gain"] * q
    a = (y - v["offset"] - v["temperature_offset"] * dt) / G
    minv = np.linalg.inv(coupling_matrix(v))
    u = _rowmat(a, minv) if np.any(v["misalignment"]) else a
    return y, dt, q, G, a, minv, u


def invert(model: SensorModel, data: WindowData, mean: Optional[np.ndarray] = None) -> np.ndarray:
    """Corrected acceleration (n, 3): the model solved for u given what was read."""
    if mean is not None:
        data = WindowData(mean, data.temperature, data.dtdt, data.t_days, None, data.series_t_s,
                          data.series_temp, data.series_index)
    return _invert_parts(model, data)[-1]


def residual_and_jacobian(model: SensorModel, data: WindowData, want_jac: bool = True):
    """r = ||u|| - 1 and dr/dtheta (n, k) for the free components (analytic; thermal lag by a
    finite difference, as it acts through a filter)."""
    y, dt, q, G, a, minv, u = _invert_parts(model, data)
    nu = np.sqrt(np.sum(u * u, axis=1))
    r = nu - 1.0
    if not want_jac:
        return r, None
    v = model.values
    nhat = u / nu[:, None]
    p = _rowmat(nhat, minv.T)  # dr/da
    pg = p / G
    J = np.empty((r.shape[0], len(model.active)))
    dt1 = dt[:, 0]
    for i, (e, c) in enumerate(model.active):
        if e == "misalignment":
            ia, ib = PAIR_INDEX[c]
            J[:, i] = -(p[:, ia] * u[:, ib] + p[:, ib] * u[:, ia])
            continue
        if e == "thermal_lag":
            h = 1e-3 * max(1.0, abs(v["thermal_lag"][0]))
            m2 = model.copy()
            m2.values["thermal_lag"][0] += h
            r2 = np.sqrt(np.sum(_invert_parts(m2, data)[-1] ** 2, axis=1)) - 1.0
            J[:, i] = (r2 - r) / h
            continue
        k = AXES.index(c)
        if e == "offset":
            J[:, i] = -pg[:, k]
        elif e == "temperature_offset":
            J[:, i] = -pg[:, k] * dt1
        elif e == "gain":
            J[:, i] = -p[:, k] * a[:, k] / v["gain"][k]
        elif e == "temperature_gain":
            J[:, i] = -p[:, k] * a[:, k] * dt1 / q[:, k]
        elif e == "nonlinearity":
            nl = v["nonlinearity"][k]
            J[:, i] = -pg[:, k] * y[:, k] ** 2 / (1.0 + 2.0 * nl * y[:, k])
        elif e == "offset_drift":
            nl = v["nonlinearity"][k]
            J[:, i] = -pg[:, k] * data.t_days / (1.0 + 2.0 * nl * y[:, k])
        else:  # pragma: no cover
            raise KeyError(e)
    return r, J


def norm_residual(model: SensorModel, data: WindowData) -> np.ndarray:
    """r = ||corrected|| - 1 per window (g)."""
    u = invert(model, data)
    return np.sqrt(np.sum(u * u, axis=1)) - 1.0


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
    tau_score: Dict[Tuple[str, str], float] = field(default_factory=dict)  # per free component

    def n_independent(self, key: Tuple[str, str]) -> float:
        """Independent windows as far as component ``key`` is concerned: n / tau of its score."""
        return self.n / max(self.tau_score.get(key, self.n / self.n_eff), 1.0)

    @property
    def gap_mg(self) -> float:
        return float(np.mean(np.abs(self.residual)) * 1000.0)


BATCH_SCALES_S = (1800.0, 3600.0, 7200.0, 14400.0, 28800.0, 43200.0)


def effective_n(residual: np.ndarray, t_days: np.ndarray, scales_s=BATCH_SCALES_S,
                min_batches: int = 6, max_gap_s: float = 60.0) -> float:
    """Number of independent windows, n / tau_int, with tau_int the integrated autocorrelation time
    of the residual in windows. Still windows come in bouts and the sensor's bias wanders slowly,
    so neighbouring windows are not independent evidence.

    tau_int is estimated by batch means (Var(batch mean) = sigma^2 tau_int / count) at time scales
    of 0.5-12 h, each with two phases of batch boundaries averaged, and by the lag-1 correlation
    within still bouts, (1 + rho) / (1 - rho). Short batches underestimate a slow correlation, so
    the largest estimate over the scales with at least ``min_batches`` batches is used: a
    deliberately conservative count (it guards the null control against slow bias wander)."""
    return effective_n_many([residual], t_days, scales_s, min_batches, max_gap_s)[0]


def effective_n_many(columns, t_days: np.ndarray, scales_s=BATCH_SCALES_S,
                     min_batches: int = 6, max_gap_s: float = 60.0) -> list:
    """:func:`effective_n` of several series on the same windows (the residual and each
    parameter's score): the time order, the adjacency and the batch numbers and counts at every
    scale and phase are computed once; each series costs its own sums only (the same operations
    as one :func:`effective_n` call, so the same numbers)."""
    columns = [np.asarray(c, np.float64) for c in columns]
    n = columns[0].shape[0] if columns else 0
    if n < 3:
        return [float(max(n, 1))] * len(columns)
    dtt = np.diff(t_days)
    if np.any(dtt < 0):
        order = np.argsort(t_days, kind="stable")
        columns = [c[order] for c in columns]
        t_days = t_days[order]
        dtt = np.diff(t_days)
    adj = dtt * 86400.0 <= max_gap_s
    use_lag = adj.sum() >= 10
    ts = (t_days - t_days[0]) * 86400.0
    batches = []  # per scale: [(k, cnt, used, nb) per phase] until too few batches
    for scale in scales_s:
        phases = []
        for phase in (0.0, 0.5):
            k = np.floor(ts / scale + phase).astype(np.int64)
            cnt = np.bincount(k).astype(float)
            used = cnt > 0
            nb = int(used.sum())
            if nb < min_batches:
                break
            phases.append((k, cnt, used, nb))
        batches.append(phases)
    out = []
    for residual in columns:
        r = residual - np.mean(residual)
        var = _dot(r, r) / n
        if var == 0:
            out.append(float(n))
            continue
        tau = 1.0
        if use_lag:
            a, b = r[:-1][adj], r[1:][adj]
            den = np.sqrt(_dot(a, a) * _dot(b, b))
            rho = min(max(_dot(a, b) / den if den > 0 else 0.0, 0.0), 0.99)
            tau = max(tau, (1.0 + rho) / (1.0 - rho))
        for phases in batches:
            est = []
            for k, cnt, used, nb in phases:
                sm = np.bincount(k, r)
                m = sm[used] / cnt[used]
                est.append(float(np.sum(cnt[used] * m * m)) / ((nb - 1) * var))
            if len(est) == 2:
                tau = max(tau, 0.5 * (est[0] + est[1]))
        out.append(float(min(max(n / tau, min(n, 10)), n)))
    return out


def _bounds(model: SensorModel):
    lo = np.full(len(model.active), -np.inf)
    hi = np.full(len(model.active), np.inf)
    for i, (e, _) in enumerate(model.active):
        if e == "thermal_lag":
            lo[i], hi[i] = 0.0, 6 * 3600.0  # the accelerometer lags the sensor (simulator's model)
        elif e == "gain":
            lo[i], hi[i] = 0.5, 1.5
    return lo, hi


def levenberg_marquardt(fun, jac, x0, lo, hi, loss_scale, max_iter=60, tol=1e-10):
    """Robust (soft-L1, by iteratively reweighted normal equations) Levenberg-Marquardt with
    projection onto box bounds. ``fun(x) -> r``, ``jac(x) -> (r, J)``.
    Returns (x, r, J, weights, iterations, converged)."""
    x = np.clip(np.asarray(x0, np.float64), lo, hi)
    r, J = jac(x)
    cost = float(np.sum(soft_l1(r, loss_scale)))
    lam = 1e-4
    converged = False
    it = 0
    for it in range(1, max_iter + 1):  # noqa: B007 - returned as the iteration count
        w = 1.0 / np.sqrt(1.0 + (r / loss_scale) ** 2)
        A = np.einsum("ij,ik->jk", J, w[:, None] * J)
        g = np.einsum("ij,i->j", J, w * r)
        d = np.diag(A).copy()
        d[d <= 0] = 1e-30
        accepted = False
        while lam < 1e10:
            try:
                delta = np.linalg.solve(A + lam * np.diag(d), -g)
            except np.linalg.LinAlgError:
                lam *= 10
                continue
            xn = np.clip(x + delta, lo, hi)
            rn = fun(xn)
            cn = float(np.sum(soft_l1(rn, loss_scale)))
            if cn <= cost:
                accepted = True
                break
            lam *= 10
        if not accepted:
            converged = True  # no descent left at machine precision
            break
        # predicted change of each parameter relative to its 1-sigma scale from the normal matrix
        sig = 1.0 / np.sqrt(d)
        small = np.all(np.abs(xn - x) <= 1e-6 * sig)
        rel = (cost - cn) <= tol * max(cost, 1e-300)
        x, cost = xn, cn
        lam = max(lam / 10, 1e-9)
        r, J = jac(x)
        if small or rel:
            converged = True
            break
    w = 1.0 / np.sqrt(1.0 + (r / loss_scale) ** 2)
    return x, r, J, w, it, converged


def fit(model: SensorModel, data: WindowData, loss_scale: float = LOSS_SCALE_G,
        max_iter: int = 60) -> FitResult:
    """Fit the free components of ``model`` to the windows; returns a new model and diagnostics."""
    if len(data) < max(10, 2 * len(model.active)):
        raise ValueError(f"too few nonmovement windows to fit ({len(data)})")
    work = model.copy()

    def fun(theta):
        work.set_theta(theta)
        return norm_residual(work, data)

    def jac(theta):
        work.set_theta(theta)
        return residual_and_jacobian(work, data)

    lo, hi = _bounds(model)
    x0 = model.theta()
    for i, (e, _) in enumerate(model.active):
        if e == "thermal_lag" and x0[i] == 0.0:
            x0[i] = 300.0  # tau acts through a filter: start inside the range, not on the bound
    x, r, J, w, iters, ok = levenberg_marquardt(fun, jac, x0, lo, hi, loss_scale, max_iter)
    out = model.with_theta(x)
    n = r.shape[0]
    # per parameter: the integrated autocorrelation of its score contributions J_p w r (a
    # slowly wandering bias projected on a changing orientation decorrelates the residual but
    # not its product with a slow covariate such as temperature)
    effs = effective_n_many([r] + [J[:, i] * w * r for i in range(len(out.active))], data.t_days)
    n_eff = effs[0]
    tau_p = {key: n / e for key, e in zip(out.active, effs[1:])}
    stderr = {}
    try:
        A = np.einsum("ij,ik->jk", J, w[:, None] * J)
        dof = max(n - len(x), 1)
        s2 = float(np.sum(w * r * r)) / dof
        cov = np.linalg.pinv(A) * s2
        for i, key in enumerate(out.active):
            stderr[key] = float(np.sqrt(max(cov[i, i], 0.0) * tau_p[key]))
    except (np.linalg.LinAlgError, ValueError):
        pass
    return FitResult(out, r, float(np.sum(soft_l1(r, loss_scale))), n, n_eff, len(x), stderr,
                     ok, f"{iters} iterations", tau_p)
