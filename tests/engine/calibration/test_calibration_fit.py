"""The sphere fit: GGIR-compatible mode against an independent implementation and on GGIR's real
84 h feature set, the converged default, variants, invariants and error rounding."""

from __future__ import annotations

import numpy as np
import pytest

from stillpoint.engine.calibration import (apply_model, calibration_error_g, fit_calibration,
                                           icp_sphere_fit, sphere_coverage, temperature_check)
from stillpoint.engine.calibration.fit import rereference
from synthetic_calibration import random_truth, synthetic_recording
from stillpoint.engine.calibration.table import read_features_csv
from stillpoint.engine.features import WindowFeatures

SPHERE_CSV = "calib_features_ggir_data_calibrate_spheredata_84h.csv"


def reference_icp(mean, temp, max_iter=1000, tol=1e-10):
    """Independent restatement of the spec's loop (normal equations instead of least squares),
    with GGIR's stopping rule; returns offset, scale, tempoffset, iterations."""
    n = mean.shape[0]
    tc = None if temp is None else temp - temp.mean()
    o, s, to = np.zeros(3), np.ones(3), np.zeros(3)
    w = np.ones(n)
    prev = np.inf
    for it in range(1, max_iter + 1):  # noqa: B007 - the last iteration count is returned
        curr = (mean + o) * s + (0 if tc is None else tc[:, None] * to)
        closest = curr / np.linalg.norm(curr, axis=1, keepdims=True)
        new = np.empty_like(curr)
        coefs = []
        for k in range(3):
            cols = [np.ones(n), curr[:, k]] + ([] if tc is None else [tc])
            X = np.column_stack(cols)
            b = np.linalg.solve(X.T @ (w[:, None] * X), X.T @ (w * closest[:, k]))
            new[:, k] = X @ b
            coefs.append(b)
        c = np.array([np.append(b, 0.0) if tc is None else b for b in coefs])
        o = o + c[:, 0] / (s * c[:, 1])
        to = to * c[:, 1] + c[:, 2]
        s = s * c[:, 1]
        d = new - closest
        res = 3 * np.mean(w[:, None] * d ** 2) / w.sum()
        w = np.minimum(1 / np.linalg.norm(d, axis=1), 100)
        if abs(res - prev) < tol:
            break
        prev = res
    return o, s, to, it


@pytest.fixture(scope="module")
def synth():
    rng = np.random.default_rng(11)
    truth = random_truth(rng)
    rec = synthetic_recording(80, truth, seed=12)
    still = rec.features.select(rec.still)
    return truth, still


def test_ggir_mode_matches_independent_reference(synth):
    _, feats = synth
    est = fit_calibration(feats, ggir_compatible=True, select=False)
    o, s, to, it = reference_icp(feats.mean, feats.temperature)
    assert est.iterations == it
    np.testing.assert_allclose(est.offset, o, atol=1e-10)
    np.testing.assert_allclose(est.scale, s, atol=1e-10)
    np.testing.assert_allclose(est.tempoffset, to, atol=1e-11)
    est1 = fit_calibration(feats, ggir_compatible=True, select=False, temperature=False)
    o1, s1, _, it1 = reference_icp(feats.mean, None)
    assert est1.iterations == it1 and est1.method == "autocal-c1"
    np.testing.assert_allclose(est1.offset, o1, atol=1e-10)
    np.testing.assert_array_equal(est1.tempoffset, 0.0)


def test_ggir_stopping_rule_is_the_only_difference(synth):
    """The GGIR result equals the default loop stopped after the same number of iterations,
    and the default loop continues to parameter convergence."""
    _, feats = synth
    tc = feats.temperature - feats.temperature.mean()
    g = icp_sphere_fit(feats.mean, tc, ggir_compatible=True)
    d = icp_sphere_fit(feats.mean, tc, ggir_compatible=False, max_iter=g.iterations)
    np.testing.assert_allclose(d.offset, g.offset, atol=1e-12)
    np.testing.assert_allclose(d.scale, g.scale, atol=1e-12)
    res = np.array(g.res)
    assert abs(res[-1] - res[-2]) < 1e-10 <= np.min(np.abs(np.diff(res[:-1])))
    full = icp_sphere_fit(feats.mean, tc)
    assert full.converged and full.iterations > g.iterations
    more = icp_sphere_fit(feats.mean, tc, param_tol=1e-12)
    np.testing.assert_allclose(full.offset, more.offset, atol=1e-8)
    np.testing.assert_allclose(full.tempoffset, more.tempoffset, atol=1e-8)


