"""Alignment signal and per-block lags: grid resampling, filter, normalised cross-correlation,
and invariance of the streaming estimator to how the input is cut."""

from __future__ import annotations

import numpy as np
import pytest

from stillpoint.engine.alignment.lags import LagEstimator, normalized_xcorr, peak_lag
from stillpoint.engine.alignment.signal import (DEAD_BAND_G, GridResampler, TemperatureTrack,
                                                brond_filter)
from synthetic_alignment import DeviceClock, SyntheticPair
from stillpoint.engine.core.blocks import Block


def _block(t_s, mag, t0_ns=0, segment=0):
    """Block with ‖a‖ = 1 + mag along x (counts 1/4096 g so quantisation is negligible)."""
    counts = np.zeros((t_s.size, 3), np.int64)
    counts[:, 0] = np.round((1.0 + mag) * 4096)
    return Block(time_ns=t0_ns + np.round(t_s * 1e9).astype(np.int64), accel=counts,
                 accel_counts_per_g=np.full(3, 4096.0), accel_zero=np.zeros(3), segment=segment)


def _collect(gr, blocks):
    out = {}
    for b in blocks:
        for k0, v in gr.push(b):
            for i, x in enumerate(v):
                assert k0 + i not in out
                out[k0 + i] = x
    ks = np.array(sorted(out))
    return ks, np.array([out[k] for k in ks])


def test_grid_resampler_matches_interpolation_and_is_cut_invariant():
    rng = np.random.default_rng(1)
    t = np.arange(0, 200, 0.01) + 0.003
    mag = np.sin(2 * np.pi * 0.7 * t) * 0.3
    whole = _collect(GridResampler(0, 30.0, 100.0), [_block(t, mag)])
    cuts = np.sort(rng.choice(np.arange(1, t.size), 40, replace=False))
    parts = [_block(t[a:b], mag[a:b]) for a, b in zip(np.r_[0, cuts], np.r_[cuts, t.size])]
    pieces = _collect(GridResampler(0, 30.0, 100.0), parts)
    np.testing.assert_array_equal(whole[0], pieces[0])
    np.testing.assert_allclose(whole[1], pieces[1], atol=1e-12)
    k, v = whole
    assert k[0] == 1 and k[-1] == int(np.floor(t[-1] * 30))  # first grid point after t[0]
    expect = np.interp(k / 30.0, t, np.round((1 + mag) * 4096) / 4096 - 1)
    np.testing.assert_allclose(v, expect, atol=1e-9)


def test_grid_resampler_leaves_gaps_and_segment_breaks_nan():
    t1 = np.arange(0, 10, 0.01)
    t2 = np.arange(15, 20, 0.01)  # 5 s gap inside one block
    t = np.r_[t1, t2]
    k, v = _collect(GridResampler(0, 30.0, 100.0), [_block(t, np.full(t.size, 0.2))])
    tk = k / 30.0
    gap = (tk > t1[-1]) & (tk < 15)
    assert np.isnan(v[gap]).all() and gap.sum() > 140
    assert np.isfinite(v[~gap]).all()
    # a segment change between blocks: no interpolation across, even if the times are close
    b1 = _block(np.arange(0, 5, 0.01), np.full(500, 0.1), segment=0)
    b2 = _block(np.arange(5.5, 8, 0.01), np.full(250, 0.1), segment=1)
    k, v = _collect(GridResampler(0, 30.0, 100.0), [b1, b2])
    between = (k / 30.0 > 4.99) & (k / 30.0 < 5.5)
    assert np.isnan(v[between]).all() and between.any()


def test_grid_resampler_drops_non_increasing_times():
    t = np.r_[np.arange(0, 5, 0.01), np.arange(4, 6, 0.01)]
    gr = GridResampler(0, 30.0, 100.0)
    k, v = _collect(gr, [_block(t, np.zeros(t.size))])
    assert gr.samples_dropped == 100
    assert np.all(np.diff(k) == 1)


def test_brond_filter_dead_band_and_band_pass():
    rate = 30.0
    t = np.arange(0, 600, 1 / rate)
    small = 0.9 * DEAD_BAND_G * np.sin(2 * np.pi * 2 * t)
    assert not brond_filter(small, rate).any()  # all inside the dead band
    big = 0.5 * np.sin(2 * np.pi * 2 * t)
    y = brond_filter(big, rate)
    assert (y >= 0).all()
    mid = slice(1800, -1800)
    # 2 Hz passes nearly unchanged (zero phase): |y| follows |x| outside the dead band
    np.testing.assert_allclose(y[mid].max(), 0.5, rtol=0.05)
    slow = 0.5 * np.sin(2 * np.pi * 0.01 * t)  # below the 0.1 Hz corner
    assert brond_filter(slow, rate, dead_band=0.0)[mid].max() < 0.02
    fast = 0.5 * np.sin(2 * np.pi * 12 * t)  # above 7 Hz
    assert brond_filter(fast, rate, dead_band=0.0)[mid].max() < 0.05
    np.testing.assert_array_equal(brond_filter(np.full(100, np.nan), rate), 0)


