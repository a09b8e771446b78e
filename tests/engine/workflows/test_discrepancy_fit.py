"""The discrepancy workflow's building blocks: the sensor model mirrors the simulator's, inverts
exactly, its Jacobian is right, the fit recovers parameters, the JSON round-trips, and the inputs
(feature table, still selection, dT/dt) behave."""

import json

import numpy as np
import pytest

from stillpoint.engine.core.errors import RecordingError
from stillpoint.engine.features import WindowFeatures
from stillpoint.engine.sim import model as sim
from stillpoint.engine.workflows.inputs import prepare, read_feature_table, temperature_rate
from stillpoint.engine.workflows.sensor_fit import (EFFECT_COMPONENTS, SensorModel, WindowData,
                                                    effective_n, fit, forward, invert,
                                                    norm_residual, residual_and_jacobian)
from stillpoint.engine.workflows.simmodel import from_sim, to_sim

FULL = sim.SensorModel({
    "misalignment": {"x_from_y_pct": 0.8, "y_from_x_pct": 0.8, "x_from_z_pct": -0.5,
                     "z_from_x_pct": -0.5, "y_from_z_pct": 0.3, "z_from_y_pct": 0.3},
    "gain": {"x_pct": 0.7, "y_pct": -1.1, "z_pct": 0.4},
    "temperature_gain": {"x_pct_per_c": 0.01, "y_pct_per_c": -0.02, "z_pct_per_c": 0.04,
                         "reference_c": 25.0},
    "offset": {"x_mg": 12.0, "y_mg": -30.0, "z_mg": 55.0},
    "temperature_offset": {"x_mg_per_c": 0.3, "y_mg_per_c": -0.4, "z_mg_per_c": 1.8,
                           "reference_c": 25.0},
    "nonlinearity": {"x_mg_per_g2": 3.0, "y_mg_per_g2": -2.0, "z_mg_per_g2": 4.0},
    "offset_drift": {"x_mg_per_day": 0.5, "y_mg_per_day": -0.8, "z_mg_per_day": 0.2},
    "thermal_lag": {"tau_s": 600.0},
})


def _series(n=3000, seed=0):
    rng = np.random.default_rng(seed)
    u = rng.normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    t_s = np.arange(n) * 60.0  # one window a minute over ~2 days
    temp = 28 + 4 * np.sin(t_s / 20000.0) + 2 * (np.sin(t_s / 3000.0) > 0.7)
    return u, t_s, temp


def _data(mean, t_s, temp):
    return WindowData(mean, temp, np.gradient(temp, t_s), t_s / 86400.0)


def test_forward_equals_the_simulators_deterministic_sensor_function():
    u, t_s, temp = _series()
    read = sim.apply_deterministic(u, FULL, temperature_c=temp, time_s=t_s)
    mine = from_sim(FULL)
    # symmetric misalignment is exactly representable, so the two must agree to rounding
    got = forward(mine, u, _data(read, t_s, temp))
    assert np.max(np.abs(got - read)) < 1e-12


def test_invert_recovers_unit_gravity_and_reference_shift_is_the_same_model():
    u, t_s, temp = _series()
    read = sim.apply_deterministic(u, FULL, temperature_c=temp, time_s=t_s)
    data = _data(read, t_s, temp)
    m = from_sim(FULL)
    assert np.max(np.abs(invert(m, data) - u)) < 1e-12
    shifted = m.shift_temperature_ref(31.7)
    assert np.max(np.abs(norm_residual(shifted, data))) < 1e-12


def test_analytic_jacobian_matches_finite_differences():
    u, t_s, temp = _series(800, seed=3)
    m = from_sim(FULL)
    data = _data(sim.apply_deterministic(u * 1.003, FULL, temperature_c=temp, time_s=t_s), t_s, temp)
    r, J = residual_and_jacobian(m, data)
    th = m.theta()
    for i, (e, c) in enumerate(m.active):
        h = (1e-3 if e == "thermal_lag" else 1e-6) * max(1.0, abs(th[i]))
        step = np.zeros_like(th)
        step[i] = h
        num = (norm_residual(m.with_theta(th + step), data)
               - norm_residual(m.with_theta(th - step), data)) / (2 * h)
        scale = np.max(np.abs(num)) + 1e-12
        assert np.max(np.abs(num - J[:, i])) / scale < 1e-3, (e, c)


def test_fit_recovers_every_parameter_from_noisy_windows():
    u, t_s, temp = _series(6000, seed=5)
    rng = np.random.default_rng(1)
    read = sim.apply_deterministic(u, FULL, temperature_c=temp, time_s=t_s)
    read = read + rng.normal(scale=0.0005, size=read.shape)
    data = _data(read, t_s, temp)
    truth = from_sim(FULL)
    start = SensorModel(active=list(truth.active), temperature_ref=25.0)
    res = fit(start, data)
    assert res.success
    got, want = res.model.values, truth.values
    assert np.allclose(got["offset"], want["offset"], atol=3e-4)  # 0.3 mg
    assert np.allclose(got["gain"], want["gain"], atol=3e-4)
    assert np.allclose(got["temperature_offset"], want["temperature_offset"], atol=5e-5)
    assert np.allclose(got["misalignment"], want["misalignment"], atol=3e-4)
    assert abs(got["thermal_lag"][0] - 600.0) < 60.0
    # standard errors exist and are honest-ish: the truth lies within 5 SE
    for (e, c), se in res.stderr.items():
        k = EFFECT_COMPONENTS[e].index(c)
        assert abs(got[e][k] - want[e][k]) < 5 * se + 1e-9, (e, c, got[e][k], want[e][k], se)