def test_errors_recomputed_from_returned_parameters(synth):
    _, feats = synth
    est = fit_calibration(feats, select=False)
    cal = est.apply(feats.mean, feats.temperature)
    assert est.error_after_mg == pytest.approx(calibration_error_g(cal) * 1000, rel=1e-12)
    assert est.error_before_mg == pytest.approx(calibration_error_g(feats.mean) * 1000, rel=1e-12)
    assert est.temperature_ref == pytest.approx(np.mean(feats.temperature))
    g = fit_calibration(feats, ggir_compatible=True, select=False)
    tc = feats.temperature - g.temperature_ref
    cal_g = apply_model(feats.mean, tc, g.offset, g.scale, g.tempoffset, ggir_arithmetic=True)
    after_g = round(calibration_error_g(cal_g), 5)
    assert g.extra["error_after_g"] == after_g
    assert g.error_after_mg == pytest.approx(after_g * 1000, abs=1e-9)
    # GGIR prints the error to 1e-5 g: a multiple of 0.01 mg
    for v in (g.error_before_mg, g.error_after_mg):
        assert abs(v * 100 - round(v * 100)) < 1e-6


def test_invariances(synth):
    _, feats = synth
    base = fit_calibration(feats, select=False)
    # window order does not matter
    perm = np.random.default_rng(3).permutation(len(feats))
    p = fit_calibration(feats.select(perm), select=False)
    np.testing.assert_allclose(p.offset, base.offset, atol=1e-9)
    np.testing.assert_allclose(p.scale, base.scale, atol=1e-9)
    # a constant temperature shift moves only the reference temperature
    shifted = WindowFeatures.from_arrays(feats.mean, feats.sd, feats.temperature + 10.0)
    sh = fit_calibration(shifted, select=False)
    assert sh.temperature_ref == pytest.approx(base.temperature_ref + 10.0)
    np.testing.assert_allclose(sh.offset, base.offset, atol=1e-9)
    np.testing.assert_allclose(sh.tempoffset, base.tempoffset, atol=1e-10)
    # swapping the x and y axes swaps the parameters
    sw = WindowFeatures.from_arrays(feats.mean[:, [1, 0, 2]], feats.sd, feats.temperature)
    s = fit_calibration(sw, select=False)
    np.testing.assert_allclose(s.offset, base.offset[[1, 0, 2]], atol=1e-9)
    np.testing.assert_allclose(s.scale, base.scale[[1, 0, 2]], atol=1e-9)


def test_variants_recover_what_they_model():
    rng = np.random.default_rng(5)
    truth = random_truth(rng, tempoffset_mg_per_c=0.0)
    truth.scale[:] = 1.0  # offset-only device
    rec = synthetic_recording(48, truth, seed=6)
    feats = rec.features.select(rec.still)
    off = fit_calibration(feats, select=False, variant="offset")
    assert off.method == "autocal-offset" and off.status == "ok"
    np.testing.assert_array_equal(off.scale, 1.0)
    np.testing.assert_allclose(off.offset, truth.offset, atol=5e-5)
    truth2 = random_truth(rng, tempoffset_mg_per_c=0.0)
    truth2.offset[:] = 0.0  # gain-only device
    rec2 = synthetic_recording(48, truth2, seed=7)
    feats2 = rec2.features.select(rec2.still)
    sc = fit_calibration(feats2, select=False, variant="scale")
    assert sc.method == "autocal-scale" and sc.status == "ok"
    np.testing.assert_array_equal(sc.offset, 0.0)
    np.testing.assert_allclose(sc.scale, truth2.scale, rtol=5e-5)
    c1 = fit_calibration(feats2, select=False, variant="c1")
    assert c1.method == "autocal-c1" and not c1.uses_temperature
    with pytest.raises(ValueError):
        fit_calibration(feats2, variant="nonsense")
    with pytest.raises(ValueError):
        fit_calibration(feats2, variant="offset", ggir_compatible=True)


