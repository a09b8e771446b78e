"""Window features: mean and sample SD per axis, mean temperature, mean norm, count per 10 s window.

Windows are cut by time from the start of each segment (``[t0 + k*10 s, t0 + (k+1)*10 s)``) and
never span a segment (a gap, a restart, a skipped corrupt sector). Temperature is **held per
sample** (each sample takes its sector's/page's temperature) and averaged over the window, which
is what GGIR does for its calibration windows; when the unit values allow exact sums (.cwa
temperatures) the window's sum is taken per unit (value times samples), the same number. A window is emitted only if it holds at least
``min_fill`` of its nominal sample count (``window_s * rate_hz``), so the short tail of a segment
does not enter the fit; ``min_fill=0`` emits every window.

Samples an ActiGraph flags as idle sleep (``per_sample["idle_sleep"]``: its last sample repeated
while it slept) are left out before the windows are cut: a flat, unmeasured stretch is never a
still window of the calibration.

The statistics of a window are computed on the contiguous samples of that window alone, so the
table is bit-identical however the input was cut. Integer counts (every device reader) are summed
exactly (sum and sum of squares of integers held in float64, ``n*S2 - S1**2`` for the variance)
and converted to g once per window: means and mean norms are the same bits as averaging the
per-sample g values (the AX scale is a power of two), SDs are the exact value rounded once
(a two-pass float SD differs from it in the last bit or so). Float input is done in two passes.
"""

from __future__ import annotations

import numpy as np

from ..core.blocks import Block, without_idle_sleep
from ..features import WindowFeatures
from .base import accel_g_columns, ring_capacity
from .binning import BinChunk, TimeBinner

WINDOW_S = 10.0  # van Hees 2014 / GGIR: 10 s windows for the calibration features


def chunk_features(chunk: BinChunk, width_ns: int, zero=None, counts_per_g=None, *,
                   overwrite: bool = False, norm_for=None) -> WindowFeatures:
    """Features of the whole windows in one chunk (pure function unless ``overwrite``).

    With ``counts_per_g`` the chunk's ``accel`` column holds counts (integers stored in float64)
    and the per-window sums are exact: sum and sum of squares of integers below 2**53, the
    variance from ``n * S2 - S1**2`` (exact too), converted to g once per window. Without it,
    ``accel`` is in g and the statistics are computed in two passes (mean, then deviations).
    ``overwrite``: the counts may be squared in place (a scratch the caller no longer needs):
    the same numbers without a temporary per axis. ``norm_for(mean, sd) -> (k,) bool``: the mean
    norm is computed only for those windows (NaN for the others), from their samples alone, so
    the numbers are those of the full computation.
    """
    a = chunk.cols["accel"]
    st = chunk.starts
    cnt = chunk.counts
    k = len(cnt)
    mean = np.empty((k, 3))
    sd = np.empty((k, 3))
    norm_scaled = False  # norm holds |counts| (one scale per window at the end)
    if counts_per_g is None:
        for j in range(3):  # column by column: faster than the (n, 3) broadcast forms (operators/base.py)
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
        shifted = bool(np.any(zero))
        uniform = bool(np.all(cpg == cpg[0]))
        in_place = overwrite and not shifted and uniform
        sq_sum = None
        var_n = np.empty((k, 3))
        for j in range(3):
            c = a[:, j]
            s1 = np.add.reduceat(c, st)
            sq = np.multiply(c, c, out=c if in_place else None)
            s2 = np.add.reduceat(sq, st)
            if in_place:
                pass  # the squares stay in a's columns (summed per wanted window below)
            elif sq_sum is None:
                sq_sum = sq
            else:
                sq_sum += sq  # exact integers: any order gives the same sum
            mean[:, j] = s1 / cnt
            var_n[:, j] = cnt * s2 - s1 * s1  # n^2 * population variance, exact
        if shifted:
            mean -= zero
        mean /= cpg
        with np.errstate(invalid="ignore", divide="ignore"):
            nn1 = (cnt * (cnt - 1.0))[:, None]
            sd = np.sqrt(var_n / nn1) / cpg
        if shifted or not uniform:
            g = (a - zero) / cpg
            norm = np.sqrt(np.einsum("ij,ij->i", g, g))
        else:  # |c| / cpg: the squares already summed exactly, one sqrt, one scale per window
            norm_scaled = True
    sd[cnt < 2] = np.nan
    if chunk.sums is not None and "temperature" in chunk.sums:
        temp = chunk.sums["temperature"] / cnt
    else:
        temp = np.add.reduceat(chunk.cols["temperature"], st) / cnt
    if norm_scaled and in_place:  # the squares are in a's columns: sum, root, mean per window
        want = np.ones(k, bool) if norm_for is None else np.asarray(norm_for(mean, sd), bool)
        norm_mean = np.full(k, np.nan)
        ends = np.append(st[1:], a.shape[0])
        edges = np.flatnonzero(np.diff(np.concatenate([[False], want, [False]]).view(np.int8)))
        for w0, w1 in zip(edges[0::2].tolist(), edges[1::2].tolist()):  # runs of wanted windows
            r0, r1 = int(st[w0]), int(ends[w1 - 1])
            q = a[r0:r1, 0]
            q += a[r0:r1, 1]  # exact integers: any order gives the same sum
            q += a[r0:r1, 2]
            np.sqrt(q, out=q)
            norm_mean[w0:w1] = np.add.reduceat(q, st[w0:w1] - r0) / cnt[w0:w1]
        norm_mean /= cpg[0]
    else:
        if norm_scaled:
            norm = np.sqrt(sq_sum, out=sq_sum)
        norm_mean = np.add.reduceat(norm, st) / cnt
        if norm_scaled:
            norm_mean /= cpg[0]
        if norm_for is not None:
            norm_mean[~np.asarray(norm_for(mean, sd), bool)] = np.nan
    return WindowFeatures(start_ns=chunk.bin_start_ns(width_ns), n=cnt.astype(np.int64), mean=mean,
                          sd=sd, temperature=temp, norm_mean=norm_mean,
                          segment=np.full(len(cnt), chunk.segment, np.int64))


