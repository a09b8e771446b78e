"""Edge cases of the fit and the schedule: each outcome has a status and a one-line reason."""

from __future__ import annotations

import numpy as np
import pytest

from stillpoint.engine.calibration import (OnlineCalibrator, fit_batch_schedule, fit_calibration,
                                           select_calibration_windows)
from stillpoint.engine.calibration import fit as fitmod
from stillpoint.engine.calibration.fit import IcpResult, rereference
from synthetic_calibration import (random_directions, random_truth,
                                                     synthetic_recording)
from stillpoint.engine.features import WindowFeatures


def one_line(reason: str) -> bool:
    return bool(reason) and "\n" not in reason


def is_identity(est) -> bool:
    return (np.all(est.offset == 0) and np.all(est.scale == 1) and np.all(est.tempoffset == 0))


@pytest.fixture(scope="module")
def truth():
    return random_truth(np.random.default_rng(41))


def test_no_nonmovement_windows(truth):
    rec = synthetic_recording(80, truth, seed=42, still_fraction=0.0)
    est = fit_batch_schedule(rec.features)
    assert est.status == "no_nonmovement" and is_identity(est) and est.method == "identity"
    assert f"among {len(rec.features)} windows" in est.reason and one_line(est.reason)
    assert est.windows == 0
    # the schedule went on to the end of the file before giving up
    assert est.hours_used == pytest.approx(80.0)
    online = OnlineCalibrator()
    pub = online.add(rec.features)
    assert all(not e.extra["accepted"] for e in pub)
    assert online.current.status == "identity" and is_identity(online.current)
    assert fit_calibration(WindowFeatures.empty()).status == "no_nonmovement"


def test_too_few_windows(truth):
    rec = synthetic_recording(10, truth, seed=43)
    still = rec.features.select(np.flatnonzero(rec.still)[:5])
    est = fit_calibration(still, select=False)
    assert est.status == "too_few_windows" and is_identity(est) and "only 5" in est.reason


def test_one_sided_sphere(truth):
    rec = synthetic_recording(100, truth, seed=44, min_axis=np.array([-1.0, -1.0, 0.4]))
    est = fit_batch_schedule(rec.features)
    assert est.status == "sphere_not_covered" and is_identity(est)
    assert "z never below -0.3 g" in est.reason and one_line(est.reason)
    assert est.error_before_mg > 10  # reported, so users see how bad the device is
    assert [a["hours"] for a in est.extra["schedule"]] == [72.0, 84.0, 96.0, 100.0]


def test_fit_that_never_reaches_10mg(truth):
    """Cross-axis coupling the model cannot express: the fit helps but stays above 10 mg."""
    rec = synthetic_recording(50, truth, seed=45)
    coupling = np.array([[1.0, 0.06, 0.03], [-0.05, 1.0, 0.07], [0.04, -0.06, 1.0]])
    f = rec.features
    bent = WindowFeatures.from_arrays(f.mean @ coupling.T, f.sd, f.temperature, start_ns=f.start_ns)
    est = fit_batch_schedule(bent, first_hours=24)
    assert est.status == "high_error", est.reason
    assert 10.0 <= est.error_after_mg < est.error_before_mg
    assert not is_identity(est)  # it lowered the error, so it is applied
    assert "above the 10 mg target" in est.reason and one_line(est.reason)
    assert est.extra["schedule"][-1]["hours"] == pytest.approx(50.0)  # tried to the end
    assert [a["hours"] for a in est.extra["schedule"]] == [24.0, 36.0, 48.0, 50.0]


@pytest.mark.parametrize("profile, why", [("flat", "temperature flat"),
                                          ("missing", "temperature missing")])
def test_temperature_flat_or_missing_fits_c1(profile, why):
    rng = np.random.default_rng(46)
    tr = random_truth(rng, tempoffset_mg_per_c=0.0)
    rec = synthetic_recording(80, tr, seed=47, temperature=profile)
    est = fit_batch_schedule(rec.features)
    assert est.status == "ok" and est.method == "autocal-c1"
    assert not est.uses_temperature and why in est.reason
    assert est.extra["temperature_reason"].startswith(why)
    np.testing.assert_allclose(est.offset, tr.offset, atol=0.05e-3)
    np.testing.assert_allclose(est.scale, tr.scale, rtol=0.005e-2)
    # c2 explicitly requested: falls back to c1 and flags it
    c2 = fit_calibration(rec.features, variant="c2")
    assert c2.method == "autocal-c1" and "temperature_unavailable" in c2.extra["flags"]