def test_temperature_check_rules():
    assert temperature_check(None) == (False, "temperature missing")
    assert not temperature_check(np.full(100, np.nan))[0]
    ok, why = temperature_check(np.full(100, 25.0))
    assert not ok and "flat" in why
    ok, why = temperature_check(np.linspace(200, 210, 100))
    assert not ok and "implausible" in why
    assert temperature_check(np.linspace(20, 30, 100)) == (True, "temperature used")


def test_sphere_coverage_reports_missing_sides():
    m = np.array([[0.9, 0.1, 0.2], [-0.9, 0.5, 0.1], [0.1, -0.5, 0.9]])
    c = sphere_coverage(m)
    assert not c.covered
    assert "z never below -0.3 g" in c.describe()
    assert sphere_coverage(np.vstack([m, [0, 0, -1.0]])).covered


def test_rereference_is_the_same_calibration(synth):
    truth, feats = synth
    r = rereference(truth, 31.0)
    np.testing.assert_allclose(r.apply(feats.mean, feats.temperature),
                               truth.apply(feats.mean, feats.temperature), atol=1e-14)


# ------------------------------------------------------------------------ GGIR's real feature set
@pytest.fixture(scope="module")
def ggir_features(real_file):
    return read_features_csv(real_file(SPHERE_CSV))


def test_real_sphere_data_ggir_compatible(ggir_features):
    f = ggir_features
    assert len(f) == 10958
    est = fit_calibration(f, ggir_compatible=True)
    assert est.status == "ok" and est.method == "autocal-c2"
    assert est.windows == 10958  # GGIR's spheredata is already its selection
    assert est.temperature_ref == pytest.approx(27.2709, abs=5e-5)  # PROVENANCE: mean 27.2709
    o, s, to, it = reference_icp(f.mean, f.temperature)
    assert est.iterations == it and est.extra["converged"]
    np.testing.assert_allclose(est.offset, o, atol=1e-10)
    np.testing.assert_allclose(est.scale, s, atol=1e-10)
    np.testing.assert_allclose(est.tempoffset, to, atol=1e-11)
    # the stopping decision is not marginal: last |delta res| clearly below 1e-10, the one
    # before clearly above (so rounding differences cannot change the iteration count)
    r = icp_sphere_fit(f.mean, f.temperature - f.temperature.mean(), ggir_compatible=True)
    dres = np.abs(np.diff(r.res))
    assert dres[-1] < 0.95e-10 and dres[-2] > 1.05e-10
    before = round(calibration_error_g(f.mean), 5)
    assert est.extra["error_before_g"] == before
    assert est.error_after_mg < est.error_before_mg / 3


def test_real_sphere_data_default_vs_ggir(ggir_features):
    """Stated tolerance between GGIR's early stop and the converged fit on the real set: offsets
    within 5 mg, scales within 0.3%, temperature offsets within 1 mg/degC, and the converged
    fit's error is lower."""
    g = fit_calibration(ggir_features, ggir_compatible=True)
    # the temperature term's standard errors (0.13-0.16 mg/degC) exceed the 0.05 mg/degC
    # limit, but z is ~10 SE from zero: the default (auto) keeps it, with a warning
    auto = fit_calibration(ggir_features)
    assert auto.method == "autocal-c2" and "temperature_imprecise" in auto.extra["flags"]
    d = fit_calibration(ggir_features, variant="c2")
    assert "temperature_imprecise" in d.extra["flags"] and "kept" in d.reason
    np.testing.assert_array_equal(auto.tempoffset, d.tempoffset)
    assert d.extra["converged"] and d.iterations > 3 * g.iterations
    assert d.status == "ok" and d.error_after_mg < g.error_after_mg
    np.testing.assert_allclose(d.offset, g.offset, atol=5e-3)
    np.testing.assert_allclose(d.scale, g.scale, atol=3e-3)
    np.testing.assert_allclose(d.tempoffset, g.tempoffset, atol=1e-3)
    c1 = fit_calibration(ggir_features, temperature=False)
    assert c1.method == "autocal-c1" and d.error_after_mg < c1.error_after_mg
