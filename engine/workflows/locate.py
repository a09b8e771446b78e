"""Where the model and the measurement disagree: the norm residual of nonmovement windows against
each covariate (temperature, orientation per axis and axis pair, time since start, dT/dt, signal
magnitude), and distribution checks for effects that do not show in window means (SD of still
windows against the model's noise, the spread of the measured norm against the model's).

For each covariate: the residual's mean in 10 quantile bins (with its standard error), the share of
residual variance those bin means explain (correlation ratio eta^2), and the linear correlation.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from .sensor_fit import SensorModel, WindowData, invert


def binned(x: np.ndarray, y: np.ndarray, bins: int = 10) -> dict:
    """Mean of y in quantile bins of x: {x_mid, y_mean, y_se, n, eta2}."""
    ok = np.isfinite(x) & np.isfinite(y)
    x, y = x[ok], y[ok]
    if x.size < 2 * bins or np.ptp(x) == 0:
        return {"x_mid": [], "y_mean": [], "y_se": [], "n": [], "eta2": 0.0}
    edges = np.unique(np.quantile(x, np.linspace(0, 1, bins + 1)))
    b = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, len(edges) - 2)
    nb = len(edges) - 1
    cnt = np.bincount(b, minlength=nb).astype(float)
    sx = np.bincount(b, x, nb)
    sy = np.bincount(b, y, nb)
    syy = np.bincount(b, y * y, nb)
    good = cnt > 1
    mean = np.where(good, sy / np.maximum(cnt, 1), np.nan)
    var = np.where(good, (syy - cnt * mean ** 2) / np.maximum(cnt - 1, 1), np.nan)
    se = np.sqrt(np.maximum(var, 0) / np.maximum(cnt, 1))
    tot = float(np.var(y)) * y.size
    between = float(np.nansum(cnt * (mean - y.mean()) ** 2))
    return {"x_mid": [round(float(v), 6) for v in (sx / np.maximum(cnt, 1))[good]],
            "y_mean": [round(float(v), 4) for v in mean[good]],
            "y_se": [round(float(v), 4) for v in se[good]],
            "n": [int(v) for v in cnt[good]],
            "eta2": round(between / tot, 5) if tot > 0 else 0.0}


def covariates(model: SensorModel, data: WindowData) -> dict:
    """name -> per-window covariate."""
    a = invert(model, data)
    u = a / np.linalg.norm(a, axis=1, keepdims=True)
    out = {"temperature (degC)": data.temperature,
           "u_x": u[:, 0], "u_y": u[:, 1], "u_z": u[:, 2],
           "u_x*u_y": u[:, 0] * u[:, 1], "u_x*u_z": u[:, 0] * u[:, 2], "u_y*u_z": u[:, 1] * u[:, 2],
           "time since start (days)": data.t_days,
           "dT/dt (degC/min)": data.dtdt * 60.0,
           "signal magnitude ||mean|| (g)": np.linalg.norm(data.mean, axis=1)}
    for k, ax in enumerate("xyz"):
        out[f"u_{ax} * temperature"] = u[:, k] * (data.temperature - model.temperature_ref)
        out[f"u_{ax} * time"] = u[:, k] * data.t_days
    return out


def locate(model: SensorModel, data: WindowData, residual: np.ndarray) -> list:
    """Covariates ranked by how much of the residual's variance their bins explain."""
    y = residual * 1000.0
    rows = []
    for name, x in covariates(model, data).items():
        if not np.all(np.isfinite(x)) or np.ptp(x) == 0:
            continue
        b = binned(x, y)
        c = np.corrcoef(x, y)[0, 1] if np.std(x) > 0 and np.std(y) > 0 else 0.0
        rows.append({"covariate": name, "eta2": b["eta2"], "corr": round(float(c), 4),
                     "bins": b})
    rows.sort(key=lambda r: -r["eta2"])
    return rows