def test_recording_dominated_by_nonwear_on_a_table(truth):
    """Five days on a table (identical window means), then two days worn."""
    rec = synthetic_recording(7 * 24, truth, seed=48, table_hours=5 * 24)
    est = fit_batch_schedule(rec.features)
    assert est.status == "ok", est.reason
    assert est.extra["repeats_collapsed"] > 40000
    first = est.extra["schedule"][0]
    assert first["status"] == "too_few_windows" and first["hours"] == pytest.approx(72.0)
    tr = rereference(truth, est.temperature_ref)
    np.testing.assert_allclose(est.offset, tr.offset, atol=0.1e-3)
    np.testing.assert_allclose(est.scale, truth.scale, rtol=0.01e-2)
    sel = select_calibration_windows(rec.features)
    assert sel.repeats_dropped == est.extra["repeats_collapsed"]


def test_fit_that_raises_the_error_is_reverted(monkeypatch, truth):
    rec = synthetic_recording(30, truth, seed=49)

    def bad_fit(mean, temp, **kw):
        return IcpResult(np.full(3, 0.2), np.ones(3), np.zeros(3), 7, True, "parameters", [1.0])

    monkeypatch.setattr(fitmod, "icp_sphere_fit", bad_fit)
    est = fit_calibration(rec.features)
    assert est.status == "reverted" and is_identity(est) and est.method == "identity"
    assert "did not lower the error" in est.reason and "identity used" in est.reason
    assert est.extra["rejected_fit"]["offset"] == [0.2, 0.2, 0.2]
    assert est.error_after_mg == est.error_before_mg


def test_selection_rules():
    mean = np.array([[0, 0, 1.0], [0, 0, 1.0], [0, 1.0, 0], [2.5, 0, 0], [0, 0, 0], [0, 0.9, 0]])
    sd = np.array([[0.005] * 3, [0.005] * 3, [0.005] * 3, [0.005] * 3, [0.0] * 3,
                   [0.005, 0.014, 0.005]])
    f = WindowFeatures.from_arrays(mean, sd, np.full(6, 25.0))
    sel = select_calibration_windows(f)
    # repeat collapsed, clipped (>2 g) dropped, all-zero dropped, SD 14 mg dropped
    np.testing.assert_array_equal(sel.features.mean, mean[[0, 2]])
    assert sel.repeats_dropped == 1
    # the threshold is a parameter (actipy uses 15 mg)
    assert len(select_calibration_windows(f, sd_threshold=0.015).features) == 3
    # a repeat across a chunk boundary is seen through previous_mean
    s2 = select_calibration_windows(f.select(slice(2, 3)), previous_mean=np.array([0, 1.0, 0]))
    assert len(s2.features) == 0


def test_random_directions_respects_restriction():
    rng = np.random.default_rng(0)
    d = random_directions(rng, 500, np.array([-1, -1, 0.4]))
    assert d.shape == (500, 3) and d[:, 2].min() >= 0.4
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0)


@pytest.mark.parametrize("cuts", [[], [1], [517, 518, 4000], list(range(0, 30000, 2048))])
def test_streamed_selection_gives_the_whole_table_estimate(truth, cuts):
    """A batch run's pass 1 keeps only the nonmovement windows (NonmovementOperator) and every
    window's start time, not the window table: the estimate, its schedule and its counts are
    exactly those of the whole table, with repeats on a table, a cut inside a repeat run and a
    restart that sends the clock back."""
    from stillpoint.engine.operators.nonmovement import NonmovementOperator
    rec = synthetic_recording(100, truth, seed=46, table_hours=6.0)
    f = rec.features
    k = len(f)
    back = np.arange(k, dtype=np.int64)
    back[k // 2:] -= 3000  # a restart: the second half begins ~8 h earlier
    f = WindowFeatures.from_arrays(f.mean, f.sd, f.temperature, start_ns=f.start_ns[back])
    whole = fit_batch_schedule(f, recording_start_ns=int(f.start_ns.min()),
                               recording_end_ns=int(f.start_ns.max()))
    nm = NonmovementOperator()
    starts = []
    edges = [0] + [c for c in cuts if 0 < c < k] + [k]
    for a, b in zip(edges[:-1], edges[1:]):
        piece = f.select(np.arange(a, b))
        starts.append(piece.start_ns)
        nm.push(piece)
    assert nm.repeats_dropped > 100  # the table hours were collapsed
    streamed = fit_batch_schedule(nm.selected, select=False, all_starts=np.concatenate(starts),
                                  repeats_collapsed=nm.repeats_dropped,
                                  recording_start_ns=int(f.start_ns.min()),
                                  recording_end_ns=int(f.start_ns.max()))
    assert whole.status == "ok" and streamed.status == whole.status
    for name in ("offset", "scale", "tempoffset"):
        assert np.array_equal(getattr(streamed, name), getattr(whole, name)), name
    for name in ("temperature_ref", "error_before_mg", "error_after_mg", "windows",
                 "hours_used", "reason"):
        assert getattr(streamed, name) == getattr(whole, name), name
    assert streamed.extra == whole.extra
