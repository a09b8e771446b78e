"""Nonwear / clipping operator: GGIR's rule (2013 and 2023 forms) against a direct whole-array
implementation of the published rule, and results independent of block cuts."""

import math
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from stillpoint.engine.operators.binning import TimeBinner
from stillpoint.engine.operators.nonwear import (NonwearOperator, NonwearWindows, SubsampleBinner,
                                                 _bin_stats, clip_counts, clip_threshold_g,
                                                 subsample_rows)

RATE = 10.0  # low rate keeps the arrays small; the rule does not depend on the rate
T0 = 1_700_000_000 * 10**9 // (900 * 10**9) * (900 * 10**9) + 7 * 10**9  # 7 s after a window start


def signal(hours=8.0, seed=0):
    """Still periods (table: tiny noise; 'drawer': other orientation) between movement, one
    clipping burst, one gap that starts a new segment."""
    rng = np.random.default_rng(seed)
    n = int(hours * 3600 * RATE)
    t = T0 + (np.arange(n) * 1e9 / RATE).astype(np.int64)
    a = rng.normal(0, 0.2, (n, 3)) + [0, 0, 1]
    h = (t - T0) / 3.6e12
    still = ((h > 1.3) & (h < 3.1)) | ((h > 5.0) & (h < 6.2))
    a[still] = rng.normal(0, 0.002, (int(still.sum()), 3)) + [0, 1, 0]
    semi = (h > 6.6) & (h < 7.4)  # one axis moves: score 2 -> nonwear anyway
    a[semi, 0] = rng.normal(0, 0.002, int(semi.sum()))
    a[semi, 1] = rng.normal(0, 0.002, int(semi.sum()))
    clip = (h > 3.6) & (h < 3.75)
    a[clip, 0] = 8.0
    seg = np.where(h > 4.2, 1, 0)
    keep = ~((h > 4.2) & (h < 4.5))  # a 18-min gap
    return t[keep], a[keep], seg[keep]


def batches(t, a, seg, cuts):
    bounds = sorted(set([0, len(t)] + [c for c in cuts if 0 < c < len(t)]))
    segb = np.flatnonzero(np.diff(seg)) + 1
    bounds = sorted(set(bounds) | set(segb.tolist()))
    for i, j in zip(bounds[:-1], bounds[1:]):
        yield SimpleNamespace(time_ns=t[i:j], accel=a[i:j], segment=int(seg[i]))


def run(t, a, seg, cuts=(), **kw):
    op = NonwearOperator(RATE, **kw)
    out = [op.push(b) for b in batches(t, a, seg, cuts)]
    out.append(op.flush())
    return NonwearWindows.concat(out)


def reference(t, a, version, clip_g=7.5):
    """GGIR's loop written directly on whole arrays (windows on the 15-min clock grid)."""
    M = 900 * 10**9
    w_all = t // M
    first, last = int(w_all[0]), int(w_all[-1])
    nw = last - first + 1
    step = math.ceil(RATE / 5)
    half = t // (M // 2)
    pos = np.zeros(len(t), np.int64)  # position inside the half window (per contiguous run)
    starts = np.flatnonzero(np.r_[True, np.diff(half) != 0])
    for s, e in zip(starts, np.r_[starts[1:], len(t)]):
        pos[s:e] = np.arange(e - s)

    def still(sel):
        if sel.sum() < 2:
            return np.zeros(3, bool)
        x = a[sel]
        return (np.ptp(x, axis=0) < 0.05) & (np.std(x, axis=0, ddof=1) < 0.013)

    flags = np.zeros((nw, 3), bool)
    for k in range(nw):
        w = first + k
        if version == "2013":
            if k + 1 <= 3:
                lo, hi = first * M, (first + 4) * M
            elif k + 1 >= nw - 3:
                lo, hi = (last - 2) * M, (last + 1) * M
            else:
                lo, hi = w * M + M // 2 - 2 * M, w * M + M // 2 + 2 * M
            flags[k] |= still((t >= lo) & (t < hi))
        else:
            r = still((t >= w * M) & (t < (w + 4) * M) & (pos % step == 0))
            flags[k:k + 4] |= r
    score = flags.sum(axis=1)
    out = score.copy()
    for k in range(1, nw - 1):
        if score[k] == 1 and score[k - 1] > 1 and score[k + 1] > 1:
            out[k] = 2
    clipping = np.zeros(nw, bool)
    for k in range(nw):
        sel = w_all == first + k
        if sel.any():
            x = np.abs(a[sel])
            share = np.where((x > 1.5 * clip_g).any(axis=0), 1.0, (x > clip_g).mean(axis=0))
            clipping[k] = share.max() > 0.3
    return out, clipping