def quantisation_bias_bound_mg(step_mg, noise_mg):
    """Largest bias (mg) that rounding to ``step_mg`` leaves in the mean of many samples of a
    constant value under Gaussian noise of SD ``noise_mg``: the first harmonic of the sawtooth's
    Fourier series, (step / pi) exp(-2 pi^2 (noise / step)^2) (higher harmonics are damped far
    more). ~0 when the noise dithers the step (noise >~ step / 2)."""
    step = np.asarray(step_mg, np.float64)
    sig = np.asarray(noise_mg, np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = np.where(step > 0, step / np.pi * np.exp(-2.0 * np.pi ** 2 * (sig / np.where(step > 0, step, 1.0)) ** 2), 0.0)
    return out


def distributions(base: SensorModel, final: SensorModel, data: WindowData,
                  noise_model_mg=None, rate_hz: Optional[float] = None, step_mg=None) -> dict:
    """Distribution checks: SD of still windows per axis vs the model's noise; the measured norm
    against the model's prediction (1 g exactly for a perfect deterministic model); with the
    quantisation step of the stored values (``step_mg``) and the model's noise, the largest bias
    that the step can leave in a still window's mean."""
    out = {}
    if data.sd is not None and len(data):
        sd = data.sd * 1000.0
        per_axis = {}
        for k, ax in enumerate("xyz"):
            q = np.percentile(sd[:, k], [5, 25, 50, 75, 95])
            q = [float(v) for v in q]
            entry = {"p5": round(q[0], 3), "p25": round(q[1], 3), "median": round(q[2], 3),
                     "p75": round(q[3], 3), "p95": round(q[4], 3),
                     "zero_fraction": round(float(np.mean(sd[:, k] == 0)), 5)}
            quantised = entry["zero_fraction"] > 0.05
            entry["quantisation_dominates"] = bool(quantised)
            if rate_hz and not quantised:
                # white-noise density that would give this floor: SD / sqrt(bandwidth = rate / 2)
                entry["noise_density_ug_per_rthz"] = round(q[0] * 1000.0 / np.sqrt(rate_hz / 2.0), 1)
            if noise_model_mg is not None:
                nm = float(np.broadcast_to(np.asarray(noise_model_mg, float), (3,))[k])
                entry["model_noise_mg"] = round(nm, 3)
                entry["ratio_p5_to_model"] = round(q[0] / nm, 3) if nm > 0 else None
                entry["agrees"] = bool(nm > 0 and 0.8 <= q[0] / nm <= 1.25) and not quantised
                entry["verdict"] = ("quantisation dominates" if quantised else "agrees" if entry["agrees"]
                                    else "below the model noise (quantisation, or less noise "
                                         "than modelled)" if q[0] < 0.8 * nm
                                    else "above the model noise (more noise than modelled)")
            if step_mg is not None:
                st = float(np.broadcast_to(np.asarray(step_mg, float), (3,))[k])
                entry["quantisation_step_mg"] = round(st, 4)
                if noise_model_mg is not None:
                    entry["quantisation_bias_max_mg"] = round(float(quantisation_bias_bound_mg(st, nm)), 4)
            per_axis[ax] = entry
        out["still_window_sd_mg"] = per_axis
        out["still_window_sd_note"] = (
            "the noise floor is the low end (p5) of the still-window SD; higher SDs contain "
            "micro-movements. A model noise outside 0.8-1.25x of p5 disagrees with the data. When "
            "more than 5% of still windows have SD exactly 0 on an axis the noise is below one "
            "quantisation step there: the SD then shows the resolution, not the noise.")
    for name, m in (("before", base), ("after", final)):
        a = invert(m, data)
        r = (np.linalg.norm(a, axis=1) - 1.0) * 1000.0
        out[f"norm_residual_mg_{name}"] = {
            "mean": round(float(np.mean(r)), 4), "sd": round(float(np.std(r)), 4),
            "p5": round(float(np.percentile(r, 5)), 4), "p95": round(float(np.percentile(r, 95)), 4)}
    return out
