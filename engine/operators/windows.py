"""Window features: mean and sample SD per axis, mean temperature, mean norm, count per 10 s window.

Windows are cut by time from the start of each segment (``[t0 + k*10 s, t0 + (k+1)*10 s)``) and
never span a segment (a gap, a restart, a skipped corrupt sector). Temperature is **held per
sample** (each sample takes its sector's/page's temperature) and averaged over the window, which
is what GGIR does for its calibration windows. A window is emitted only if it holds at least
``min_fill`` of its nominal sample count (``window_s * rate_hz``), so the short tail of a segment
does not enter the fit; ``min_fill=0`` emits every window.

The statistics of a window are computed on the contiguous samples of that window alone, so the
table is bit-identical however the input was cut. Integer counts (every device reader) are summed
exactly (sum and sum of squares of integers held in float64, ``n*S2 - S1**2`` for the variance)
and converted to g once per window: means and mean norms are the same bits as averaging the
per-sample g values (the AX scale is a power of two), SDs are the exact value rounded once
(a two-pass float SD differs from it in the last bit or so). Float input is done in two passes.
"""

from __future__ import annotations

import numpy as np

from ..blocks import Block
from ..features import WindowFeatures
from .base import accel_g_columns, ring_capacity
from .binning import BinChunk, TimeBinner

WINDOW_S = 10.0  # van Hees 2014 / GGIR: 10 s windows for the calibration features


def chunk_features(chunk: BinChunk, width_ns: int, zero=None, counts_per_g=None) -> WindowFeatures:
    """Features of the whole windows in one chunk (pure function).

    With ``counts_per_g`` the chunk's ``accel`` column holds counts (integers stored in float64)
    and the per-window sums are exact: sum and sum of squares of integers below 2**53, the
    variance from ``n * S2 - S1**2`` (exact too), converted to g once per window. Without it,
    ``accel`` is in g and the statistics are computed in two passes (mean, then deviations).
    """
    a = chunk.cols["accel"]
    st = chunk.starts
    cnt = chunk.counts
    k = len(cnt)
    mean = np.empty((k, 3))
    sd = np.empty((k, 3))
    if counts_per_g is None:
        for j in range(3):  # column by column: the (n, 3) broadcast forms are ~6x slower
            c = a[:, j]
            m = np.add.reduceat(c, st) / cnt
            mean[:, j] = m
            dev = c - np.repeat(m, cnt)
            sd[:, j] = np.add.reduceat(dev * dev, st)
        with np.errstate(invalid="ignore", divide="ignore"):
            sd = np.sqrt(sd / (cnt - 1)[:, None])
        norm = np.sqrt(np.einsum("ij,ij->i", a, a))
    else:
        zero = np.asarray(zero, np.float64)
        cpg = np.asarray(counts_per_g, np.float64)
        sq_sum = None
        var_n = np.empty((k, 3))
        for j in range(3):
            c = a[:, j]
            s1 = np.add.reduceat(c, st)
            sq = c * c
            s2 = np.add.reduceat(sq, st)
            if sq_sum is None:
                sq_sum = sq
            else:
                sq_sum += sq
            mean[:, j] = s1 / cnt
            var_n[:, j] = cnt * s2 - s1 * s1  # n^2 * population variance, exact
        shifted = bool(np.any(zero))
        if shifted:
            mean -= zero
        mean /= cpg
        with np.errstate(invalid="ignore", divide="ignore"):
            nn1 = (cnt * (cnt - 1.0))[:, None]
            sd = np.sqrt(var_n / nn1) / cpg
        if shifted or not np.all(cpg == cpg[0]):
            g = (a - zero) / cpg
            norm = np.sqrt(np.einsum("ij,ij->i", g, g))
        else:  # |c| / cpg: the squares already summed exactly, one sqrt, one scale per window
            norm = np.sqrt(sq_sum)
    sd[cnt < 2] = np.nan
    temp = np.add.reduceat(chunk.cols["temperature"], st) / cnt
    norm_mean = np.add.reduceat(norm, st) / cnt
    if counts_per_g is not None and not (np.any(zero) or not np.all(cpg == cpg[0])):
        norm_mean /= cpg[0]
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
        self._scratch = np.empty((3, 0))  # counts of the current block, reused across blocks
        self._scales: dict = {}  # segment -> (zero, counts_per_g) of its counts in the binner

    def _features(self, chunks) -> WindowFeatures:
        if not chunks:
            return WindowFeatures.empty()
        w = self._binner.width_ns
        f = WindowFeatures.concat([chunk_features(c, w, *self._scales.get(c.segment, (None, None)))
                                   for c in chunks])
        self.windows_total += len(f)
        if self.min_fill > 0 and self.rate_hz > 0:
            f = f.select(f.n >= self.min_fill * self.window_s * self.rate_hz)
        self.windows += len(f)
        return f

    def _counts_columns(self, block: Block) -> np.ndarray:
        """The block's counts as float64 (exact integers) in the reused (3, n) scratch, on the
        scale of its segment's first block (a scale change within a segment is converted)."""
        n = block.n
        if self._scratch.shape[1] < n:
            self._scratch = np.empty((3, max(n, 2 * self._scratch.shape[1])))
        out = self._scratch[:, :n]
        zero, cpg = self._scales[block.segment]
        same = (np.array_equal(zero, block.accel_zero)
                and np.array_equal(cpg, block.accel_counts_per_g))
        acc = block.accel
        for j in range(3):
            c = out[j]
            c[...] = acc[:, j]
            if not same:
                c -= block.accel_zero[j]
                c *= cpg[j] / block.accel_counts_per_g[j]
                c += zero[j]
        return out.T

    def push(self, block: Block) -> WindowFeatures:
        if block.n == 0:
            return WindowFeatures.empty()
        if block.segment not in self._scales:
            self._scales = {k: v for k, v in self._scales.items() if k == self._binner.segment}
            if np.issubdtype(block.accel.dtype, np.integer):
                self._scales[block.segment] = (np.array(block.accel_zero, np.float64),
                                               np.array(block.accel_counts_per_g, np.float64))
        if self._scales.get(block.segment) is not None:
            accel = self._counts_columns(block)
        else:
            accel = accel_g_columns(block)
        chunks = self._binner.push(block.segment, block.time_ns, accel=accel,
                                   temperature=block.temperature_per_sample())
        return self._features(chunks)

    def flush(self) -> WindowFeatures:
        return self._features(self._binner.flush())
