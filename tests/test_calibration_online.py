"""Online refits and the incremental schedule: results do not depend on how the feature stream
is cut (the engine's core invariant), boundaries and effective times, end of stream."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from stillpoint.engine.calibration import (BatchSchedule, OnlineCalibrator, fit_batch_schedule,
                                           fit_calibration, select_calibration_windows)
from stillpoint.engine.calibration import fit as fitmod
from stillpoint.engine.calibration.fit import IcpResult
from stillpoint.engine.calibration.recording import calibrate_source
from synthetic_calibration import (SyntheticSource, random_truth,
                                                     synthetic_recording)

H = 3600 * 10**9


@pytest.fixture(scope="module")
def rec():
    return synthetic_recording(40, random_truth(np.random.default_rng(71)), seed=72)


def run_online(feats, cuts):
    cal = OnlineCalibrator(chunk_hours=6)
    out = []
    edges = [0, *sorted(set(cuts)), len(feats)]
    for a, b in zip(edges[:-1], edges[1:]):
        out += cal.add(feats.select(slice(a, b)))
    out += cal.finish()
    return cal, out


@pytest.fixture(scope="module")
def reference(rec):
    return run_online(rec.features, [])


@settings(max_examples=5, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(cuts=st.lists(st.integers(min_value=1, max_value=14399), max_size=12))
def test_online_independent_of_cuts(rec, reference, cuts):
    _, ref = reference
    _, got = run_online(rec.features, cuts)
    assert [e.fit_end_ns for e in got] == [e.fit_end_ns for e in ref]
    for a, b in zip(got, ref):
        assert a.extra["accepted"] == b.extra["accepted"] and a.status == b.status
        np.testing.assert_array_equal(a.offset, b.offset)
        np.testing.assert_array_equal(a.tempoffset, b.tempoffset)


def test_online_boundaries_and_finish(rec, reference):
    cal, pub = reference
    t0 = int(rec.features.start_ns[0])
    ends = [e.fit_end_ns for e in pub]
    assert ends[:-1] == [t0 + k * 6 * H for k in range(1, 7)]
    last = pub[-1]  # finish(): everything, effective after the last window
    assert last.fit_end_ns == int(rec.features.start_ns[-1]) + 10**10
    assert last.windows == len(select_calibration_windows(rec.features).features)
    for e in pub:
        assert e.fit_start_ns == t0 and e.effective_from_ns == e.fit_end_ns
        assert e.extra["mode"] == "online"
        assert e.hours_used == pytest.approx((e.fit_end_ns - t0) / H)
    assert any(cal.current is e for e in pub) and cal.current.extra["accepted"]
    assert cal.finish() == []  # nothing new: no duplicate estimate


def test_online_gap_spanning_boundaries(rec):
    """A gap over several boundaries: one fit when data resumes, effective at the first
    boundary passed; the empty boundaries publish nothing."""
    f = rec.features
    keep = (f.start_ns < f.start_ns[0] + 7 * H) | (f.start_ns >= f.start_ns[0] + 26 * H)
    cal = OnlineCalibrator(chunk_hours=6)
    pub = cal.add(f.select(keep))
    t0 = int(f.start_ns[0])
    assert [e.fit_end_ns for e in pub] == [t0 + 6 * H, t0 + 12 * H, t0 + 30 * H, t0 + 36 * H]


def test_online_rejects_ggir_mode():
    with pytest.raises(ValueError):
        OnlineCalibrator(ggir_compatible=True)


def test_incremental_schedule_equals_batch(rec):
    """Streaming the windows through BatchSchedule (as `calibrate` does) gives the same estimate
    as fit_batch_schedule on the whole table."""
    f = rec.features
    batch = fit_batch_schedule(f, first_hours=12, chunk_hours=6)
    sel = select_calibration_windows(f).features
    sched = BatchSchedule(int(f.start_ns[0]), first_hours=12, chunk_hours=6)
    est = None
    for i in range(0, len(sel), 333):
        est = sched.add(sel.select(slice(i, i + 333)))
        if est is not None:
            break
    assert est is not None
    np.testing.assert_array_equal(est.offset, batch.offset)
    assert est.hours_used == batch.hours_used == 12.0
    assert est.extra["schedule"] == batch.extra["schedule"]


def test_reader_pass_stops_early_and_matches_features(rec):
    src = SyntheticSource(rec.features, rate_hz=10.0, windows_per_block=90)
    res = calibrate_source(src, first_hours=12, chunk_hours=6)
    assert not res.read_to_end and res.estimate.hours_used == pytest.approx(12.0)
    assert res.windows_total < len(rec.features) / 2  # stopped reading
    assert res.estimate.status == "ok" and res.estimate.device_key == "AX3-99999"
    full = calibrate_source(SyntheticSource(rec.features, rate_hz=10.0), first_hours=12,
                            chunk_hours=6, read_all=True)
    assert full.read_to_end and full.windows_total == len(rec.features)
    np.testing.assert_allclose(full.estimate.offset, res.estimate.offset, atol=1e-12)


def test_failed_iteration_is_identity(monkeypatch, rec):
    def broken(mean, temp, **kw):
        return IcpResult(np.full(3, np.nan), np.ones(3), np.zeros(3), 3, False, "parameters",
                         [], "non-finite parameters at iteration 3")

    monkeypatch.setattr(fitmod, "icp_sphere_fit", broken)
    est = fit_calibration(rec.features)
    assert est.status == "failed" and est.method == "identity"
    assert np.all(est.offset == 0) and "non-finite" in est.reason


def test_prior_with_temperature_term_and_no_temperature_now():
    """A stored C2 prior cannot be evaluated when the new data have no temperature: the first
    good fit (C1) replaces it instead of being rejected forever."""
    from stillpoint.engine.calibration import CalibrationEstimate

    truth = random_truth(np.random.default_rng(81), tempoffset_mg_per_c=0.0)
    rec = synthetic_recording(14, truth, seed=82, temperature="missing")
    prior = CalibrationEstimate(offset=[0.01, 0, 0], tempoffset=[1e-3, 0, 0], temperature_ref=25,
                                status="ok", method="autocal-c2")
    cal = OnlineCalibrator(prior=prior, chunk_hours=6)
    pub = cal.add(rec.features)
    assert pub[0].method == "autocal-c1" and pub[0].extra["accepted"]
    assert pub[0].extra["in_force_error_mg"] is None and cal.current is not prior


def test_warm_refits_equal_cold_refits_within_tolerance():
    """Refits started from the previous fit (extrapolated) publish the same estimates as fits from
    identity: same statuses and acceptance, parameters within a few times the 1e-9 tolerance, in
    far fewer passes over the windows."""
    from stillpoint.engine.calibration.fit import PARAM_TOL

    f = synthetic_recording(96, random_truth(np.random.default_rng(91)), seed=92).features
    runs = {}
    for warm in (True, False):
        cal = OnlineCalibrator(chunk_hours=12, warm_start=warm)
        pub = []
        for i in range(0, len(f), 997):
            pub += cal.add(f.select(slice(i, i + 997)))
        runs[warm] = pub + cal.finish()
    warm, cold = runs[True], runs[False]
    assert len(warm) == len(cold) == 8
    for a, b in zip(warm, cold):
        assert (a.status, a.extra["accepted"], a.windows) == (b.status, b.extra["accepted"], b.windows)
        for name in ("offset", "scale", "tempoffset"):
            np.testing.assert_allclose(getattr(a, name), getattr(b, name), rtol=0,
                                       atol=20 * PARAM_TOL)
        assert a.temperature_ref == b.temperature_ref
    assert all(e.extra.get("warm_start") for e in warm[1:]) and "warm_start" not in warm[0].extra
    assert all(b.iterations > 25 for b in cold)
    assert sum(a.iterations for a in warm[1:]) < sum(b.iterations for b in cold[1:]) / 5


def test_extrapolated_start_is_near_the_fixed_point():
    from stillpoint.engine.calibration import CalibrationEstimate
    from stillpoint.engine.calibration.refit import extrapolated_start

    f = synthetic_recording(48, random_truth(np.random.default_rng(93)), seed=94).features
    sel = select_calibration_windows(f).features
    half = sel.select(sel.start_ns < sel.start_ns[0] + 24 * H)
    prev = fit_calibration(half, select=False)
    cold = fit_calibration(sel, select=False)
    x = extrapolated_start(prev, sel)
    step_prev = np.max(np.abs(prev.offset - cold.offset))
    assert np.max(np.abs(x.offset - cold.offset)) < step_prev / 100
    assert extrapolated_start(CalibrationEstimate.identity(), sel) is None  # nothing to start from