def test_effective_n_counts_correlated_windows_once():
    rng = np.random.default_rng(2)
    t = np.arange(5000) * 10 / 86400.0
    white = rng.normal(size=5000)
    # white noise: (nearly) every window counts; the estimator is deliberately conservative (the
    # largest batch-means estimate over several time scales), so allow a factor of 2.5
    assert effective_n(white, t) > 2000
    ar = np.repeat(rng.normal(size=250), 20)  # 20 identical windows per bout
    assert effective_n(ar + 0.05 * white, t) < 600
    # slow wander seen through a sign that flips with orientation: the residual decorrelates,
    # the score of a slow covariate does not
    from scipy.signal import lfilter
    slow = lfilter([1.0], [1.0, -0.999], rng.normal(size=5000) * 0.5 * np.sqrt(1 - 0.999 ** 2))
    sign = np.repeat(rng.choice([-1.0, 1.0], 500), 10)
    assert effective_n(slow * sign + white, t) > 500
    assert effective_n(slow + white, t) < 100


def test_sim_model_round_trip_and_written_json_is_accepted_by_the_simulator(tmp_path):
    m = from_sim(FULL)
    back = to_sim(m, {k: 0.001 for k in m.active}, carry=sim.SensorModel({"noise": {}, "clipping": {}}),
                  note="test")
    p = tmp_path / "model.json"
    p.write_text(json.dumps(back.to_dict()))
    loaded = sim.load_model(p)
    assert set(loaded.effects) == set(FULL.effects) | {"noise", "clipping"}
    assert loaded.effects["temperature_offset"]["uncertainty"]["z_mg_per_c"] == pytest.approx(1.0)
    sim.resolve_model(loaded, seed=0)  # complete and valid for simulation
    u, t_s, temp = _series(500)
    a = sim.apply_deterministic(u, FULL, temperature_c=temp, time_s=t_s)
    b = sim.apply_deterministic(u, loaded, temperature_c=temp, time_s=t_s)
    assert np.max(np.abs(a - b)) < 1e-6


def test_temperature_rate_is_the_slope_and_zero_across_gaps():
    t = np.arange(0, 7200, 10.0)
    temp = 20 + 0.002 * t
    d = temperature_rate(t, temp)
    assert np.allclose(d[30:-30], 0.002)
    t2 = np.concatenate([t, t[-1] + 3600 + t])  # a one-hour gap
    temp2 = np.concatenate([temp, 40 - 0.001 * t])
    d2 = temperature_rate(t2, temp2)
    i = t.size  # first window after the gap
    assert d2[i] == 0.0 and d2[i - 1] == 0.0
    assert np.allclose(d2[i + 30:-30], -0.001)


def test_prepare_selects_still_windows_and_drops_table_duplicates():
    k = 400
    rng = np.random.default_rng(0)
    mean = rng.normal(size=(k, 3)) * 0.5
    sd = np.full((k, 3), 0.005)
    sd[::4] = 0.2  # moving
    mean[102] = mean[101]
    mean[103] = mean[101]  # device on a table: identical means (window 100 is moving)
    mean[7] = [2.5, 0.0, 0.0]  # clipped
    f = WindowFeatures.from_arrays(mean, sd, 25 + np.arange(k) * 0.01)
    p = prepare(f)
    still = (np.arange(k) % 4 != 0)
    assert p.windows_still == still.sum() - 1  # minus the clipped window
    assert p.duplicates_dropped == 2
    assert len(p.data) == p.windows_still - 2
    assert p.dtdt_from_all_windows


def test_feature_table_reader_and_its_errors(tmp_path):
    good = tmp_path / "f.csv"
    good.write_text("window_index,meanx,meany,meanz,sdx,sdy,sdz,temperature\n"
                    "3,0.1,0.2,0.97,0.005,0.005,0.005,25.1\n7,0.0,1.0,0.0,0.004,0.004,0.006,25.3\n")
    f = read_feature_table(good)
    assert len(f) == 2 and f.start_ns[1] == 70 * 10**9
    assert f.temperature[1] == pytest.approx(25.3)
    bad = tmp_path / "bad.csv"
    bad.write_text("meanx,meany,sdx,sdy,sdz\n1,2,3,4,5\n")
    with pytest.raises(RecordingError, match="lacks columns"):
        read_feature_table(bad)
    bad2 = tmp_path / "bad2.csv"
    bad2.write_text("meanx,meany,meanz,sdx,sdy,sdz\n0.1,0.2,zz,0.01,0.01,0.01\n")
    with pytest.raises(RecordingError, match="row 2"):
        read_feature_table(bad2)
