"""Window means of quantised samples, de-biased (engine/calibration/quantisation.py): against
windows of samples drawn, rounded to the step and averaged, with the true value known."""

import numpy as np
import pytest

from stillpoint.engine.calibration.quantisation import dequantise_means, level_moments

STEP = 4 / 256  # AX3 packed at +-8 g: 15.6 mg


def _windows(noise_g, k=1500, n=1000, seed=0):
    rng = np.random.default_rng(seed)
    x = rng.uniform(-1.0, 1.0, (k, 3))
    s = np.rint((x[:, None, :] + rng.normal(0.0, noise_g, (k, n, 3))) / STEP) * STEP
    return x, s.mean(axis=1), s.std(axis=1, ddof=1)


@pytest.mark.parametrize("noise_mg,gain", [(2.5, 2.5), (3.9, 3.0)])
def test_dequantised_means_lose_most_of_the_pull(noise_mg, gain):
    """Device noise below half a step (a still device on a table): the pull towards the levels
    (SD 1-2 mg) shrinks several-fold, and no systematic error is added."""
    x, m, sd = _windows(noise_mg / 1000)
    d = dequantise_means(m, sd, STEP)
    raw, fixed = (m - x) * 1000, (d - x) * 1000
    assert np.all(raw.std(axis=0) > gain * fixed.std(axis=0)), (raw.std(axis=0), fixed.std(axis=0))
    assert np.all(np.abs(fixed.mean(axis=0)) < 0.05)


def test_dithered_windows_are_left_as_they_are():
    """Enough spread to dither the step: the means barely move (the pull is already nil)."""
    x, m, sd = _windows(0.010, k=500)
    d = dequantise_means(m, sd, STEP)
    assert np.max(np.abs(d - m)) * 1000 < 0.1
    # non-finite inputs stay as they are; a zero step leaves the axis alone
    m[0, 0] = np.nan
    out = dequantise_means(m, sd, np.array([STEP, 0.0, STEP]))
    assert np.isnan(out[0, 0]) and np.array_equal(out[:, 1], m[:, 1])


def test_level_moments_match_drawn_samples():
    rng = np.random.default_rng(3)
    x = rng.uniform(0, 3 * STEP, 200)
    s = np.full(200, 0.004)
    mu, v = level_moments(x, s, STEP)
    draw = np.rint((x[:, None] + rng.normal(0, 0.004, (200, 20000))) / STEP) * STEP
    np.testing.assert_allclose(mu, draw.mean(axis=1), atol=2.5e-4)  # 5 SE of 20,000 draws
    np.testing.assert_allclose(v, draw.var(axis=1), rtol=0.05)


def test_online_calibrator_takes_the_step_either_way():
    """The step as a fit option (as fit_calibration takes it) or as the stream's CountStep: the
    same de-biased windows and the same estimate."""
    from types import SimpleNamespace

    from stillpoint.engine.calibration import OnlineCalibrator
    from stillpoint.engine.sim import SimSource
    from stillpoint.engine.calibration.recording import calibrate_source

    src = SimSource(days=1.2, hz=25, seed=4)
    feats = calibrate_source(src, read_all=True).windows
    a = OnlineCalibrator(quantisation_step_g=STEP)
    b = OnlineCalibrator(count_step=SimpleNamespace(step_g=STEP))
    raw = OnlineCalibrator()
    ea, eb = a.add(feats) + a.finish(), b.add(feats) + b.finish()
    raw.add(feats)
    assert np.array_equal(a.windows.mean, b.windows.mean)
    assert a.windows.mean.shape == raw.windows.mean.shape
    assert np.max(np.abs(a.windows.mean - raw.windows.mean)) > 1e-4  # de-biased (> 0.1 mg)
    assert ea[-1].extra["means_dequantised"] and np.array_equal(ea[-1].offset, eb[-1].offset)


def test_online_calibrator_debiases_pieces_as_the_whole():
    """Windows handed over in many small pieces (a block's worth each), their step known only
    from the third piece on: de-biased as each piece on its own would be (the calibrator
    defers the work to its next fit and does each run of one step at once)."""
    from types import SimpleNamespace

    from stillpoint.engine.calibration import OnlineCalibrator
    from stillpoint.engine.calibration.select import select_calibration_windows
    from stillpoint.engine.sim import SimSource
    from stillpoint.engine.calibration.recording import calibrate_source
    from stillpoint.engine.calibration.quantisation import dequantised

    feats = calibrate_source(SimSource(days=1.0, hz=25, seed=6), read_all=True).windows
    step = SimpleNamespace(step_g=None)
    cal = OnlineCalibrator(count_step=step, chunk_hours=6)
    want, last = [], None
    for i, a in enumerate(range(0, len(feats), 37)):
        if i == 2:
            step.step_g = STEP
        piece = feats.select(slice(a, a + 37))
        cal.add(piece)
        sel = select_calibration_windows(piece, previous_mean=last).features
        last = piece.mean[-1].copy()
        if len(sel):
            want.append(sel.mean if step.step_g is None else dequantised(sel, STEP).mean)
        if i == 1:
            before = sum(len(w) for w in want)
    assert before > 0  # windows taken before the step was known stay as they were
    want = np.concatenate(want)
    got = cal.windows.mean
    assert got.shape == want.shape and np.array_equal(got, want)
