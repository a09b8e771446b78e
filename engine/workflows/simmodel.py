"""Conversion between the simulator's sensor model (engine.sim.model: JSON effects with units in the
keys) and the fit's internal parameter vector (sensor_fit.SensorModel: g, degC, s, days).

The written model is the simulator's format, accepted by it as-is: the fitted deterministic effects
with a 1-SD ``uncertainty`` and a ``note`` each, and every non-deterministic effect of the starting
model (noise, quantisation, clock, ...) carried along unchanged.
"""

from __future__ import annotations

from typing import Dict, Optional, Tuple

import numpy as np

from stillpoint.engine.sim import model as sim

from .sensor_fit import EFFECT_COMPONENTS, PAIR_INDEX, PAIRS, SensorModel, component_index

FITTED_EFFECTS = tuple(EFFECT_COMPONENTS)  # the simulator's deterministic terms we fit

# internal value -> JSON value (and back): (key template, factor, origin)
_KEYS = {
    "offset": ("{c}_mg", 1000.0, 0.0),
    "gain": ("{c}_pct", 100.0, 1.0),
    "temperature_offset": ("{c}_mg_per_c", 1000.0, 0.0),
    "temperature_gain": ("{c}_pct_per_c", 100.0, 0.0),
    "nonlinearity": ("{c}_mg_per_g2", 1000.0, 0.0),
    "offset_drift": ("{c}_mg_per_day", 1000.0, 0.0),
    "thermal_lag": ("tau_s", 1.0, 0.0),
}


def from_sim(m: sim.SensorModel, temperature_ref: Optional[float] = None) -> SensorModel:
    """Internal model with every component of the simulator's deterministic effects switched on."""
    eff = m.effects
    ref_o = float(eff.get("temperature_offset", {}).get("reference_c", sim.DEFAULT_REFERENCE_C))
    ref_g = float(eff.get("temperature_gain", {}).get("reference_c", ref_o))
    out = SensorModel(temperature_ref=ref_o)
    active = []
    for name, (tmpl, f, origin) in _KEYS.items():
        if name not in eff:
            continue
        comps = EFFECT_COMPONENTS[name]
        for i, c in enumerate(comps):
            key = tmpl.format(c=c)
            dflt = 600.0 if name == "thermal_lag" else 0.0
            out.values[name][i] = float(eff[name].get(key, dflt)) / f + origin
            active.append((name, c))
    if "misalignment" in eff:
        mm = m.misalignment_matrix()
        for p, (a, b) in PAIR_INDEX.items():
            out.values["misalignment"][PAIRS.index(p)] = 0.5 * (mm[a, b] + mm[b, a])
            active.append(("misalignment", p))
    if "temperature_gain" in eff and ref_g != ref_o:
        # g (1 + tg (T - ref_g)) = g (1 + tg (ref_o - ref_g)) (1 + tg' (T - ref_o))
        tg = out.values["temperature_gain"]
        out.values["gain"] = out.values["gain"] * (1.0 + tg * (ref_o - ref_g))
        out.values["temperature_gain"] = tg / (1.0 + tg * (ref_o - ref_g))
    order = {n: i for i, n in enumerate(sim.EFFECT_ORDER)}
    out.active = sorted(active, key=lambda k: (order.get(k[0], 99), EFFECT_COMPONENTS[k[0]].index(k[1])))
    if temperature_ref is not None:
        out = out.shift_temperature_ref(temperature_ref)
    return out


def to_sim(model: SensorModel, stderr: Optional[Dict[Tuple[str, str], float]] = None,
           carry: Optional[sim.SensorModel] = None, note: str = "") -> sim.SensorModel:
    """The simulator's model for the effects that are on in ``model`` (+ carried effects)."""
    stderr = stderr or {}
    effects: Dict[str, dict] = {}
    for name in model.effects_on():
        comps = [c for e, c in model.active if e == name]
        params, unc = {}, {}
        if name == "misalignment":
            for p in PAIRS:
                a, b = p
                v = 100.0 * model.values[name][PAIRS.index(p)]
                params[f"{a}_from_{b}_pct"] = params[f"{b}_from_{a}_pct"] = round(float(v), 6)
                if (name, p) in stderr:
                    unc[f"{a}_from_{b}_pct"] = unc[f"{b}_from_{a}_pct"] = \
                        round(100.0 * stderr[(name, p)], 6)
        else:
            tmpl, f, origin = _KEYS[name]
            for c in EFFECT_COMPONENTS[name]:
                key = tmpl.format(c=c)
                v = (model.values[name][component_index(name, c)] - origin) * f
                params[key] = round(float(v), 6)
                if (name, c) in stderr and np.isfinite(stderr[(name, c)]):
                    unc[key] = round(float(stderr[(name, c)] * f), 6)
        if name in ("temperature_offset", "temperature_gain"):
            params["reference_c"] = round(float(model.temperature_ref), 6)
        if unc:
            params["uncertainty"] = unc
        fixed = [c for c in EFFECT_COMPONENTS[name] if c not in comps]
        if note or fixed:
            params["note"] = (note + (f"; fixed (not fitted): {', '.join(fixed)}" if fixed else "")
                              + ("; symmetric part only (a common rotation is invisible to the norm)"
                                 if name == "misalignment" else "")).strip("; ")
        effects[name] = params
    if carry is not None:
        for name, p in carry.effects.items():
            if name not in FITTED_EFFECTS and name not in effects:
                effects[name] = dict(p)
    return sim.SensorModel(effects)


def noise_sd_mg(m: Optional[sim.SensorModel], rate_hz: float) -> Optional[np.ndarray]:
    """Per-axis SD (mg) of a single sample from the model's white noise at ``rate_hz``
    (density x sqrt(rate / 2)), or None when the model has no noise term."""
    if m is None or not m.on("noise"):
        return None
    dens = m.axis_vector("noise", "ug_per_rthz") / 1000.0  # mg/sqrt(Hz)
    return dens * np.sqrt(rate_hz / 2.0)
