"""The detector's input signals from a recording: calibrated acceleration norm and angular-velocity
norm per sample, median-detrended, optionally filtered or resampled.

Streaming: a recording is read block by block and only three per-sample values are kept (time,
acceleration norm, angular-velocity norm: 24 bytes a sample, ~160 MB for 72 h at 25 Hz), never
the six channels. The median needs the whole series, so that is the floor.

Filters (never called "8 Hz" when they are not):
* ``2tap`` - the reference's "first-order FIR, Hamming, 8 Hz": a 2-tap average [0.5, 0.5] run
  causally with zero initial state, whatever the cut-off (|H(f)| = |cos(pi f / fs)|);
* ``lowpass8`` - a real zero-phase 8 Hz low-pass (windowed-sinc FIR, 1 s long, forward-backward);
* ``none``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Optional

import numpy as np

G_MS2 = 9.80665  # m/s^2 per g (reference constant)
DEG_TO_RAD = 0.017453  # the reference's factor (only the sign of w is used)
FILTERS = ("none", "2tap", "lowpass8")
LOWPASS_HZ = 8.0


@dataclass
class LegSignals:
    time_ns: np.ndarray  # (n,) int64
    acc_norm: np.ndarray  # (n,) m/s^2, calibrated
    gyro_norm: Optional[np.ndarray]  # (n,) deg/s (None: no gyroscope)
    fs: int  # nominal (or resampled) rate used for the sample constants

    @property
    def n(self) -> int:
        return int(self.time_ns.shape[0])


def two_tap(x: np.ndarray) -> np.ndarray:
    """The reference filter: y[i] = (x[i] + x[i-1]) / 2, y[0] = x[0] / 2."""
    y = np.empty_like(x, dtype=np.float64)
    y[0:1] = 0.5 * x[0:1]
    np.add(x[1:], x[:-1], out=y[1:])
    y[1:] *= 0.5
    return y


def lowpass(x: np.ndarray, fs: float, cutoff_hz: float = LOWPASS_HZ) -> np.ndarray:
    """Zero-phase windowed-sinc low-pass (Hamming, ~1 s of taps, applied forward-backward)."""
    from scipy.signal import filtfilt, firwin
    if cutoff_hz >= fs / 2:
        raise ValueError(f"a {cutoff_hz:g} Hz low-pass needs a sampling rate above "
                         f"{2 * cutoff_hz:g} Hz (this one is {fs:g} Hz)")
    taps = int(fs) | 1
    h = firwin(taps, cutoff_hz, window="hamming", fs=fs)
    if x.shape[0] <= 3 * taps:
        return np.convolve(x, h, mode="same")
    return filtfilt(h, [1.0], x)


def apply_filter(a_d: np.ndarray, name: str, fs: float) -> np.ndarray:
    if name == "none":
        return a_d
    if name == "2tap":
        return two_tap(a_d)
    if name == "lowpass8":
        return lowpass(a_d, fs)
    raise ValueError(f"filter must be one of {FILTERS}, not {name!r}")


def detrend(x: np.ndarray) -> np.ndarray:
    return x - np.median(x)


def read_signals(path, correct: Callable[[np.ndarray], np.ndarray], *, resample_hz=None,
                 use_gyro: bool = True, progress=None) -> LegSignals:
    """Stream a recording into LegSignals. ``correct``: raw g (n, 3) -> calibrated g (n, 3).
    ``resample_hz``: linear interpolation of the calibrated axes and the gyro onto a uniform grid
    from the first sample (step rounded to 0.01 s, end excluded), as the HBCD release does."""
    from stillpoint.engine.recordings import open_recording
    src = open_recording(path)
    info = src.info
    fs_nom = int(round(float(info.sample_rate_nominal or 0)))
    times, accs, gyrs = [], [], []
    prev = None  # last raw sample of the previous block (resampling across blocks)
    t0 = None
    grid_k = 0
    step = None if not resample_hz else 1.0 / float(resample_hz)
    try:
        for block in src:
            if block.n == 0:
                continue
            t = block.time_ns
            a = correct(block.accel_g())
            g = block.gyro_dps() if use_gyro else None
            if use_gyro and g is None:
                g = np.full((block.n, 3), np.nan)
            if t0 is None:
                t0 = int(t[0])
            if step is None:
                times.append(t.copy())
                accs.append(np.sqrt(np.einsum("ij,ij->i", a, a)) * G_MS2)
                if use_gyro:
                    gyrs.append(np.sqrt(np.einsum("ij,ij->i", g, g)))
                continue
            if prev is not None:
                t = np.concatenate(([prev[0]], t))
                a = np.concatenate((prev[1][None], a))
                if use_gyro:
                    g = np.concatenate((prev[2][None], g))
            prev = (int(t[-1]), a[-1].copy(), None if g is None else g[-1].copy())
            rel = (t - t0) / 1e9
            # grid points k*step (rounded to 0.01 s) with rel[0] <= point < rel[-1]
            k_end = int(np.floor(rel[-1] / step)) + 2
            ks = np.arange(grid_k, k_end)
            pts = np.round(ks * step, 2)
            sel = pts < rel[-1]
            pts, ks = pts[sel], ks[sel]
            if pts.size == 0:
                continue
            grid_k = int(ks[-1]) + 1
            ai = np.stack([np.interp(pts, rel, a[:, j]) for j in range(3)], 1)
            times.append(t0 + np.round(pts * 1e9).astype(np.int64))
            accs.append(np.sqrt(np.einsum("ij,ij->i", ai, ai)) * G_MS2)
            if use_gyro:
                gi = np.stack([np.interp(pts, rel, g[:, j]) for j in range(3)], 1)
                gyrs.append(np.sqrt(np.einsum("ij,ij->i", gi, gi)))
            if progress:
                progress(int(t[-1] - t0))
    finally:
        src.close()
    def cat(xs, dt):  # one channel at a time, its blocks freed as soon as it is joined
        out = np.concatenate(xs) if xs else np.zeros(0, dt)
        xs.clear()
        return out

    fs = int(resample_hz) if resample_hz else fs_nom
    t_all = cat(times, np.int64)
    a_all = cat(accs, np.float64)
    g_all = cat(gyrs, np.float64) if use_gyro else None
    return LegSignals(t_all, a_all, g_all, fs)


def signals_from_arrays(time_ns, acc_g, gyro_dps, fs, correct=None) -> LegSignals:
    """LegSignals from in-memory arrays (raw g, deg/s); ``correct``: raw g -> calibrated g."""
    a = np.asarray(acc_g, np.float64)
    if correct is not None:
        a = correct(a)
    g = None if gyro_dps is None else np.linalg.norm(np.asarray(gyro_dps, np.float64), axis=1)
    return LegSignals(np.asarray(time_ns, np.int64), np.linalg.norm(a, axis=1) * G_MS2, g, int(fs))
