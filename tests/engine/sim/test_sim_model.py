"""Sensor model: JSON format, --effect syntax, the deterministic pure function, GGIR equivalence."""

import json

import numpy as np
import pytest

from stillpoint.engine.sim.model import (EFFECT_ORDER, ModelError, SensorModel, apply_deterministic,
                                         first_order_lag, ggir_equivalent, load_model,
                                         parse_effect_option, resolve_model, save_model)


def test_json_round_trip_and_aliases(tmp_path):
    m = SensorModel({"offset": {"x_mg": 10, "y_mg": -5, "z_mg": 50},
                     "temperature": {"z_mg_per_c": 3.9, "uncertainty": {"z_mg_per_c": 0.1}},
                     "gain": {"x_pct": 1.0, "enabled": False}})
    assert list(m.effects) == ["offset", "temperature_offset"]  # order = EFFECT_ORDER, gain off
    p = tmp_path / "m.json"
    save_model(m, p)
    d = json.loads(p.read_text())
    assert d["format"] == "stillpoint.sensor_model" and d["version"] == 1
    m2 = load_model(p)
    assert m2.effects == m.effects
    # a truth JSON is accepted as a model file too
    (tmp_path / "t.json").write_text(json.dumps({"sensor_model": m.to_dict()}))
    assert load_model(tmp_path / "t.json").effects == m.effects


@pytest.mark.parametrize("bad, msg", [
    ({"effects": {"offst": {}}}, "unknown effect"),
    ({"effects": {"offset": {"x_g": 1}}}, "no parameter"),
    ({"format": "other", "effects": {}}, "format"),
    ({"nothing": 1}, "effects"),
    ({"effects": {"offset": {"x_mg": "ten"}}}, "finite number"),
    ({"effects": {"offset": 5}}, "object"),
    ({"effects": {"halts": {"events": 3}}}, "list"),
])
def test_bad_models_are_typed_errors(tmp_path, bad, msg):
    p = tmp_path / "bad.json"
    p.write_text(json.dumps(bad))
    with pytest.raises(ModelError, match=msg):
        load_model(p)


def test_effect_option_syntax_and_units():
    assert parse_effect_option("temperature:z=3.9mg/C") == ("temperature_offset", {"z_mg_per_c": 3.9})
    assert parse_effect_option("offset:x=0.1g,z=-20") == ("offset", {"x_mg": 100.0, "z_mg": -20.0})
    assert parse_effect_option("clock:skew=20ppm,offset=-3s") == ("clock", {"skew_ppm": 20.0,
                                                                            "offset_s": -3.0})
    assert parse_effect_option("halts:at=26h,duration=5min") == (
        "halts", {"events": [{"start_s": 93600.0, "duration_s": 300.0}]})
    assert parse_effect_option("thermal_lag:tau=10min") == ("thermal_lag", {"tau_s": 600.0})
    with pytest.raises(ModelError, match="unit"):
        parse_effect_option("offset:z=3s")
    with pytest.raises(ModelError, match="unknown parameter"):
        parse_effect_option("offset:w=3")


def test_deterministic_terms_in_documented_order():
    f = np.array([[0.0, 0.6, 0.8], [1.0, 0.0, 0.0]])
    T = np.array([30.0, 20.0])
    t = np.array([0.0, 86400.0 * 2])
    m = SensorModel({
        "misalignment": {"x_from_y_pct": 1.0},
        "gain": {"x_pct": 2.0, "y_pct": 0.0, "z_pct": -1.0},
        "offset": {"x_mg": 10.0, "y_mg": 0.0, "z_mg": -50.0},
        "temperature_offset": {"x_mg_per_c": 1.0, "y_mg_per_c": 0.0, "z_mg_per_c": 2.0,
                               "reference_c": 25.0},
        "nonlinearity": {"x_mg_per_g2": 5.0},
        "offset_drift": {"z_mg_per_day": 0.5},
    })
    a = apply_deterministic(f, m, temperature_c=T, time_s=t)
    # by hand, row 0: x = (0 + 0.01*0.6) * 1.02 + 0.010 + 0.001*5 ; then + 0.005*x^2
    x0 = 0.006 * 1.02 + 0.010 + 0.005
    x0 += 0.005 * x0 ** 2
    z0 = 0.8 * 0.99 - 0.050 + 0.002 * 5
    assert a[0, 0] == pytest.approx(x0, abs=1e-15)
    assert a[0, 2] == pytest.approx(z0, abs=1e-15)
    x1 = 1.0 * 1.02 + 0.010 - 0.005
    x1 += 0.005 * x1 ** 2
    assert a[1, 0] == pytest.approx(x1, abs=1e-15)
    assert a[1, 2] == pytest.approx(0.0 - 0.050 - 0.010 + 0.001, abs=1e-15)  # drift 2 days * 0.5 mg
    with pytest.raises(ValueError, match="temperature"):
        apply_deterministic(f, m)


