"""Core engine tests: ring buffer, time binner, window features, nonmovement selection (on the
synthetic Blocks of synthetic_blocks.py)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, given, settings, strategies as st

from stillpoint.engine.features import WindowFeatures
from stillpoint.engine.operators.nonmovement import NonmovementOperator
from stillpoint.engine.operators.windows import WindowFeaturesOperator
from stillpoint.engine.core.ringbuffer import RingBuffer

from synthetic_blocks import RATE, assert_features_equal, recut, run_op, synth_segments

# ---------------------------------------------------------------------- ring buffer
def test_ringbuffer_wraps_and_keeps_absolute_index():
    r = RingBuffer(10, time=(np.int64, ()), v=(np.float64, (3,)))
    r.append(time=np.arange(7), v=np.arange(21.0).reshape(7, 3))
    r.consume(5)
    assert (r.start, r.end, len(r)) == (5, 7, 2)
    r.append(time=np.arange(7, 15), v=np.arange(21.0, 45.0).reshape(8, 3))
    assert len(r) == 10 and r.free == 0
    v = r.view(6, 14)
    assert np.array_equal(v["time"], np.arange(6, 14))
    assert np.array_equal(v["v"][:, 0], np.arange(6, 14) * 3.0)
    with pytest.raises(BufferError):
        r.append(time=np.arange(1), v=np.zeros((1, 3)))
    with pytest.raises(IndexError):
        r.view(2, 6)


def test_ringbuffer_view_is_a_view_when_contiguous():
    r = RingBuffer(8, x=(np.float64, ()))
    r.append(x=np.arange(5.0))
    v = r.view(1, 4)["x"]
    assert np.shares_memory(v, r._data["x"])


@settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(0, 9), min_size=1, max_size=40), st.integers(0, 9))
def test_ringbuffer_matches_a_list(chunks, keep):
    r = RingBuffer(10, x=(np.int64, ()))
    ref = []
    nxt = 0
    for c in chunks:
        c = min(c, r.free)
        r.append(x=np.arange(nxt, nxt + c))
        ref += list(range(nxt, nxt + c))
        nxt += c
        r.consume(max(r.start, r.end - keep))
        ref = ref[len(ref) - len(r):] if len(r) else []
        assert list(r.view()["x"]) == ref


# ---------------------------------------------------------------------- window features
def test_window_features_match_direct_computation():
    blocks = synth_segments()
    op = WindowFeaturesOperator(RATE, min_fill=0)
    f = WindowFeatures.concat(run_op(op, recut(blocks, "unit")))
    # reference: numpy on each segment, windows by time from the segment start
    rows = []
    for b in blocks:
        g = b.accel_g()
        temp = b.temperature_per_sample()
        w = (b.time_ns - b.time_ns[0]) // 10**10
        for k in np.unique(w):
            s = w == k
            rows.append((b.time_ns[0] + k * 10**10, s.sum(), g[s].mean(0), g[s].std(0, ddof=1),
                         temp[s].mean(), np.linalg.norm(g[s], axis=1).mean(), b.segment))
    assert len(f) == len(rows)
    assert np.array_equal(f.start_ns, [r[0] for r in rows])
    assert np.array_equal(f.n, [r[1] for r in rows])
    assert np.allclose(f.mean, [r[2] for r in rows], rtol=0, atol=1e-12)
    assert np.allclose(f.sd, [r[3] for r in rows], rtol=0, atol=1e-12)
    assert np.allclose(f.temperature, [r[4] for r in rows], atol=1e-9)
    assert np.allclose(f.norm_mean, [r[5] for r in rows], atol=1e-12)
    assert np.array_equal(f.segment, [r[6] for r in rows])
    # windows never span a segment: every window's samples lie within its segment's time range
    for b in blocks:
        sel = f.segment == b.segment
        assert f.start_ns[sel][0] == b.time_ns[0]
        assert np.all(f.start_ns[sel] <= b.time_ns[-1])


def test_window_fill_rule_drops_short_tails():
    blocks = synth_segments(seconds=(95.0,))
    f_all = WindowFeatures.concat(run_op(WindowFeaturesOperator(RATE, min_fill=0), blocks))
    f = WindowFeatures.concat(run_op(WindowFeaturesOperator(RATE), blocks))
    assert len(f_all) == 10 and f_all.n[-1] < 900
    assert len(f) == 9 and np.all(f.n >= 900)


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 10_000))
def test_window_features_independent_of_block_cuts(seed):
    blocks = synth_segments(seed=seed % 7)
    ref = WindowFeatures.concat(run_op(WindowFeaturesOperator(RATE), recut(blocks, "whole")))
    assert len(ref) > 5
    for how in ("unit", "random"):
        f = WindowFeatures.concat(run_op(WindowFeaturesOperator(RATE), recut(blocks, how, seed)))
        assert_features_equal(f, ref)


@settings(max_examples=15, deadline=None)
@given(st.integers(0, 10_000))
def test_window_norm_for_a_subset_is_the_full_norm(seed):
    """norm_for: the mean norm of the wanted windows is that of the full computation (bit for
    bit), NaN elsewhere; every other column is unchanged; independent of block cuts."""
    blocks = synth_segments(seed=seed % 7)
    ref = WindowFeatures.concat(run_op(WindowFeaturesOperator(RATE), recut(blocks, "whole")))
    for how in ("whole", "unit", "random"):
        f = WindowFeatures.concat(run_op(WindowFeaturesOperator(RATE, norm_for=lambda m, s: (
            (m[:, 0].view(np.int64) + seed) % 3 != 0)), recut(blocks, how, seed)))
        want = (ref.mean[:, 0].view(np.int64) + seed) % 3 != 0  # a pattern of the mean's bits
        assume(want.any() and not want.all())
        assert np.array_equal(f.norm_mean[want], ref.norm_mean[want])
        assert np.all(np.isnan(f.norm_mean[~want]))
        for name in ("start_ns", "n", "mean", "sd", "temperature", "segment"):
            assert np.array_equal(getattr(f, name), getattr(ref, name), equal_nan=True), name


def test_window_features_non_integer_rate():
    rate = 600 / 7  # GENEActiv 85.7 Hz
    blocks = synth_segments(rate=rate, unit=300, seconds=(61.0,))
    f = WindowFeatures.concat(run_op(WindowFeaturesOperator(rate, min_fill=0), recut(blocks, "random")))
    # 10 s at 85.714 Hz is 857 or 858 samples, never a fixed count
    assert set(f.n[:-1].tolist()) <= {857, 858}
    assert f.n.sum() == blocks[0].n


# ---------------------------------------------------------------------- nonmovement
def _features_for_nonmovement():
    k = 12
    mean = np.tile([0.0, 0.0, 1.0], (k, 1)) + np.arange(k)[:, None] * 1e-3
    sd = np.full((k, 3), 0.005)
    sd[3] = [0.005, 0.02, 0.005]  # moving
    mean[5] = mean[4]  # repeat of the previous window
    mean[6] = [2.5, 0, 0]  # clipped
    mean[8] = mean[7]
    mean[9] = mean[7]
    return WindowFeatures.from_arrays(mean, sd, np.full(k, 25.0))


def test_nonmovement_selection_rules():
    f = _features_for_nonmovement()
    op = NonmovementOperator()
    sel = op.push(f)
    assert op.windows_in == 12 and op.repeats_dropped == 3
    assert sel.start_ns.tolist() == [w * 10**10 for w in (0, 1, 2, 4, 7, 10, 11)]
    op2 = NonmovementOperator(sd_threshold=0.03)
    assert 3 * 10**10 in op2.push(f).start_ns


@settings(max_examples=30, deadline=None)
@given(st.lists(st.integers(1, 11), max_size=5))
def test_nonmovement_independent_of_cuts(cuts):
    f = _features_for_nonmovement()
    ref = NonmovementOperator()
    ref.push(f)
    op = NonmovementOperator()
    edges = [0] + sorted(set(cuts)) + [len(f)]
    for a, b in zip(edges[:-1], edges[1:]):
        op.push(f.select(slice(a, b)))
    assert_features_equal(op.selected, ref.selected)
