"""Device clocks: the RTC that timestamps the samples, and the sampling grid of the
accelerometer's own oscillator.

RTC: device_time(t) = t + offset_s + 1e-6 * integral_0^t [skew_ppm
      + curvature_ppm_per_c2 * (T(u) - turnover_c)^2] du
with T the device temperature (the 32.768 kHz tuning-fork crystal's parabola; -0.035 ppm/degC^2
around 25 degC, see drivers/constants.py). Integrated on the temperature grid (trapezoid rule,
exact for the piecewise-linear temperature); ``device_time`` interpolates it.

Sampling: the accelerometer samples at rate_true = rate_nominal * (1 + rate_error_pct / 100) in
true time; samples inside a halt or a restart gap are not taken (time runs on). The file's
sample times are device_time(true sample time).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .model import SensorModel


@dataclass
class ClockModel:
    """Offset (s) of the device clock against true time on a grid, plus the sampling plan."""

    grid_s: np.ndarray  # (g,) true time
    offset_s: np.ndarray  # (g,) device_time - true time at grid_s
    rate_true_hz: float
    halts: list = field(default_factory=list)  # [(start_s, end_s)] true time, no samples
    restarts: list = field(default_factory=list)  # [(start_s, end_s)] true time, logging stopped
    params: dict = field(default_factory=dict)

    def device_time(self, t) -> np.ndarray:
        """Device clock reading (s since the true start) at true times t."""
        t = np.asarray(t, np.float64)
        return t + np.interp(t, self.grid_s, self.offset_s)

    def true_time(self, d) -> np.ndarray:
        """Inverse of device_time (monotonic: the clock never runs backwards)."""
        return np.interp(np.asarray(d, np.float64), self.grid_s + self.offset_s, self.grid_s)

    def gaps(self) -> list:
        return sorted(self.halts + self.restarts)

    def sample_times(self, i0: int, i1: int) -> tuple[np.ndarray, np.ndarray]:
        """True times of sample slots [i0, i1) of the sampling grid, and a mask of the slots
        actually sampled (outside halts and restart gaps)."""
        t = np.arange(i0, i1, dtype=np.float64) / self.rate_true_hz
        keep = np.ones(t.shape[0], bool)
        for a, b in self.gaps():
            if b > t[0] and a <= t[-1] if t.size else False:
                keep &= ~((t >= a) & (t < b))
        return t, keep


def make_clock(model: SensorModel, t_grid: np.ndarray, temperature_c: np.ndarray,
               rate_hz: float) -> ClockModel:
    """Build the clock from a resolved model and the device temperature track."""
    p = model.effects.get("clock")
    if p is not None:
        ppm = float(p.get("skew_ppm", 0.0)) + float(p.get("curvature_ppm_per_c2", -0.035)) * (
            temperature_c - float(p.get("turnover_c", 25.0))) ** 2
        inc = 0.5 * (ppm[1:] + ppm[:-1]) * 1e-6 * np.diff(t_grid)
        off = float(p.get("offset_s", 0.0)) + np.concatenate([[0.0], np.cumsum(inc)])
    else:
        off = np.zeros_like(t_grid)
    rate_true = rate_hz * (1.0 + float(model.get("rate_error", "pct", 0.0)) / 100.0)
    halts = [(float(e["start_s"]), float(e["start_s"]) + float(e["duration_s"]))
             for e in model.get("halts", "events", [])] if model.on("halts") else []
    restarts = [(float(e["start_s"]), float(e["start_s"]) + float(e["gap_s"]))
                for e in model.get("restarts", "events", [])] if model.on("restarts") else []
    return ClockModel(grid_s=np.asarray(t_grid, np.float64), offset_s=off, rate_true_hz=rate_true,
                      halts=halts, restarts=restarts, params=dict(p or {}))