def test_thermal_lag_matches_exponential_response():
    t = np.arange(0, 7200.0, 10.0)
    T = np.where(t < 600, 20.0, 30.0)  # a step: linear from 590 s to 600 s
    y = first_order_lag(T, t, 600.0)
    after = t >= 1200
    expect = 30.0 - 10.0 * np.exp(-(t[after] - 595.0) / 600.0)  # ramp 590-600 s, centred at 595 s
    assert np.max(np.abs(y[after] - expect)) < 0.01
    # irregular spacing and long gaps are fine; chunking does not change the answer
    ti = np.sort(np.random.default_rng(0).uniform(0, 1e5, 3000))
    Ti = 25 + 5 * np.sin(ti / 5000)
    full = first_order_lag(Ti, ti, 900.0)
    half = first_order_lag(Ti[1500:], ti[1500:], 900.0, initial=full[1500])
    assert np.allclose(full[1500:], half, atol=1e-9)
    # with the lag, temperature_offset follows the lagged temperature
    m = SensorModel({"temperature_offset": {"x_mg_per_c": 1, "y_mg_per_c": 0, "z_mg_per_c": 0},
                     "thermal_lag": {"tau_s": 900.0}})
    a = apply_deterministic(np.zeros((ti.size, 3)), m, temperature_c=Ti, time_s=ti)
    assert np.allclose(a[:, 0], (full - 25.0) * 1e-3)


def test_ggir_equivalent_undoes_the_model():
    rng = np.random.default_rng(3)
    f = rng.normal(size=(500, 3))
    f /= np.linalg.norm(f, axis=1, keepdims=True)
    T = rng.uniform(20, 35, 500)
    m = resolve_model(SensorModel({"offset": {}, "gain": {}, "temperature_offset": {}}), seed=5)
    raw = apply_deterministic(f, m, temperature_c=T)
    g = ggir_equivalent(m, temperature_ref=float(T.mean()))
    cal = (raw + g["offset"]) * g["scale"] + (T - g["temperature_ref"])[:, None] * g["tempoffset"]
    assert np.max(np.abs(cal - f)) < 1e-12
    with pytest.raises(ModelError):
        ggir_equivalent(m.with_effect("nonlinearity", x_mg_per_g2=1.0), 25.0)


def test_resolve_fills_typical_values_reproducibly():
    base = SensorModel({n: {} for n in EFFECT_ORDER}).with_effect("offset", z_mg=80.0)
    a = resolve_model(base, seed=7)
    b = resolve_model(base, seed=7)
    assert a.effects == b.effects
    assert a.effects["offset"]["z_mg"] == 80.0  # explicit value kept
    assert all(abs(a.effects["offset"][k]) <= 100 for k in ("x_mg", "y_mg"))
    assert abs(a.effects["clock"]["skew_ppm"]) <= 50
    assert a.effects["clock"]["curvature_ppm_per_c2"] == -0.035
    # one effect's draws do not depend on which other effects are on
    c = resolve_model(SensorModel({"gain": None}), seed=7)
    assert c.effects["gain"] == a.effects["gain"]
    assert resolve_model(SensorModel({"gain": {}}), seed=8).effects["gain"] != c.effects["gain"]


def _broadcast_deterministic(f, model, Ta, t):
    """The deterministic steps in their (n, 3) broadcast form (the reference for the column form)."""
    dt = f.dtype
    a = f @ model.misalignment_matrix().T.astype(dt)
    a *= (1.0 + model.axis_vector("gain", "pct") / 100.0).astype(dt)
    a *= 1.0 + (Ta - 25.0).astype(dt)[:, None] * (model.axis_vector("temperature_gain", "pct_per_c") / 100.0).astype(dt)
    a += (model.axis_vector("offset", "mg") / 1000.0).astype(dt)
    a += (Ta - 25.0).astype(dt)[:, None] * (model.axis_vector("temperature_offset", "mg_per_c") / 1000.0).astype(dt)
    a += (model.axis_vector("nonlinearity", "mg_per_g2") / 1000.0).astype(dt) * (a * a)
    a += (t / 86400.0).astype(dt)[:, None] * (model.axis_vector("offset_drift", "mg_per_day") / 1000.0).astype(dt)
    return a


def test_deterministic_columns_equal_broadcast_form():
    from stillpoint.engine.sim.model import SensorModel, apply_deterministic

    rng = np.random.default_rng(3)
    eff = {"misalignment": {"x_from_y_pct": 1.0, "z_from_x_pct": -0.5},
           "gain": {"x_pct": 1.5, "y_pct": -1.0, "z_pct": 0.3},
           "temperature_gain": {"x_pct_per_c": 0.02, "z_pct_per_c": -0.01, "reference_c": 25.0},
           "offset": {"x_mg": 30.0, "y_mg": -20.0, "z_mg": 5.0},
           "temperature_offset": {"x_mg_per_c": 0.8, "y_mg_per_c": -0.4, "reference_c": 25.0},
           "nonlinearity": {"x_mg_per_g2": 2.0, "z_mg_per_g2": -1.0},
           "offset_drift": {"x_mg_per_day": 0.5, "y_mg_per_day": -0.3}}
    model = SensorModel(eff)
    assert set(model.effects) >= set(eff)
    for dtype in (np.float32, np.float64):
        f = rng.normal(0, 1, (4000, 3)).astype(dtype)
        T = rng.uniform(20, 35, 4000)
        t = np.sort(rng.uniform(0, 86400 * 3, 4000))
        got = apply_deterministic(f, model, temperature_c=T, time_s=t, accel_temperature_c=T)
        assert np.array_equal(got, _broadcast_deterministic(f, model, T, t))
