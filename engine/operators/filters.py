"""Streaming IIR filters: second-order sections whose state is carried across blocks.

``SosStream.push(x)`` filters one piece of a signal and keeps the final state, so filtering a
signal piece by piece gives exactly ``scipy.signal.sosfilt(sos, whole_signal, axis=0)`` (zero
initial state, as scipy's default and GGIR's ``signal::filter``). ``reset()`` starts a new
signal (the metrics operator resets at every segment: a filter must not ring across a gap).
"""

from __future__ import annotations

import numpy as np
from scipy import signal

BFEN_BAND_GGIR = (0.2, 15.0)  # GGIR default band-pass for BFEN (hfen/bfen: lb 0.2 Hz, hb 15 Hz)
BFEN_BAND_VANHEES = (0.5, 15.0)  # van Hees et al. 2013 (PLoS ONE) comparison of metrics
BFEN_ORDER = 4  # 4th-order Butterworth as GGIR


def bandpass_sos(rate_hz: float, band=BFEN_BAND_GGIR, order: int = BFEN_ORDER) -> np.ndarray:
    """Butterworth band-pass as second-order sections.

    The upper edge is clipped to 90 % of the Nyquist frequency when the rate is too low for it
    (e.g. 15 Hz at a 20 Hz rate becomes 9 Hz); ``band_used`` reports what was designed.
    """
    return signal.butter(order, band_used(rate_hz, band), btype="bandpass", fs=rate_hz, output="sos")


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
        self.zi = np.zeros((self.sos.shape[0], 2, self.channels))

    def push(self, x: np.ndarray) -> np.ndarray:
        if x.shape[0] == 0:
            return np.zeros((0, self.channels))
        y, self.zi = signal.sosfilt(self.sos, x, axis=0, zi=self.zi)
        return y
