"""End-to-end alignment accuracy on synthetic device pairs with known clocks (CI-sized: 1.5-2.5
days at 20 Hz; the full 7-day, 20-seed table is tools/crosschecks/align_seeds.py)."""

from __future__ import annotations

import numpy as np
import pytest

from stillpoint.engine.alignment import AlignConfig, estimate_alignment
from synthetic_alignment import DeviceClock, SyntheticPair

RATE = 30.0


def _pair(seed, days, **kw):
    rng = np.random.default_rng(1000 + seed)
    kw.setdefault("clock_ref", DeviceClock(offset_s=0.0, skew_ppm=float(rng.uniform(-50, 50))))
    kw.setdefault("clock_other", DeviceClock(offset_s=float(rng.uniform(-10, 10)),
                                             skew_ppm=float(rng.uniform(-50, 50))))
    return SyntheticPair(seed=seed, duration_s=days * 86400, rate_ref=20, rate_other=20, **kw)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_linear_clocks_offset_within_one_sample_and_day7_within_0p1s(seed):
    pair = _pair(seed, 1.5)
    res = estimate_alignment(pair.source(0), pair.source(1), AlignConfig(method="robust"))
    assert res.ok, res.reason
    truth = pair.truth()
    fit = res.fit
    # the crystals' temperature term is in the model whenever the devices' temperatures vary
    assert fit.model in ("linear", "linear+temperature")
    assert abs(fit.initial_offset_s - truth["initial_offset_s"]) < 1 / RATE
    assert abs(fit.drift_day7_s - truth["drift_day7_s"]) < 0.1
    lo, hi = fit.ci()["initial_offset_s"]
    assert hi - lo < 0.05


def test_sampling_halt_detected_located_and_day7_kept_where_linear_fails():
    halt_at, halt_s = 1.2 * 86400, 150.0
    pair = _pair(7, 1.8, clock_other=DeviceClock(offset_s=3.0, skew_ppm=20, halt_at_s=halt_at,
                                                  halt_s=halt_s))
    truth = pair.truth()
    robust = estimate_alignment(pair.source(0), pair.source(1), AlignConfig(method="robust"))
    assert robust.ok and robust.fit.model.startswith("piecewise")
    [step] = robust.fit.steps
    # the halt starts at true time halt_at; on the reference clock that is:
    t_ref = float(pair.clock(0, halt_at) - pair.first_sample_clock(0))
    assert step.window_s[0] <= t_ref <= step.window_s[1] + 1.0
    assert step.window_s[1] - step.window_s[0] <= 3600.0
    assert abs(step.size / RATE + halt_s) < 0.1
    assert abs(robust.fit.drift_day7_s - truth["drift_day7_s"]) < 0.5
    brond = estimate_alignment(pair.source(0), pair.source(1),
                               AlignConfig(method="brond", max_lag_s=300.0))
    assert brond.ok and abs(brond.fit.drift_day7_s - truth["drift_day7_s"]) > 0.5


def test_temperature_dependent_crystals_robust_beats_linear_on_held_out_blocks():
    pair = _pair(11, 2.0, clock_ref=DeviceClock(skew_ppm=5, temp_ppm_per_c2=-0.035),
                 clock_other=DeviceClock(offset_s=1.1, skew_ppm=-20, temp_ppm_per_c2=-0.035))
    res = estimate_alignment(pair.source(0), pair.source(1), AlignConfig(method="robust"))
    assert res.ok and res.fit.model == "linear+temperature"
    d = res.fit.diagnostics["temperature"]
    assert d["heldout_rmse_with"] < 0.5 * d["heldout_rmse_without"]
    # and the model follows the true offset better than a line between the blocks
    t = np.linspace(0, 1.9 * 86400, 50)
    err = np.abs(res.fit.offset_s(t) - pair.truth_offset_s(t))
    assert err.max() < 2 / RATE


def test_sedentary_recording_reports_too_few_blocks():
    pair = _pair(21, 1.0, active_fraction=0.01)
    for method in ("brond", "robust"):
        res = estimate_alignment(pair.source(0), pair.source(1), AlignConfig(method=method))
        assert not res.ok and res.fit is None
        assert res.reason.startswith("too few blocks") and "inactive" in res.reason
        d = res.as_dict()
        assert d["aligned"] is False and d["initial_offset_s"] is None


def test_recordings_that_do_not_overlap():
    a = _pair(22, 0.3)
    b = SyntheticPair(seed=22, duration_s=0.3 * 86400, rate_ref=20, rate_other=20,
                      clock_other=DeviceClock(offset_s=-2 * 86400.0))
    res = estimate_alignment(a.source(0), b.source(1), AlignConfig())
    assert not res.ok and "do not overlap" in res.reason


def test_recordings_months_apart_are_refused_without_filling_the_gap():
    """Two short recordings 60 days apart (either one first): the streams are read merged by
    time and nothing is kept past the usable span, so the answer comes at once instead of after
    NaN-filling two months of grid (which grew without bound and took hours)."""
    import threading
    a = SyntheticPair(seed=23, duration_s=1800, rate_ref=20, rate_other=20)
    b = SyntheticPair(seed=23, duration_s=1800, rate_ref=20, rate_other=20,
                      clock_other=DeviceClock(offset_s=60 * 86400.0))
    for ref, oth in ((a.source(0), b.source(1)), (b.source(1), a.source(0))):
        got = {}
        t = threading.Thread(target=lambda: got.update(res=estimate_alignment(ref, oth, AlignConfig())),
                             daemon=True)
        t.start()
        t.join(120)
        assert not t.is_alive(), "the alignment filled the gap between the recordings"
        assert not got["res"].ok and "do not overlap" in got["res"].reason


