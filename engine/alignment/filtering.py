"""The alignment's filter and correlation without importing ``scipy.signal``.

Importing ``scipy.signal`` costs ~0.8 s of CPU (it imports ``scipy.stats`` and parses hundreds of
docstrings), a fifth of a 2-day ``align``. The two things the alignment needs from it are
reproduced here with the same numbers:

* ``sosfiltfilt(sos, x)``: ``scipy.signal.sosfiltfilt(sos, x)`` for 1-D ``x`` with the defaults
  (odd extension of ``3 * (2 * sections + 1)`` samples, steady-state initial conditions), the
  same steps in the same order around scipy's compiled sosfilt kernel (loaded from its extension
  module alone, as ``engine/operators/filters.py`` does);
* ``correlate_valid(a, v)``: ``scipy.signal.correlate(a, v, mode="valid", method="fft")`` for
  1-D real arrays, with ``scipy.fft`` as scipy does it (padded to ``next_fast_len``).

The Brønd band-pass at the common rate (30 Hz) and its steady-state conditions are stored as
scipy computes them (``band_pass_sos``; a test checks them against ``scipy.signal.butter`` and
``sosfilt_zi``); any other rate or band is designed by ``scipy.signal``, imported then. When the
kernel cannot be loaded, ``scipy.signal.sosfiltfilt`` itself is used.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from stillpoint.engine.operators.filters import _KERNEL

_H = float.fromhex
# scipy.signal.butter(4, (0.1, 7.0), btype="bandpass", fs=30.0, output="sos")
_SOS_30 = np.array([[_H(v) for v in row] for row in (
    ("0x1.2843f6e15391fp-4", "0x1.2843f6e15391fp-3", "0x1.2843f6e15391fp-4",
     "0x1.0000000000000p+0", "-0x1.0a417d3832662p-3", "0x1.72cd4512ec7d6p-5"),
    ("0x1.0000000000000p+0", "0x1.0000000000000p+1", "0x1.0000000000000p+0",
     "0x1.0000000000000p+0", "-0x1.418b334fc0490p-3", "0x1.d3bb6f44e5c98p-2"),
    ("0x1.0000000000000p+0", "-0x1.0000000000000p+1", "0x1.0000000000000p+0",
     "0x1.0000000000000p+0", "-0x1.f602350db9503p+0", "0x1.ec3f1cafc2314p-1"),
    ("0x1.0000000000000p+0", "-0x1.0000000000000p+1", "0x1.0000000000000p+0",
     "0x1.0000000000000p+0", "-0x1.fbe262c9d9869p+0", "0x1.f7fe30c936401p-1"),
)])
# scipy.signal.sosfilt_zi(_SOS_30)
_ZI_30 = np.array([[_H(v) for v in row] for row in (
    ("0x1.f342c6511efa6p-3", "0x1.db511675bf2d6p-5"),
    ("0x1.503c81ec4e67ap-1", "-0x1.06a580f429829p-3"),
    ("-0x1.f215b25cc08b2p-1", "0x1.f215b25cc08bap-1"),
    ("-0x0.0p+0", "0x0.0p+0"),
)])
_STORED = {(4, (0.1, 7.0), 30.0): (_SOS_30, _ZI_30)}


@lru_cache(maxsize=8)
def _design(order: int, band: tuple, rate: float):
    stored = _STORED.get((int(order), tuple(float(b) for b in band), float(rate)))
    if stored is not None:
        return stored
    from scipy import signal
    sos = signal.butter(order, band, btype="bandpass", fs=rate, output="sos")
    return sos, signal.sosfilt_zi(sos)


def band_pass_sos(rate: float, order: int, band: tuple) -> np.ndarray:
    """``scipy.signal.butter(order, band, btype="bandpass", fs=rate, output="sos")``."""
    return _design(int(order), tuple(band), float(rate))[0]


def _steady_state(sos: np.ndarray) -> np.ndarray:
    for s, zi in _STORED.values():
        if sos is s or np.array_equal(sos, s):
            return zi
    from scipy import signal
    return signal.sosfilt_zi(sos)


def _sosfilt_zi(sos: np.ndarray, x: np.ndarray, zi: np.ndarray) -> np.ndarray:
    """``scipy.signal.sosfilt(sos, x, zi=zi)[0]`` for 1-D x (zi (sections, 2), not modified)."""
    y = np.array(x.reshape(1, -1), np.float64, order="C")  # a copy, filtered in place
    _KERNEL(sos, y, np.ascontiguousarray(zi.reshape(1, sos.shape[0], 2)))
    return y.reshape(-1)


def sosfiltfilt(sos: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``scipy.signal.sosfiltfilt(sos, x)`` for 1-D float64 ``x`` (see the module docstring)."""
    sos = np.asarray(sos, np.float64)
    x = np.asarray(x, np.float64)
    if _KERNEL is None or x.ndim != 1 or sos.ndim != 2 or sos.shape[1] != 6:
        from scipy import signal
        return signal.sosfiltfilt(sos, x)
    n_sections = sos.shape[0]
    ntaps = 2 * n_sections + 1
    ntaps -= min(int((sos[:, 2] == 0).sum()), int((sos[:, 5] == 0).sum()))
    edge = 3 * ntaps
    if x.shape[0] <= edge:
        raise ValueError("The length of the input vector x must be greater than padlen, "
                         f"which is {edge}.")
    if edge > 0:  # odd extension (scipy.signal._arraytools.odd_ext)
        ext = np.concatenate((2 * x[0:1] - x[edge:0:-1], x,
                              2 * x[-1:] - x[-2:-(edge + 2):-1]))
    else:
        ext = x
    zi = _steady_state(sos)
    y = _sosfilt_zi(sos, ext, zi * ext[0:1])
    y = _sosfilt_zi(sos, y[::-1], zi * y[-1:])
    y = y[::-1]
    if edge > 0:
        y = y[edge:-edge]
    return y


def correlate_valid(a: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``scipy.signal.correlate(a, v, mode="valid", method="fft")`` for 1-D real float64 arrays
    with ``len(a) >= len(v) >= 1`` (scipy's fftconvolve of ``a`` and reversed ``v``)."""
    from scipy import fft as sp_fft

    a = np.asarray(a, np.float64)
    k = np.asarray(v, np.float64)[::-1]
    s1, s2 = a.shape[0], k.shape[0]
    if a.ndim != 1 or k.ndim != 1 or s2 < 1 or s1 < s2:
        from scipy import signal
        return signal.correlate(a, v, mode="valid", method="fft")
    shape = s1 + s2 - 1
    if s1 == 1 or s2 == 1:  # scipy: no FFT along a length-1 axis, a plain product
        ret = a * k
    else:
        fshape = [sp_fft.next_fast_len(shape, True)]
        sp1 = sp_fft.rfftn(a, fshape, axes=[0])
        sp2 = sp_fft.rfftn(k, fshape, axes=[0])
        ret = sp_fft.irfftn(sp1 * sp2, fshape, axes=[0])[:shape]
    n_valid = s1 - s2 + 1  # scipy's _centered(ret, valid shape)
    start = (ret.shape[0] - n_valid) // 2
    return ret[start:start + n_valid].copy()
