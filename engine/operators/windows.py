"""Window features: mean and sample SD per axis, mean temperature, mean norm, count per 10 s window.

Windows are cut by time from the start of each segment (``[t0 + k*10 s, t0 + (k+1)*10 s)``) and
never span a segment (a gap, a restart, a skipped corrupt sector). Temperature is **held per
sample** (each sample takes its sector's/page's temperature) and averaged over the window, which
is what GGIR does for its calibration windows. A window is emitted only if it holds at least
``min_fill`` of its nominal sample count (``window_s * rate_hz``), so the short tail of a segment
does not enter the fit; ``min_fill=0`` emits every window.

The statistics of a window are computed on the contiguous samples of that window alone (two
passes: mean, then squared deviations), so the table is bit-identical however the input was cut.
"""

from __future__ import annotations

import numpy as np

from ..blocks import Block
from ..features import WindowFeatures
from .base import accel_g_columns, ring_capacity
from .binning import BinChunk, TimeBinner

WINDOW_S = 10.0  # van Hees 2014 / GGIR: 10 s windows for the calibration features


def chunk_features(chunk: BinChunk, width_ns: int) -> WindowFeatures:
    """Features of the whole windows in one chunk (pure function)."""
    a = chunk.cols["accel"]
    st = chunk.starts
    cnt = chunk.counts
    mean = np.empty((len(cnt), 3))
    ss = np.empty((len(cnt), 3))
    for j in range(3):  # column by column: the (n, 3) broadcast forms are ~6x slower
        c = a[:, j]
        m = np.add.reduceat(c, st) / cnt
        mean[:, j] = m
        dev = c - np.repeat(m, cnt)
        ss[:, j] = np.add.reduceat(dev * dev, st)
    with np.errstate(invalid="ignore", divide="ignore"):
        sd = np.sqrt(ss / (cnt - 1)[:, None])
    sd[cnt < 2] = np.nan
    temp = np.add.reduceat(chunk.cols["temperature"], st) / cnt
    norm = np.sqrt(np.einsum("ij,ij->i", a, a))
    norm_mean = np.add.reduceat(norm, st) / cnt
    return WindowFeatures(start_ns=chunk.bin_start_ns(width_ns), n=cnt.astype(np.int64), mean=mean,
                          sd=sd, temperature=temp, norm_mean=norm_mean,
                          segment=np.full(len(cnt), chunk.segment, np.int64))


class WindowFeaturesOperator:
    """push(Block) -> WindowFeatures of the windows completed by it; flush() -> the rest."""

    def __init__(self, rate_hz: float, window_s: float = WINDOW_S, min_fill: float = 0.9):
        self.rate_hz = float(rate_hz)
        self.window_s = float(window_s)
        self.min_fill = float(min_fill)
        self._binner = TimeBinner(window_s, {"accel": (np.float64, (3,)),
                                             "temperature": (np.float64, ())},
                                  align="segment", capacity=ring_capacity(window_s, rate_hz))
        self.windows_total = 0  # windows formed (before the fill rule)
        self.windows = 0  # windows emitted

    def _features(self, chunks) -> WindowFeatures:
        if not chunks:
            return WindowFeatures.empty()
        f = WindowFeatures.concat([chunk_features(c, self._binner.width_ns) for c in chunks])
        self.windows_total += len(f)
        if self.min_fill > 0 and self.rate_hz > 0:
            f = f.select(f.n >= self.min_fill * self.window_s * self.rate_hz)
        self.windows += len(f)
        return f

    def push(self, block: Block) -> WindowFeatures:
        if block.n == 0:
            return WindowFeatures.empty()
        chunks = self._binner.push(block.segment, block.time_ns, accel=accel_g_columns(block),
                                   temperature=block.temperature_per_sample())
        return self._features(chunks)

    def flush(self) -> WindowFeatures:
        return self._features(self._binner.flush())
