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


def _corrected(est, pts, temps):
    from stillpoint.engine.calibration.fit import apply_model
    tc = temps - est.temperature_ref if est.uses_temperature else None
    return apply_model(pts, tc, est.offset, est.scale, est.tempoffset)


def test_fit_set_keeps_the_first_windows_of_each_cell_whatever_the_cuts(rec):
    from stillpoint.engine.calibration.online import FIT_CELL_C, FIT_CELL_G
    f = rec.features
    sel = select_calibration_windows(f).features
    cal = OnlineCalibrator(chunk_hours=6, per_cell=3)
    cal.add(f)
    fit = cal.fit_windows
    assert 0 < len(fit) < len(sel) == len(cal.windows)
    # the rule, checked window by window: a window joins when its cell holds fewer than 3
    key = [tuple(np.floor(m / FIT_CELL_G).astype(int)) + (int(np.floor(t / FIT_CELL_C)),)
           for m, t in zip(sel.mean, sel.temperature)]
    seen: dict = {}
    expect = []
    for i, k in enumerate(key):
        if seen.get(k, 0) < 3:
            expect.append(i)
        seen[k] = seen.get(k, 0) + 1
    np.testing.assert_array_equal(fit.start_ns, sel.start_ns[expect])
    # cut anywhere: the same fit set and the same estimates, bit for bit
    for cuts in ([1, 2, 3, 5000], list(range(0, len(f), 977))):
        other = OnlineCalibrator(chunk_hours=6, per_cell=3)
        edges = [0, *cuts, len(f)]
        got = []
        for a, b in zip(edges[:-1], edges[1:]):
            got += other.add(f.select(slice(a, b)))
        np.testing.assert_array_equal(other.fit_windows.start_ns, fit.start_ns)
        for a, b in zip(got, cal.estimates):
            np.testing.assert_array_equal(a.offset, b.offset)
            assert a.extra["accepted"] == b.extra["accepted"]


def test_fit_set_refits_agree_with_every_window_and_the_final_fit_uses_every_window(rec):
    f = rec.features
    every = OnlineCalibrator(chunk_hours=6, per_cell=None)
    capped = OnlineCalibrator(chunk_hours=6, per_cell=2)
    a = every.add(f) + every.finish()
    b = capped.add(f) + capped.finish()
    assert [e.fit_end_ns for e in a] == [e.fit_end_ns for e in b]
    assert len(capped.fit_windows) < len(capped.windows)
    rng = np.random.default_rng(5)
    u = rng.normal(size=(500, 3))
    u /= np.linalg.norm(u, axis=1)[:, None]
    temps = rng.uniform(20, 32, 500)
    for x, y in zip(a[:-1], b[:-1]):  # boundary refits: on the fit set, within ~1 mg
        assert y.windows <= len(capped.fit_windows)
        assert y.extra["nonmovement_windows"] >= y.windows
        assert np.abs(_corrected(x, u, temps) - _corrected(y, u, temps)).max() < 2e-3
    # the end of stream fit: every window, the same fixed point within the fit's tolerance
    assert b[-1].windows == a[-1].windows == len(capped.windows)
    assert "nonmovement_windows" not in b[-1].extra
    assert np.abs(_corrected(a[-1], u, temps) - _corrected(b[-1], u, temps)).max() < 1e-6
    assert capped.finish() == []
    with pytest.raises(ValueError):
        OnlineCalibrator(per_cell=0)


def test_fit_set_stops_growing_on_still_wear(rec):
    """Days of the same few orientations (a device on a table, a resting wrist): the windows
    pile up, the fit set does not."""
    from dataclasses import replace

    f = select_calibration_windows(rec.features).features
    day = 24 * H
    span = int(f.start_ns[-1] - f.start_ns[0]) + 10**10
    cal = OnlineCalibrator(chunk_hours=12, per_cell=2)
    sizes = []
    for k in range(4):  # the same windows again, a span later each time (same cells)
        cal.add(replace(f, start_ns=f.start_ns + k * span))
        sizes.append((len(cal.windows), len(cal.fit_windows)))
    assert sizes[-1][0] == 4 * sizes[0][0] and span > day
    # after two passes every cell holds its 2: nothing more joins
    assert sizes[3][1] == sizes[2][1] == sizes[1][1] < sizes[-1][0] / 2
