"""The alignment's filter and correlation without ``scipy.signal`` give scipy's numbers.

Exactly, except where scipy's result goes through LAPACK: ``sosfilt_zi`` solves a small linear
system, so its last bits depend on the machine's LAPACK (6e-15 apart on two machines). The
30 Hz band-pass stores those conditions as scipy computed them once; against the local LAPACK they
are compared to a rounding-level tolerance, and the filter run with them must stay within the same
rounding scaled by the filter's gain. Every rate whose conditions are computed locally is compared
bit for bit."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

from stillpoint.engine.alignment import filtering
from stillpoint.engine.alignment.signal import BAND_HZ, BUTTER_ORDER, COMMON_RATE_HZ

# sosfilt_zi's linear solve differs between LAPACK builds by a few ulps of its largest value
# (6e-15 measured); 1e-12 leaves room for that and for the filter's gain, and is still a million
# times smaller than any difference a wrong design or wrong conditions would make.
_LAPACK_ROUNDING = 1e-12


def test_stored_band_pass_is_scipys_design():
    sos = filtering.band_pass_sos(COMMON_RATE_HZ, BUTTER_ORDER, BAND_HZ)
    ref = signal.butter(BUTTER_ORDER, BAND_HZ, btype="bandpass", fs=COMMON_RATE_HZ, output="sos")
    assert np.array_equal(sos, ref)
    zi, ref_zi = filtering._steady_state(sos), signal.sosfilt_zi(ref)
    assert np.allclose(zi, ref_zi, rtol=0, atol=_LAPACK_ROUNDING * np.abs(ref_zi).max())


@pytest.mark.parametrize("rate", [COMMON_RATE_HZ, 25.0])
@pytest.mark.parametrize("n", [28, 29, 100, 4001])
def test_sosfiltfilt_bit_identical(rate, n):
    rng = np.random.default_rng(n)
    sos = filtering.band_pass_sos(rate, BUTTER_ORDER, BAND_HZ)
    x = rng.normal(size=n) * (rng.random(n) > 0.3)
    ours, ref = filtering.sosfiltfilt(sos, x), signal.sosfiltfilt(sos, x)
    if rate == COMMON_RATE_HZ:  # stored conditions: the local LAPACK's rounding may differ
        assert np.allclose(ours, ref, rtol=0, atol=_LAPACK_ROUNDING * max(1.0, np.abs(x).max()))
    else:
        assert np.array_equal(ours, ref)


def test_sosfiltfilt_too_short_raises_like_scipy():
    sos = filtering.band_pass_sos(COMMON_RATE_HZ, BUTTER_ORDER, BAND_HZ)
    with pytest.raises(ValueError):
        filtering.sosfiltfilt(sos, np.zeros(27))
    with pytest.raises(ValueError):
        signal.sosfiltfilt(sos, np.zeros(27))


@pytest.mark.parametrize("n,m", [(1, 1), (5, 1), (7, 3), (1000, 1000), (3000, 2001),
                                 (108000, 106000)])
def test_correlate_valid_bit_identical(n, m):
    rng = np.random.default_rng(n + m)
    a, v = rng.normal(size=n), rng.normal(size=m)
    assert np.array_equal(filtering.correlate_valid(a, v),
                          signal.correlate(a, v, mode="valid", method="fft"))


@pytest.mark.parametrize("dtype,cpg", [(np.int16, 256.0), (np.int16, 4096.0), (np.int8, 64.0),
                                       (np.int16, 100.0), (np.int32, 256.0)])
def test_magnitude_from_counts_is_the_g_form(dtype, cpg):
    from stillpoint.engine.alignment.signal import magnitude_minus_one
    from stillpoint.engine.core.blocks import Block
    from stillpoint.engine.operators.base import accel_g_columns

    info = np.iinfo(dtype)
    lo, hi = max(info.min, -2**20), min(info.max, 2**20)
    a = np.random.default_rng(3).integers(lo, hi, (5000, 3), endpoint=True).astype(dtype)
    a[:4], a[4:8] = lo, hi  # the largest squares
    b = Block(time_ns=np.arange(5000, dtype=np.int64), accel=a,
              accel_counts_per_g=np.full(3, cpg), accel_zero=np.zeros(3))
    g = accel_g_columns(b)
    x, y, z = g[:, 0], g[:, 1], g[:, 2]
    ref = x * x
    ref += z * z
    ref += y * y
    assert np.array_equal(magnitude_minus_one(b), np.sqrt(ref) - 1.0)


def test_grid_push_with_reused_buffers_equals_push_arrays():
    """push() (times and values in buffers reused across blocks, carried sample in slot 0) gives
    the pieces push_arrays() gives from freshly computed arrays, including repeated times, a
    segment break and blocks of growing size."""
    from stillpoint.engine.alignment.signal import GridResampler, magnitude_minus_one
    from stillpoint.engine.core.blocks import Block

    rng = np.random.default_rng(5)
    t0 = 1_700_000_000_123_456_789
    blocks, start = [], t0
    for i, n in enumerate([50, 400, 3, 1, 2000, 700]):
        step = np.full(n, 10_000_000, np.int64) + rng.integers(-30_000, 30_000, n)
        if i == 3:
            step[:] = 0  # a repeated time: dropped
        tn = start + np.cumsum(step)
        start = int(tn[-1]) + (5_000_000_000 if i == 4 else 0)
        blocks.append(Block(time_ns=tn, accel=rng.integers(-600, 600, (n, 3)).astype(np.int16),
                            accel_counts_per_g=np.full(3, 256.0), accel_zero=np.zeros(3),
                            segment=1 if i >= 5 else 0))
    a, b = GridResampler(t0, 30.0, 100.0), GridResampler(t0, 30.0, 100.0)
    got = [(k, v.copy()) for blk in blocks for k, v in a.push(blk)]
    want = [(k, v) for blk in blocks for k, v in b.push_arrays(
        (blk.time_ns - t0).astype(np.float64) * 1e-9, magnitude_minus_one(blk), blk.segment)]
    assert len(got) == len(want) and got
    for (k1, v1), (k2, v2) in zip(got, want):
        assert k1 == k2 and np.array_equal(v1, v2, equal_nan=True)
    assert (a.samples_dropped, a.gaps, a.last_time_s) == (b.samples_dropped, b.gaps, b.last_time_s)
