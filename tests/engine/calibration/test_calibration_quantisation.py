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


def test_tables_built_once_then_read_from_the_cache(tmp_path, monkeypatch):
    """The tables are built on first use and written to the cache; later runs read the same
    bits; a damaged cache file is rebuilt; with the cache off nothing is written."""
    from stillpoint.engine.calibration import quantisation as q

    monkeypatch.setenv("STILLPOINT_CACHE_DIR", str(tmp_path))
    q._tables.cache_clear()
    X, V = q._tables()
    files = list(tmp_path.glob("quantisation_tables-*.npy"))
    assert len(files) == 1
    built = np.stack(q.build_tables())
    assert np.array_equal(np.stack([X, V]).view(np.uint64), built.view(np.uint64))
    q._tables.cache_clear()
    calls = []
    monkeypatch.setattr(q, "build_tables", lambda: calls.append(1) or tuple(built))
    X2, V2 = q._tables()
    assert not calls and np.array_equal(X2, X) and np.array_equal(V2, V)  # read, not built
    files[0].write_bytes(files[0].read_bytes()[:100])  # a torn file
    q._tables.cache_clear()
    X3, _ = q._tables()
    assert calls == [1] and np.array_equal(X3, X)
    off = tmp_path / "off"
    monkeypatch.setenv("STILLPOINT_CACHE_DIR", "off")
    q._tables.cache_clear()
    q._tables()
    assert calls == [1, 1] and not off.exists()
    q._tables.cache_clear()


def test_calibration_import_does_not_load_scipy_special(tmp_path, monkeypatch):
    """Importing the calibration package (and de-biasing on cached tables) leaves
    scipy.special, the online calibrator and the store unloaded: the start-up cost of
    ``stillpoint calibrate``; the lazy names still import."""
    import os
    import subprocess
    import sys

    from stillpoint.engine.calibration import quantisation as q

    monkeypatch.setenv("STILLPOINT_CACHE_DIR", str(tmp_path))
    q._tables.cache_clear()
    q._tables()  # warms the cache the child reads
    q._tables.cache_clear()

    code = ("import sys; import stillpoint.engine.calibration as c; "
            "import numpy as np; from stillpoint.engine.calibration.quantisation import "
            "dequantise_means; dequantise_means(np.full((4, 3), 0.3), np.full((4, 3), 0.003), "
            "4 / 256); print([m in sys.modules for m in ('scipy.special', "
            "'stillpoint.engine.calibration.store', 'stillpoint.engine.calibration.online')]); "
            "print(c.CalibrationStore.__name__, c.CalibrationStoreError.__name__, "
            "c.OnlineCalibrator.__name__)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         env=dict(os.environ))
    assert out.stdout.split("\n")[:2] == ["[False, False, False]",
                                          "CalibrationStore CalibrationStoreError OnlineCalibrator"]


def test_solve_equals_the_full_row_form():
    """The solve reads the position table at the two bracketing sigmas only: the same bits as
    interpolating the whole row first."""
    from stillpoint.engine.calibration import quantisation as q

    def full_rows(m, v_obs, step):
        X, V = q._tables()
        out = m.copy()
        ok = np.isfinite(m) & np.isfinite(v_obs) & (v_obs < (q.SIGMA[-1] * step) ** 2)
        level = np.floor(m[ok] / step)
        f = (m[ok] / step - level) * (q.MU.size - 1)
        i0 = np.minimum(f.astype(np.int64), q.MU.size - 2)
        t = (f - i0)[:, None]
        vrow = (1 - t) * V[i0] + t * V[i0 + 1]
        xrow = (1 - t) * X[i0] + t * X[i0 + 1]
        vn = v_obs[ok] / (step * step)
        j = np.clip(np.sum(vrow < vn[:, None], axis=1), 1, q.SIGMA.size - 1)
        r = np.arange(j.size)
        lo, hi = vrow[r, j - 1], vrow[r, j]
        w = np.clip((vn - lo) / np.where(hi > lo, hi - lo, 1.0), 0.0, 1.0)
        x = (1 - w) * xrow[r, j - 1] + w * xrow[r, j]
        out[np.nonzero(ok)[0]] = (level + x) * step
        return out

    rng = np.random.default_rng(11)
    m = rng.uniform(-2.0, 2.0, 5000)
    v = (rng.uniform(0.0, 0.03, 5000)) ** 2
    m[:3] = [np.nan, 0.0, STEP]
    v[3] = np.inf
    assert np.array_equal(q._solve(m, v, STEP), full_rows(m, v, STEP), equal_nan=True)


def test_windows_solved_a_chunk_at_a_time_as_all_at_once(monkeypatch):
    """The windows are solved CHUNK at a time (small temporaries); any cut gives the same bits."""
    import stillpoint.engine.calibration.quantisation as q
    rng = np.random.default_rng(3)
    m = rng.normal(0.0, 0.5, (1500, 3))
    sd = np.abs(rng.normal(0.004, 0.002, (1500, 3)))
    monkeypatch.setattr(q, "CHUNK", 10**6)
    whole = dequantise_means(m, sd, 0.0156)
    assert not np.array_equal(whole, m)  # the pull was removed somewhere
    for chunk in (7, 512):
        monkeypatch.setattr(q, "CHUNK", chunk)
        assert np.array_equal(dequantise_means(m, sd, 0.0156), whole), chunk


def test_a_batch_run_lets_the_tables_go_after_its_fit(tmp_path):
    """Pass 2 fits nothing: the tables (~1 MB) are not held through it."""
    from stillpoint.engine.calibration.quantisation import _tables
    from stillpoint.engine.run import RunSettings, process_file
    from cwa_helpers import damaged_cwa
    src = damaged_cwa(tmp_path / "d.cwa", 3)
    _tables()
    assert _tables.cache_info().currsize == 1
    process_file(src, tmp_path / "out.mcap", RunSettings(mode="batch", chunk_hours=0.25, first_hours=0.25))
    assert _tables.cache_info().currsize == 0