def _brute_coeff(r, o_ext, M):
    out = []
    for k in range(-M, M + 1):
        seg = o_ext[M + k:M + k + r.size]
        out.append(np.dot(r, seg) / np.sqrt(np.dot(r, r) * np.dot(seg, seg)))
    return np.array(out)


def test_normalized_xcorr_against_brute_force_and_known_shift():
    rng = np.random.default_rng(3)
    x = np.abs(rng.normal(size=3000))
    M, shift = 40, 17
    r = x[M:M + 2000]
    o_ext = np.roll(x, shift)[:2000 + 2 * M]  # other lags the reference by +17 samples
    c = normalized_xcorr(r, o_ext, M, centred=False)
    np.testing.assert_allclose(c, _brute_coeff(r, o_ext, M), rtol=1e-9, atol=1e-12)
    lag, peak, edge = peak_lag(normalized_xcorr(r, o_ext, M, centred=True), M, subsample=False)
    assert lag == shift and not edge and peak > 0.99


@pytest.mark.parametrize("frac", [-0.4, -0.2, 0.0, 0.25, 0.45])
def test_subsample_lag_of_a_smooth_signal(frac):
    rate = 30.0
    t = np.arange(0, 600, 1 / rate)
    f = lambda tt: np.abs(np.sin(2 * np.pi * 0.37 * tt) * np.sin(2 * np.pi * 0.053 * tt + 1)) \
        + 0.3 * np.sin(2 * np.pi * 0.011 * tt) ** 2  # noqa: E731
    M, true = 60, 12 + frac
    r = f(t[M:-M])
    o_ext = f(t - true / rate)[: r.size + 2 * M]
    lag, peak, edge = peak_lag(normalized_xcorr(r, o_ext, M), M)
    assert abs(lag - true) < 0.1 and not edge


def test_peak_at_search_limit_is_flagged():
    c = np.linspace(0, 1, 21)
    lag, _, edge = peak_lag(c, 10)
    assert edge and lag == 10


def _lags(pair, cut_seed=None):
    est = LagEstimator(rate=30.0, block_s=3600.0, max_lag=300)
    t0 = int(next(iter(pair.blocks(0))).time_ns[0])
    grs = {"ref": GridResampler(t0, 30.0, pair.rate_ref),
           "other": GridResampler(t0, 30.0, pair.rate_other)}
    rng = np.random.default_rng(cut_seed)
    out = []
    for which, site in (("ref", 0), ("other", 1)):  # one stream entirely, then the other
        for b in pair.blocks(site):
            parts = [b]
            if cut_seed is not None:
                cuts = np.sort(rng.choice(np.arange(1, b.n), 5, replace=False))
                parts = [b.slice(a, c) for a, c in zip(np.r_[0, cuts], np.r_[cuts, b.n])]
            for p in parts:
                for k0, v in grs[which].push(p):
                    out += est.feed(which, k0, v)
        out += est.finish(which)
    return out


def test_lag_estimator_does_not_depend_on_cuts_or_interleaving():
    pair = SyntheticPair(seed=5, duration_s=6 * 3600, rate_ref=25, rate_other=25,
                         clock_other=DeviceClock(offset_s=1.2, skew_ppm=30), active_fraction=0.6)
    a = _lags(pair)
    b = _lags(pair, cut_seed=9)
    assert len(a) == len(b) >= 6
    for x, y in zip(a, b):
        assert x.valid == y.valid and x.reason == y.reason
        if x.valid:
            assert abs(x.lag - y.lag) < 1e-6
    valid = [x for x in a if x.valid]
    assert len(valid) >= 3
    for x in valid:  # and the lags are right
        assert abs(x.lag / 30.0 - pair.truth_offset_s(x.centroid_s)) < 1.5 / 30


def test_temperature_track_bins_and_fills():
    tr = TemperatureTrack(bin_s=60.0)
    tr.push(np.array([0.0, 30.0, 65.0, 300.0]), np.array([20.0, 22.0, 25.0, np.nan]))
    s = tr.series(0, 4)
    np.testing.assert_allclose(s, [21.0, 25.0, 25.0, 25.0])
    assert np.isnan(TemperatureTrack().series(0, 3)).all()


def test_magnitude_columns_equal_the_broadcast_form():
    """The column-by-column |a| - 1 gives the numbers of the (n, 3) einsum form (AX scale and
    a GENEActiv-like per-axis gain and offset)."""
    from stillpoint.engine.alignment.signal import magnitude_minus_one
    from stillpoint.engine.core.blocks import Block

    rng = np.random.default_rng(5)
    for cpg, zero in (([256.0] * 3, [0.0] * 3), ([312.7, 315.9, 309.6], [3.1, -2.2, 0.7])):
        acc = rng.integers(-2048, 2048, (5000, 3)).astype(np.int16)
        b = Block(time_ns=np.arange(5000, dtype=np.int64), accel=acc,
                  accel_counts_per_g=np.array(cpg), accel_zero=np.array(zero))
        a = b.accel_g()
        np.testing.assert_allclose(magnitude_minus_one(b), np.sqrt(np.einsum("ij,ij->i", a, a)) - 1.0,
                                   rtol=0, atol=1e-15)