def test_a_gap_of_months_inside_both_recordings_costs_nothing():
    """Both recordings stop and start again 90 days later (a clock that jumped): the grid across
    the gap is never stored (it was filled with NaN: gigabytes, hours); each gap block is a
    "no_overlap" block, settled without its arrays."""
    import threading

    from stillpoint.engine.core.blocks import Block, DeviceInfo

    class Source:
        def __init__(self, seed):
            rng = np.random.default_rng(seed)
            self.info = DeviceInfo("AX3", str(seed), 1, "t", 20.0, 8.0)
            self.parts = []
            for seg, start in enumerate((0, 90 * 86400)):
                t = start + np.arange(0, 1800, 0.05)
                a = np.zeros((t.size, 3), np.int64)
                a[:, 2] = 256 + rng.integers(-30, 30, t.size)
                self.parts.append(Block(time_ns=(t * 1e9).astype(np.int64), accel=a,
                                        accel_counts_per_g=np.full(3, 256.0),
                                        accel_zero=np.zeros(3), segment=seg))

        def __iter__(self):
            return iter(self.parts)

    got = {}
    t = threading.Thread(target=lambda: got.update(res=estimate_alignment(Source(1), Source(2),
                                                                          AlignConfig())),
                         daemon=True)
    t.start()
    t.join(120)
    assert not t.is_alive(), "the alignment stored the grid across the gap"
    res = got["res"]
    assert not res.ok and len(res.blocks) > 12_000  # 90 days of 10-minute blocks
    assert sum(b.reason == "no_overlap" for b in res.blocks) > 12_000


def test_grid_buffer_stores_no_gap():
    from stillpoint.engine.alignment.lags import _GridBuffer
    b = _GridBuffer(0)
    b.append(0, np.arange(5.0))
    b.append(10**12, np.array([7.0, 8.0]))  # after a gap of ~1,000 years at 30 Hz: nothing stored
    assert b.k_end == 10**12 + 2 and sum(v.size for _a, v in b._pieces) == 7
    assert not b.has_data(5, 10**12) and b.has_data(4, 6)
    assert np.array_equal(b.get(3, 7), [3.0, 4.0, np.nan, np.nan], equal_nan=True)
    assert np.array_equal(b.get(10**12 - 1, 10**12 + 1), [np.nan, 7.0], equal_nan=True)
    b.trim(10**12 + 1)
    assert b.k_start == 10**12 + 1 and np.array_equal(b.get(10**12, 10**12 + 2), [np.nan, 8.0],
                                                      equal_nan=True)


def test_lag_estimator_keeps_nothing_past_the_usable_span():
    from stillpoint.engine.alignment.lags import LagEstimator
    est = LagEstimator(RATE, 600.0, 300)
    rng = np.random.default_rng(5)
    est.feed("ref", 0, rng.normal(size=int(RATE * 900)))
    est.finish("ref")
    end = est.ref.k_end
    reach = end + est.P + est.M
    est.feed("other", reach + 10 * est.B, rng.normal(size=1000))  # far past the reference
    assert est.other.k_end <= reach
    est.feed("other", end, rng.normal(size=3 * est.B))  # straddling the end: cut at reach
    assert est.other.k_end == reach


def test_online_estimates_converge_to_the_batch_estimate():
    pair = _pair(4, 1.5)
    seen = []
    res = estimate_alignment(pair.source(0), pair.source(1), AlignConfig(method="robust"),
                             on_estimate=lambda fit, bl: seen.append((bl.index, fit)))
    assert len(seen) >= 4
    idx = [i for i, _ in seen]
    assert idx == sorted(idx)
    last = seen[-1][1]
    assert abs(last.initial_offset_s - res.fit.initial_offset_s) < 1 / RATE
    truth = pair.truth()
    assert abs(seen[-1][1].drift_day7_s - truth["drift_day7_s"]) < 0.2


def test_brond_method_reproduces_the_paper_on_linear_clocks():
    pair = _pair(5, 1.5, clock_other=DeviceClock(offset_s=2.0, skew_ppm=15))
    res = estimate_alignment(pair.source(0), pair.source(1), AlignConfig(method="brond"))
    assert res.ok and res.fit.method == "brond"
    lags = [b.lag for b in res.blocks if b.valid]
    assert all(float(x).is_integer() for x in lags)  # integer lags at 30 Hz, as the paper
    assert res.fit.thresholds[0] == 1.0
    truth = pair.truth()
    # block start as the lag's time biases the offset by drift x 30 min (documented)
    bias = truth["drift_day7_s"] / 7 / 48
    assert abs(res.fit.initial_offset_s - truth["initial_offset_s"] - bias) < 3 / RATE
    assert abs(res.fit.drift_day7_s - truth["drift_day7_s"]) < 1.0