@pytest.mark.parametrize("version", ["2013", "2023"])
def test_matches_the_published_rule(version):
    t, a, seg = signal()
    got = run(t, a, seg, version=version)
    score, clipping = reference(t, a, version)
    assert len(got) == len(score)
    np.testing.assert_array_equal(got.score, score)
    np.testing.assert_array_equal(got.nonwear, score >= 2)
    np.testing.assert_array_equal(got.clipping, clipping)
    assert got.nonwear.sum() >= 3 and got.clipping.sum() >= 1  # the signal exercises the rule
    assert np.all(np.diff(got.start_ns) == 900 * 10**9)  # consecutive, gap windows included


def test_versions_differ_where_documented():
    """2023 flags the whole long window: its nonwear periods reach further than 2013's."""
    t, a, seg = signal()
    old, new = run(t, a, seg, version="2013"), run(t, a, seg, version="2023")
    assert new.nonwear.sum() > old.nonwear.sum()


@settings(max_examples=12, deadline=None)
@given(st.lists(st.integers(0, 8 * 36000), max_size=25), st.sampled_from(["2013", "2023"]))
def test_block_cut_invariance(cuts, version):
    t, a, seg = signal(seed=3)
    ref = run(t, a, seg, version=version)
    got = run(t, a, seg, cuts, version=version)
    for f in ("start_ns", "n", "score", "nonwear", "clipping"):
        np.testing.assert_array_equal(getattr(got, f), getattr(ref, f))
    np.testing.assert_array_equal(got.clip_share, ref.clip_share)


def test_memory_is_bounded():
    t, a, seg = signal(hours=12)
    op = NonwearOperator(RATE)
    peak = 0
    for b in batches(t, a, seg, list(range(0, len(t), 3000))):
        op.push(b)
        peak = max(peak, len(op._half))
    assert peak <= 24  # a few long windows of half windows, not the recording


def test_clip_threshold():
    assert clip_threshold_g(8) == 7.5 and clip_threshold_g(16) == 15.5 and clip_threshold_g(None) == 7.5


def _bins(draw_counts):
    cnt = np.array(draw_counts, np.int64)
    return np.concatenate([[0], np.cumsum(cnt)[:-1]]).astype(np.int64), cnt


@settings(max_examples=200, deadline=None)
@given(st.lists(st.integers(1, 60), min_size=1, max_size=8), st.integers(1, 25))
def test_subsample_rows_are_every_step_th_sample_of_each_bin(counts, step):
    st_, cnt = _bins(counts)
    rows, sub_st, sub_cnt = subsample_rows(st_, cnt, step)
    pos = np.arange(cnt.sum()) - np.repeat(st_, cnt)  # position within the bin
    keep = pos % step == 0
    np.testing.assert_array_equal(rows, np.flatnonzero(keep))
    np.testing.assert_array_equal(sub_cnt, np.add.reduceat(keep.astype(np.int64), st_))
    np.testing.assert_array_equal(sub_st, np.concatenate([[0], np.cumsum(sub_cnt)[:-1]]))


@settings(max_examples=200, deadline=None)
@given(st.lists(st.integers(1, 40), min_size=1, max_size=6), st.integers(0, 2**32 - 1),
       st.sampled_from([0.0, 0.3, 1.0]), st.booleans())
