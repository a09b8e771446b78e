"""Streaming IIR filters: second-order sections whose state is carried across blocks.

``SosStream.push(x)`` filters one piece of a signal and keeps the final state, so filtering a
signal piece by piece gives exactly ``scipy.signal.sosfilt(sos, whole_signal, axis=0)`` (zero
initial state, as scipy's default and GGIR's ``signal::filter``). ``reset()`` starts a new
signal (the metrics operator resets at every segment: a filter must not ring across a gap).

Start-up cost: importing ``scipy.signal`` takes ~0.5 s (more than a day of data takes to
filter), so the Butterworth design is done here (analog prototype, band-pass transform,
bilinear transform, one section per conjugate pole pair with a zero at z = 1 and z = -1), and
filtering calls scipy's compiled sosfilt kernel, loaded from its extension module alone; if that
module cannot be loaded, ``scipy.signal.sosfilt`` is used (same kernel, same numbers).
"""

from __future__ import annotations

import numpy as np

from ..core.kernels import scipy_extension

BFEN_BAND_GGIR = (0.2, 15.0)  # GGIR default band-pass for BFEN (hfen/bfen: lb 0.2 Hz, hb 15 Hz)
BFEN_BAND_VANHEES = (0.5, 15.0)  # van Hees et al. 2013 (PLoS ONE) comparison of metrics
BFEN_ORDER = 4  # 4th-order Butterworth as GGIR


def bandpass_sos(rate_hz: float, band=BFEN_BAND_GGIR, order: int = BFEN_ORDER) -> np.ndarray:
    """Butterworth band-pass as second-order sections.

    The upper edge is clipped to 90 % of the Nyquist frequency when the rate is too low for it
    (e.g. 15 Hz at a 20 Hz rate becomes 9 Hz); ``band_used`` reports what was designed.
    """
    return butter_bandpass_sos(order, band_used(rate_hz, band), rate_hz)


def butter_bandpass_sos(order: int, band, fs: float) -> np.ndarray:
    """Digital Butterworth band-pass (``2 * order`` poles) as ``order`` second-order sections;
    the same response as ``scipy.signal.butter(order, band, "bandpass", fs=fs, output="sos")``
    (sections paired and scaled differently: equal up to rounding)."""
    lo, hi = (2.0 * float(f) / fs for f in band)  # normalised to Nyquist
    w1, w2 = 4.0 * np.tan(np.pi * lo / 2.0), 4.0 * np.tan(np.pi * hi / 2.0)  # pre-warped (fs=2)
    n = int(order)
    p = -np.exp(1j * np.pi * np.arange(-n + 1, n, 2) / (2 * n))  # analog low-pass prototype
    bw, wo = w2 - w1, np.sqrt(w1 * w2)
    plp = p * bw / 2.0
    root = np.sqrt(plp * plp - wo * wo)
    pbp = np.concatenate([plp + root, plp - root])  # 2n band-pass poles, n zeros at s = 0
    k = bw ** n
    pz = (4.0 + pbp) / (4.0 - pbp)  # bilinear transform: zeros go to z = 1 (n) and z = -1 (n)
    k *= float(np.real(4.0 ** n / np.prod(4.0 - pbp)))
    upper = pz[pz.imag > 0]  # one of each conjugate pair (no real poles for a band-pass)
    if upper.shape[0] != n:
        raise ValueError(f"band-pass design failed for band {band} at {fs} Hz")
    upper = upper[np.argsort(np.abs(upper))]  # poles nearest the unit circle last
    sos = np.zeros((n, 6))
    sos[:, 0], sos[:, 2] = 1.0, -1.0  # (1 - z^-1)(1 + z^-1)
    sos[:, 3] = 1.0
    sos[:, 4] = -2.0 * upper.real
    sos[:, 5] = np.abs(upper) ** 2
    sos[0, :3] *= k
    return sos


def _load_kernel():
    """scipy's compiled ``_sosfilt(sos, x, zi)`` (filters the rows of C-ordered x in place),
    from its extension module alone (no ``scipy.signal`` import); None if not loadable."""
    mod = scipy_extension("signal", "_sosfilt")
    return getattr(mod, "_sosfilt", None)


_KERNEL = _load_kernel()


def band_used(rate_hz: float, band=BFEN_BAND_GGIR) -> tuple[float, float]:
    lo, hi = float(band[0]), float(band[1])
    nyq = rate_hz / 2.0
    hi = min(hi, 0.9 * nyq)
    if not 0 < lo < hi:
        raise ValueError(f"band-pass {band} Hz is not possible at {rate_hz:g} Hz")
    return lo, hi


class SosStream:
    """Carry ``sosfilt`` state across pieces of one signal with ``channels`` columns."""

    def __init__(self, sos: np.ndarray, channels: int = 3):
        self.sos = np.asarray(sos, np.float64)
        self.channels = channels
        self.reset()

    def reset(self) -> None:
        self._zi = np.zeros((self.channels, self.sos.shape[0], 2))  # the kernel's layout

    @property
    def zi(self) -> np.ndarray:
        """The state in ``scipy.signal.sosfilt(..., axis=0)`` layout (sections, 2, channels)."""
        return np.moveaxis(self._zi, 0, -1).copy()

    def push(self, x: np.ndarray) -> np.ndarray:
        if x.shape[0] == 0:
            return np.zeros((0, self.channels))
        if _KERNEL is None:
            from scipy import signal
            y, zi = signal.sosfilt(self.sos, x, axis=0, zi=self.zi)
            self._zi = np.ascontiguousarray(np.moveaxis(zi, -1, 0))
            return np.ascontiguousarray(y.T).T  # the kernel's layout: (n, 3) view of (3, n)
        xt = np.array(np.asarray(x, np.float64).T, np.float64, order="C")  # (channels, n) copy
        _KERNEL(self.sos, xt, self._zi)
        return xt.T
