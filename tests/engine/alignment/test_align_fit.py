"""Clock-model fits on lag tables with known answers: Brønd iterative exclusion, robust fit,
confidence intervals, step detection and location, temperature term selection."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.special import stdtrit

from stillpoint.engine.alignment.fit import (CannotAlign, ClockFit, TemperatureRegressor,
                                             brond_fit, fit_brond, fit_robust, heldout_rmse)
from stillpoint.engine.alignment.lags import BlockLag

RATE = 30.0


def table(lags, start_s=None, sub=None, valid=None):
    n = len(lags)
    start_s = np.arange(n) * 3600.0 if start_s is None else start_s
    out = []
    for i in range(n):
        b = BlockLag(index=i, start_s=float(start_s[i]), duration_s=3600.0, lag=float(lags[i]),
                     corr=0.9, valid=True if valid is None else bool(valid[i]))
        b.centroid_s = b.centre_s
        if sub is not None:
            b.sub_lags = sub[i]
        out.append(b)
    return out


def test_brond_thresholds_follow_1_e_ee():
    rng = np.random.default_rng(0)
    t = np.arange(200) * 3600.0
    y = 5 + 1e-4 * t + rng.normal(0, 1, t.size)
    y[[10, 50, 120]] += [40, -60, 80]
    coef, inc, used = brond_fit(t, y)
    assert used[0] == 1.0 and len(used) >= 2
    for a, b in zip(used, used[1:]):  # 1, e, e^e, ...
        assert b == pytest.approx(math.exp(a))
    assert not inc[[10, 50, 120]].any()
    assert abs(coef[1] - 1e-4) < 2e-5
    # without outliers, the first 1-SD pass drops about a third of normal residuals (a known
    # property of the method, spec "Known gaps in the code")
    _, inc2, _ = brond_fit(t, 5 + 1e-4 * t + rng.normal(0, 1, t.size))
    assert 0.2 < 1 - inc2.mean() < 0.45


def test_fit_brond_recovers_line_and_reports_exclusions():
    rng = np.random.default_rng(1)
    t = np.arange(100) * 3600.0
    y = np.round(-30 + 2.5e-4 * t + rng.normal(0, 0.3, t.size))
    y[7] = 400
    fit = fit_brond(table(y), RATE, block_time="start")
    assert fit.model == "linear" and fit.method == "brond"
    assert not fit.included[7]
    assert abs(fit.initial_offset_s - (-1.0)) < 0.5 / RATE
    assert abs(fit.drift_s_per_day - 2.5e-4 / RATE * 86400) < 0.01


def test_too_few_blocks_is_a_clear_cannot_align():
    blocks = table([1.0, 2.0, 3.0, 4.0, 5.0], valid=[True, True, True, False, False])
    blocks[3].reason = blocks[4].reason = "inactive"
    for f in (fit_brond, fit_robust):
        with pytest.raises(CannotAlign, match="too few blocks: 3 usable .*2 inactive"):
            f(blocks, RATE)
        with pytest.raises(CannotAlign, match=r"too few blocks: 0 usable block\(s\) .*\(0 block"):
            f([], RATE)  # no block at all: no block length is named (it used to say 60 min)


def test_robust_confidence_intervals_cover_the_truth():
    rng = np.random.default_rng(2)
    hits = 0
    for _ in range(60):
        t = np.arange(60) * 3600.0
        b0, b1 = rng.uniform(-300, 300), rng.uniform(-2e-3, 2e-3)
        y = b0 + b1 * (t + 1800) + rng.normal(0, 0.3, t.size)
        fit = fit_robust(table(y), RATE, detect_steps=False)
        lo, hi = fit.ci()["initial_offset_s"]
        lo2, hi2 = fit.ci()["drift_s_per_day"]
        hits += (lo <= b0 / RATE <= hi) and (lo2 <= b1 / RATE * 86400 <= hi2)
    assert hits >= 48  # 95 % intervals, both must cover: expect ~54 of 60


def test_robust_ignores_gross_outliers_and_finds_no_step_in_a_line():
    rng = np.random.default_rng(3)
    t = np.arange(80) * 3600.0 + 1800
    y = 12 + 4e-4 * t + rng.normal(0, 0.2, t.size)
    bad = rng.choice(80, 12, replace=False)
    y[bad] += rng.uniform(-5000, 5000, 12)
    fit = fit_robust(table(y), RATE)
    assert fit.model == "linear" and not fit.steps
    assert set(np.nonzero(~fit.included)[0]) >= set(bad[np.abs(y[bad] - 12 - 4e-4 * t[bad]) > 2])
    assert abs(fit.b0 - 12) < 0.3 and abs(fit.b1 - 4e-4) < 5e-6


@pytest.mark.parametrize("halt_s", [2.0, 37.5, 400.0])
def test_step_detected_and_located_with_sub_blocks(halt_s):
    rng = np.random.default_rng(int(halt_s))
    n = 72
    start = np.arange(n) * 3600.0
    tau = 30.3 * 3600.0  # the halt happens 18 min into block 30
    true = lambda tt: 40 + 3e-4 * tt - halt_s * RATE * (tt >= tau)  # noqa: E731
    sub_t = start[:, None] + (np.arange(6) + 0.5)[None, :] * 600
    sub = true(sub_t) + rng.normal(0, 0.3, sub_t.shape)
    sub[30, 1] = true(tau + 1)  # the sub-block containing the halt: mostly after it
    y = np.array([np.mean(s) for s in sub])
    y[30] = true(start[30] + 3000)  # the mixed block takes the post-halt lag
    fit = fit_robust(table(y + rng.normal(0, 0.2, n), sub=sub), RATE)
    assert fit.model.startswith("piecewise") and len(fit.steps) == 1
    s = fit.steps[0]
    assert abs(s.size / RATE + halt_s) < 0.05
    assert s.window_s[0] <= tau <= s.window_s[1]
    assert s.window_s[1] - s.window_s[0] <= 3600.0  # within one block
    assert abs(fit.drift_day7_s - (true(7 * 86400.0) - true(0.0)) / RATE) < 0.5


def test_temperature_term_follows_the_data_from_the_crystal_prior():
    rng = np.random.default_rng(4)
    grid = np.arange(0, 7 * 86400.0, 60.0)
    t_ref = 31 + 3 * np.sin(2 * np.pi * grid / 86400)
    t_oth = 26 + 8 * np.sin(2 * np.pi * grid / 86400 + 1)
    reg = TemperatureRegressor.from_temperatures(grid, t_ref, t_oth)
    t = np.arange(140) * 3600.0 + 1800
    gamma = -0.035e-6 * RATE  # samples per (degC^2 s)
    y_temp = 5 + 2e-4 * t + gamma * reg(t) + rng.normal(0, 0.15, t.size)
    fit = fit_robust(table(y_temp), RATE, temperature=reg)
    assert fit.model == "linear+temperature"
    assert abs(fit.temp_coef - gamma) < 0.2 * abs(gamma)
    d = fit.diagnostics["temperature"]
    assert d["heldout_rmse_with"] < d["heldout_rmse_without"]
    y_lin = 5 + 2e-4 * t + rng.normal(0, 0.15, t.size)
    fit2 = fit_robust(table(y_lin), RATE, temperature=reg)
    # the parabola is always in the model, its coefficient starting from the typical crystal's:
    # lags that do not curve pull it to about zero, and the line is the data's
    assert fit2.model == "linear+temperature" and not fit2.diagnostics["temperature"]["chosen"]
    assert abs(fit2.temp_coef) < 0.2 * abs(gamma)
    assert abs(fit2.b0 - 5) < 0.1 and abs(fit2.b1 - 2e-4) < 1e-6


def test_heldout_rmse_prefers_the_true_model():
    rng = np.random.default_rng(5)
    t = np.arange(50) * 3600.0
    y = 2 + 1e-3 * t + 5 * (t >= 25 * 3600) + rng.normal(0, 0.1, t.size)
    assert heldout_rmse(t, y, [24.5 * 3600], None) < heldout_rmse(t, y, [], None)


def test_weak_peaks_and_the_crystal_curve_do_not_bias_the_initial_offset():
    """Realistic wear: weak-peak blocks carry biased, noisier lags and the lag curves with the
    crystals' temperatures (too gently for a free term to be chosen). The weighted fit with the
    crystal prior keeps the initial offset and its interval on the truth; equal weights and a
    straight line were 0.7 samples off, outside their interval."""
    rng = np.random.default_rng(31)
    grid = np.arange(0, 7 * 86400.0 + 3600, 60.0)
    t_ref = 30 + 2 * np.sin(2 * np.pi * grid / 86400)
    t_oth = 32 + 4 * np.sin(2 * np.pi * grid / 86400 + 0.5)
    reg = TemperatureRegressor.from_temperatures(grid, t_ref, t_oth)
    t = np.arange(0, 7 * 86400.0, 1800.0) + 900.0
    gamma = -0.035e-6 * RATE
    truth = -100.0 + 1.5e-5 * t + gamma * reg(t)
    strong = rng.random(t.size) < 0.4
    y = truth + np.where(strong, rng.normal(0, 1.0, t.size), rng.normal(-1.2, 2.5, t.size))
    blocks = table(y, start_s=t - 900.0)
    for b, s in zip(blocks, strong):
        b.duration_s, b.corr = 1800.0, (0.93 if s else 0.45)
        b.centroid_s = b.centre_s
    fit = fit_robust(blocks, RATE, temperature=reg)
    assert abs(fit.b0 - (-100.0)) < 0.3, fit.b0
    lo, hi = fit.ci()["initial_offset_s"]
    assert lo <= -100.0 / RATE <= hi
    d_lo, d_hi = fit.ci()["drift_day7_s"]
    true7 = float(truth[-1] - truth[0]) / RATE  # close to day 7 (t runs 0.5 h .. 7 d - 0.5 h)
    assert abs(fit.drift_day7_s - true7) < 0.1


def _biased_pair(seed: int, days: float = 2.0, block_s: float = 600.0):
    """A pair's 10-minute block lags with a known clock: the peak heights of wrist/hip wear
    (0.4-0.97), lag noise growing with the peak's noise-to-signal ratio (1 - rho^2) / rho^2, and
    a bias proportional to it whose size and sign are the pair's own (on simulated wrist/hip
    weeks the weak blocks of one pair are 20-50 ms early, of another as late)."""
    rng = np.random.default_rng(seed)
    grid = np.arange(0, days * 86400.0 + 3600, 60.0)
    reg = TemperatureRegressor.from_temperatures(
        grid, 30 + 2 * np.sin(2 * np.pi * grid / 86400),
        32 + 4 * np.sin(2 * np.pi * grid / 86400 + 0.5))
    t = np.arange(0, days * 86400.0, block_s) + block_s / 2
    t = t[((t % 86400) < 16 * 3600) & (rng.random(t.size) < 0.6)]  # awake, moving
    b0, b1 = rng.uniform(-300, 300), rng.uniform(-50, 50) * 1e-6 * RATE
    truth = b0 + b1 * t - 0.035e-6 * RATE * reg(t)
    rho = np.clip(rng.beta(5, 2.2, t.size), 0.4, 0.97)
    nsr = (1 - rho ** 2) / rho ** 2
    y = truth + rng.normal(0, 0.4) * nsr + rng.normal(0, 0.45, t.size) * np.sqrt(nsr)
    blocks = table(y, start_s=t - block_s / 2)
    for b, r in zip(blocks, rho):
        b.duration_s, b.corr = block_s, float(r)
        b.centroid_s = b.centre_s
    return blocks, reg, b0 / RATE


def test_the_weak_peaks_bias_is_modelled_and_the_interval_covers_the_offset():
    """The weak peaks' bias differs in sign between pairs, so no fixed correction and no
    weighting removes it: the fit estimates it per pair as a term in the blocks' noise-to-signal
    ratio and reports the clock's lag at a noise-free peak. Over 12 seeded pairs the initial
    offset's 95 % interval covers the truth in at least 11 and the median error is below 3 ms
    (12 and 2.1 ms; with the bias left in the lags 7 were covered, median error 7.5 ms)."""
    errs, covered = [], 0
    for seed in range(12):
        blocks, reg, truth = _biased_pair(seed)
        fit = fit_robust(blocks, RATE, temperature=reg, min_blocks=12)
        lo, hi = fit.ci()["initial_offset_s"]
        covered += lo <= truth <= hi
        errs.append(abs(fit.initial_offset_s - truth))
        assert fit.diagnostics["weak_peak_bias"]["sd"] > 0
    assert covered >= 11, covered
    assert np.median(errs) < 0.003, np.median(errs)


def test_each_interval_takes_the_wider_variance_for_its_own_quantity():
    """The jackknife over time folds is wider than weighted least squares for the drift here but
    not for the initial offset: the offset's interval keeps its least-squares width and t
    quantile, day 7 takes the folds' variance with folds - 1 degrees of freedom (one factor
    for both widened the offset by the drift's ratio)."""
    fit = ClockFit(method="robust", model="linear", rate=RATE, b0=0.0, b1=0.0,
                   cov=np.diag([4.0, 1e-12]), dof=200,
                   cov_folds=np.diag([1.0, 9e-12]), dof_folds=6)
    ci = fit.ci()
    h0 = 0.5 * (ci["initial_offset_s"][1] - ci["initial_offset_s"][0]) * RATE
    assert h0 == pytest.approx(float(stdtrit(200, 0.975)) * 2.0)
    h7 = 0.5 * (ci["drift_day7_s"][1] - ci["drift_day7_s"][0]) * RATE
    assert h7 == pytest.approx(float(stdtrit(6, 0.975)) * 3e-6 * 7 * 86400.0)