def test_clip_counts_match_the_per_sample_rule(counts, seed, beyond, nan):
    """Counts and hard flags as per-sample comparisons give them: samples at the threshold, just
    beyond it (either sign), beyond 1.5 x, and NaN."""
    clip_g = 7.5
    st_, cnt = _bins(counts)
    rng = np.random.default_rng(seed)
    n = int(cnt.sum())
    a = rng.normal(0, 2, (n, 3))
    pick = rng.random((n, 3))
    a[pick < 0.1] = clip_g  # at the threshold: not clipping
    a[pick > 1 - 0.1 * beyond] = -np.nextafter(clip_g, np.inf)
    a[pick > 1 - 0.02 * beyond] = 1.6 * clip_g
    if nan:
        a[rng.integers(n), rng.integers(3)] = np.nan
    for arr in (a, np.asfortranarray(a)):
        over, hard = clip_counts(arr, st_, clip_g)
        np.testing.assert_array_equal(over, np.add.reduceat((np.abs(a) > clip_g).astype(np.int64), st_, axis=0))
        np.testing.assert_array_equal(hard, np.logical_or.reduceat(np.abs(a) > 1.5 * clip_g, st_, axis=0))
        assert over.dtype == np.int64 and hard.dtype == bool


def _half_windows(parts):
    """[(bin, n, count, mean, m2, lo, hi, clip, hard)] of reduced half windows, in order."""
    return [(int(b), int(p.n[i]), p.still[i].n, p.still[i].mean.tolist(), p.still[i].m2.tolist(),
             p.still[i].lo.tolist(), p.still[i].hi.tolist(), p.clip[i].tolist(), p.hard[i].tolist())
            for p in parts for i, b in enumerate(p.bins)]


@settings(max_examples=25, deadline=None)
@given(st.lists(st.integers(0, 20_000), max_size=20), st.integers(0, 2**32 - 1), st.sampled_from([1, 3, 20]))
def test_subsample_binner_matches_whole_half_windows(cuts, seed, step):
    """The 2023 form's half windows, reduced block by block, equal to the bit those of the whole
    half windows (gathered by TimeBinner) whatever the block cuts, across a segment break and
    with clipping samples."""
    rng = np.random.default_rng(seed)
    n, width_s, brk = 20_000, 60.0, 11_111
    t = (T0 + np.arange(n) * 50_000_000).astype(np.int64)
    t[brk:] += 7 * 10**9
    a = np.asfortranarray(rng.normal(0, 0.5, (n, 3)) + [0, 0, 1])
    a[rng.integers(0, n, 30), rng.integers(0, 3, 30)] = rng.choice([7.6, -9.0, 12.0], 30)
    bounds = sorted(set([0, brk, n] + cuts))
    ref_binner, got_binner = TimeBinner(width_s, {"accel": (np.float64, (3,))}, align="clock"), \
        SubsampleBinner(width_s, step, 7.5)
    chunks, got = [], []
    for i, j in zip(bounds[:-1], bounds[1:]):
        seg = int(i >= brk)
        chunks += ref_binner.push(seg, t[i:j], accel=a[i:j])
        got += got_binner.push(seg, t[i:j], accel=a[i:j])
    chunks += ref_binner.flush()
    got += got_binner.flush()
    ref = []
    for ch in chunks:
        x, cnt = ch.cols["accel"], ch.counts
        rows, sub_st, sub_cnt = subsample_rows(ch.starts, cnt, step)
        clip = np.add.reduceat((np.abs(x) > 7.5).astype(np.int64), ch.starts, axis=0)
        hard = np.logical_or.reduceat(np.abs(x) > 11.25, ch.starts, axis=0)
        ref.append(SimpleNamespace(bins=ch.bins, n=cnt, still=_bin_stats(x[rows], sub_st, sub_cnt),
                                   clip=clip, hard=hard))
    assert _half_windows(got) == _half_windows(ref)
