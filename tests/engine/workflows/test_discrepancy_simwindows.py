"""The hidden-effect validation data (engine.workflows.simwindows) are the simulator's: the window
features built from its wearer, temperature and sensor model without a file agree with those the
engine reads back from the simulator's own .cwa of the same seed (same windows, same still windows,
means equal up to the white noise of the two independent draws, same SD and temperature); and the
exact-moment shortcut gives the same window statistics as drawing the samples."""

import numpy as np
import pytest

from stillpoint.engine.sim.record import simulate_recording
from stillpoint.engine.sim.sensor import DeviceSpec
from stillpoint.engine.workflows import scenarios
from stillpoint.engine.workflows.simwindows import simulate_windows, window_statistics
from stillpoint.engine.workflows.sources import stream_features

DAYS = 0.25


@pytest.mark.parametrize("packed,method", [(False, "samples"), (True, "moments")])
def test_windows_match_the_simulators_own_recording(tmp_path, packed, method):
    truth, _ = scenarios.models("thermal_lag", 3)  # lag + temperature offset, bias wander, noise
    sw = simulate_windows(truth, days=DAYS, seed=3, packed=packed, method=method)
    path = tmp_path / "sim.cwa"
    simulate_recording(path, days=DAYS, seed=3, effects=truth, range_g=8, packed=packed,
                       truth_path=False)
    f = stream_features(path).features
    assert len(f) == len(sw.features)
    assert np.array_equal(f.start_ns - f.start_ns[0], sw.features.start_ns)
    s = sw.still
    assert s.sum() > 100
    # the truly still windows pass the still criterion on the file (but for a few whose worn
    # micro-motion is strong) and the window-level SDs see the same micro-motion
    passed = np.all(f.sd[s] < 0.013, axis=1)
    assert passed.mean() > 0.75
    assert np.mean(passed == np.all(sw.features.sd[s] < 0.013, axis=1)) > 0.95
    d = (f.mean[s] - sw.features.mean[s]) * 1000.0  # mg
    # the same deterministic reading, bias, micro-motion mean and quantisation: only two
    # independent noise draws differ (per-window SD sqrt(2) * noise / sqrt(1000) ~ 0.13-0.18 mg
    # unpacked; packed adds the rounding error the micro-motion leaves in each window mean)
    se = d.std(axis=0) / np.sqrt(d.shape[0])
    assert np.all(np.abs(d.mean(axis=0)) < 5 * se + 0.01)
    assert np.all(d.std(axis=0) < (0.4 if packed else 0.25))
    assert np.allclose(f.sd[s].mean(axis=0), sw.features.sd[s].mean(axis=0), rtol=0.02)
    assert np.max(np.abs(f.temperature - sw.features.temperature)) < 0.05


@pytest.mark.parametrize("packed", [False, True])
def test_moment_shortcut_matches_drawn_samples(packed):
    spec = DeviceSpec.make("ax3", range_g=8, packed=packed)
    rng = np.random.default_rng(7)
    x = rng.uniform(-1.0, 1.0, size=(3000, 3))
    noise = np.array([0.0028, 0.0028, 0.0039])
    ms, ss = window_statistics(x, noise, spec, True, 1000, np.random.default_rng(1), "samples")
    mm, sm = window_statistics(x, noise, spec, True, 1000, np.random.default_rng(2), "moments")
    bs, bm = (ms - x) * 1000.0, (mm - x) * 1000.0  # quantisation bias + noise of the window mean, mg
    noise_of_mean = noise * 1000.0 / np.sqrt(1000.0)
    d = bs - bm  # same x, independent draws: the bias (a function of x) cancels
    assert np.all(np.abs(d.mean(axis=0)) < 5 * d.std(axis=0) / np.sqrt(d.shape[0]))
    # each window mean scatters by the SD of its quantised samples / sqrt(n)
    assert np.allclose(d.std(axis=0), np.sqrt(2 * np.mean(ss ** 2, axis=0) / 1000.0) * 1000.0, rtol=0.1)
    if packed:  # the 15.6 mg step is not dithered by ~3-4 mg of noise: a bias of up to ~2.6 mg
        assert np.all(bs.std(axis=0) > 3 * noise_of_mean)
        assert np.all([np.corrcoef(bs[:, k], bm[:, k])[0, 1] > 0.9 for k in range(3)])
    assert np.allclose(ss.mean(axis=0), sm.mean(axis=0), rtol=0.01)
    assert np.allclose(ss.std(axis=0), sm.std(axis=0), rtol=0.15)


@pytest.mark.parametrize("noise_mg", [1.5, 2.8, 3.9, 8.0])
def test_quantisation_bias_bound_is_the_largest_bias_of_a_window_mean(noise_mg):
    """The report's bound (first harmonic) against the exact mean of rounded noisy samples."""
    from stillpoint.engine.workflows.locate import quantisation_bias_bound_mg
    from stillpoint.engine.calibration.quantisation import level_moments
    step = 15.625
    x = np.linspace(0.0, step, 2001)
    m, _ = level_moments(x, np.full_like(x, noise_mg), step)
    exact = np.max(np.abs(m - x))
    bound = float(quantisation_bias_bound_mg(step, noise_mg))
    assert bound == pytest.approx(exact, rel=0.12, abs=1e-3)
