"""Window features: the per-10 s-window summary table that calibration, the discrepancy workflow
and the MCAP log share (mean and SD per axis, mean temperature, mean norm, sample count).

It is the sufficient statistic of the autocalibration fit: a week is ~60k rows.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np


@dataclass
class WindowFeatures:
    start_ns: np.ndarray  # (k,) int64 window start (UTC ns)
    n: np.ndarray  # (k,) int64 samples in the window
    mean: np.ndarray  # (k, 3) float64 mean acceleration per axis, g
    sd: np.ndarray  # (k, 3) float64 sample SD (ddof=1) per axis, g
    temperature: np.ndarray  # (k,) float64 mean temperature, degC (NaN when unknown)
    norm_mean: np.ndarray  # (k,) float64 mean Euclidean norm, g
    segment: np.ndarray  # (k,) int64 segment of the source the window lies in

    @staticmethod
    def empty() -> "WindowFeatures":
        return WindowFeatures(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3)),
                              np.zeros((0, 3)), np.zeros(0), np.zeros(0), np.zeros(0, np.int64))

    def __len__(self) -> int:
        return int(self.start_ns.shape[0])

    def select(self, mask) -> "WindowFeatures":
        return WindowFeatures(**{f.name: getattr(self, f.name)[mask] for f in fields(self)})

    @staticmethod
    def concat(parts) -> "WindowFeatures":
        parts = list(parts)
        if not parts:
            return WindowFeatures.empty()
        return WindowFeatures(**{f.name: np.concatenate([getattr(p, f.name) for p in parts])
                                 for f in fields(WindowFeatures)})

    @staticmethod
    def from_arrays(mean, sd, temperature, start_ns=None, n=None, norm_mean=None, segment=None):
        """Build from a table (e.g. GGIR's sphere data: meanx..z, sdx..z, temperature)."""
        mean = np.asarray(mean, np.float64).reshape(-1, 3)
        k = mean.shape[0]
        return WindowFeatures(
            start_ns=np.asarray(start_ns if start_ns is not None else np.arange(k) * 10 * 10**9,
                                np.int64),
            n=np.asarray(n if n is not None else np.zeros(k), np.int64),
            mean=mean,
            sd=np.asarray(sd, np.float64).reshape(-1, 3),
            temperature=np.asarray(temperature, np.float64).reshape(-1),
            norm_mean=np.asarray(norm_mean if norm_mean is not None else np.linalg.norm(mean, axis=1),
                                 np.float64),
            segment=np.asarray(segment if segment is not None else np.zeros(k), np.int64),
        )