def exact_unit_sums(unit_start: np.ndarray, values: np.ndarray, n: int) -> bool:
    """Whether a per-unit column can be summed over windows per unit (value times samples,
    ``binning.unit_bin_sums``) with the bits of summing it per sample: every value finite and a
    multiple of 2^-8 below 2^10 in magnitude (a .cwa temperature, raw * 75/256 - 50), so that
    every partial sum of a block (below 2^10 * n, on the 2^-8 grid) is exact in float64."""
    if values.shape[0] == 0 or unit_start.shape[0] != values.shape[0] or unit_start[0] != 0:
        return False
    if n >= 1 << 40:
        return False
    v = values * 256.0
    return bool(np.all(np.abs(values) < 1024.0) and np.all(v == np.rint(v)))


class WindowFeaturesOperator:
    """push(Block) -> WindowFeatures of the windows completed by it; flush() -> the rest."""

    def __init__(self, rate_hz: float, window_s: float = WINDOW_S, min_fill: float = 0.9,
                 norm_for=None):
        """``norm_for(mean, sd) -> (k,) bool``: compute the mean norm of those windows only
        (NaN for the others; e.g. the calibration, which keeps only nonmovement windows)."""
        self.norm_for = norm_for
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
        # the counts in the chunks are the operator's scratch or copies: squared in place
        f = WindowFeatures.concat([chunk_features(c, w, *self._scales.get(c.segment, (None, None)),
                                                  overwrite=True, norm_for=self.norm_for)
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
        out[...] = acc.T  # one pass (quickest from column-major counts)
        if not same:
            for j in range(3):
                c = out[j]
                c -= block.accel_zero[j]
                c *= cpg[j] / block.accel_counts_per_g[j]
                c += zero[j]
        return out.T

    def push(self, block: Block) -> WindowFeatures:
        # idle sleep (ActiGraph: the last sample repeated while the device slept) is never a
        # still window: its samples are left out, so a window holding them has fewer samples
        # (and falls under min_fill when mostly idle)
        block = without_idle_sleep(block)
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
        times = block.time_ns if block.time_ns is not None else block.clock
        if exact_unit_sums(block.unit_start, block.temperature_c, block.n):
            chunks = self._binner.push(block.segment, times, accel=accel, units=(
                block.unit_start, {"temperature": block.temperature_c}))
        else:
            chunks = self._binner.push(block.segment, times, accel=accel,
                                       temperature=block.temperature_per_sample())
        return self._features(chunks)

    def flush(self) -> WindowFeatures:
        return self._features(self._binner.flush())
