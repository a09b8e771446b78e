"""The alignment's filter and correlation without ``scipy.signal`` give scipy's numbers exactly."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

from stillpoint.engine.alignment import filtering
from stillpoint.engine.alignment.signal import BAND_HZ, BUTTER_ORDER, COMMON_RATE_HZ


def test_stored_band_pass_is_scipys_design():
    sos = filtering.band_pass_sos(COMMON_RATE_HZ, BUTTER_ORDER, BAND_HZ)
    ref = signal.butter(BUTTER_ORDER, BAND_HZ, btype="bandpass", fs=COMMON_RATE_HZ, output="sos")
    assert np.array_equal(sos, ref)
    assert np.array_equal(filtering._steady_state(sos), signal.sosfilt_zi(ref))


@pytest.mark.parametrize("rate", [COMMON_RATE_HZ, 25.0])
@pytest.mark.parametrize("n", [28, 29, 100, 4001])
def test_sosfiltfilt_bit_identical(rate, n):
    rng = np.random.default_rng(n)
    sos = filtering.band_pass_sos(rate, BUTTER_ORDER, BAND_HZ)
    x = rng.normal(size=n) * (rng.random(n) > 0.3)
    assert np.array_equal(filtering.sosfiltfilt(sos, x), signal.sosfiltfilt(sos, x))


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
