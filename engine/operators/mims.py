"""MIMS-units (John et al. 2019, J Meas Phys Behav 2(4):268-281, doi 10.1123/jmpb.2018-0068) as a
streaming epoch metric, reproducing the reference implementation (R package MIMSunit 0.11.2,
mHealthGroup/MIMSunit, MIT; its rules, re-written here):

1. **interpolate to 100 Hz**: a natural cubic spline through the samples (times in seconds),
   evaluated at ``t0 + k * 0.01`` from the segment's first sample (R/extrapolate.R,
   ``extrapolate_single_col``; R/helper.R's grid arithmetic);
2. **extrapolation of clipped samples**: samples within ``5 * 0.03`` g of the dynamic range are
   marked by the reference's gamma rule (``.mark_gamma``) and replaced by a smoothing-spline
   extrapolation. Not reproduced here: such samples are used as recorded, and the epochs that
   hold them are counted (``MimsOperator.near_range_epochs``) and flagged by ``clipping`` in the
   epoch table's windows;
3. **band-pass**: 4th-order Butterworth 0.2-5 Hz (R/filter.R ``iir``, ``signal::butter`` and
   ``signal::filter``: zero initial state at the segment's first sample);
4. **area under the curve** per axis and epoch: the rectified signal integrated with the
   trapezoidal rule over consecutive 100 Hz samples inside the epoch (R/aggregate_over_epoch.R,
   ``aggregate_for_mims``); an epoch with fewer than 90 % of its samples, or an axis whose area
   reaches ``16 * 100 * epoch_s`` (the largest possible), has no value (the reference writes
   -0.01);
5. **truncation**: an axis area in ``(0, 1e-4 * 100 * epoch_s]`` is 0 (R/mims_unit.R);
6. **sum** of the three axes (``combination = "sum"``).

Epochs are cut on the UTC grid (``[k*epoch, (k+1)*epoch)``), which for 1 s epochs is the
reference's grid too (it cuts at whole seconds from the first sample's second); for longer epochs
the reference starts its epochs at the first sample's whole second instead. Times follow the
reference's arithmetic: seconds since the Unix epoch as float64, the 100 Hz grid ``t0 + k/100``.

Streaming: the spline is solved tile by tile (``TILE`` samples with ``OVERLAP`` samples of the
neighbouring tiles on each side, cut at fixed sample numbers of the segment, so the result does
not depend on how the stream was cut); a natural spline's dependence on a knot decays by a factor
of about 0.27 per knot, so 64 knots of overlap leave differences from the spline through the
whole segment below 1e-30 relative; at a segment's ends the natural end conditions are the
reference's. The filter carries its state; a segment (a gap) starts every stage afresh.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from .correction import CorrectedBatch

MIMS_HZ = 100  # resampled rate (R/extrapolate.R: "over sampling to 100Hz")
MIMS_BAND = (0.2, 5.0)  # Hz (R/mims_unit.R mims_unit: cutoffs = c(0.2, 5))
MIMS_ORDER = 4  # R/mims_unit.R: iir(..., order = 4, type = "pass")
MIN_FILL = 0.9  # R/aggregate_over_epoch.R: nrow(rows) >= 0.9 * n_threshold
MAX_PER_SAMPLE = 16.0  # R/aggregate_over_epoch.R: max_values <- 16 * n_threshold (trapz)
TRUNCATE_PER_SAMPLE = 1e-4  # R/mims_unit.R: <= 1e-04 * parse_epoch_string(epoch, sr)
NOISE_LEVEL_G = 0.03  # R/mims_unit.R mims_unit: noise_level = 0.03 (extrapolation marker)
TILE = 2048  # input samples per spline tile
OVERLAP = 64  # knots of each neighbouring tile in a tile's spline


def _natural_spline(x: np.ndarray, y: np.ndarray, xo: np.ndarray) -> np.ndarray:
    """Natural cubic spline through (x, y[:, c]) evaluated at ``xo`` (stats::spline method
    "natural" inside the knots)."""
    from scipy.interpolate import CubicSpline
    if x.shape[0] == 1:
        return np.repeat(y[:1], xo.shape[0], axis=0)
    if x.shape[0] == 2:
        w = ((xo - x[0]) / (x[1] - x[0]))[:, None]
        return y[0] + w * (y[1] - y[0])
    return CubicSpline(x, y, bc_type="natural", axis=0)(xo)


def _ba():
    """The reference's filter in its own form: ``signal::butter(4, c(0.2, 5)/50, "pass")`` as
    numerator/denominator polynomials (an 8th-order IIR run by ``signal::filter``)."""
    from scipy import signal
    return signal.butter(MIMS_ORDER, [f / (MIMS_HZ / 2.0) for f in MIMS_BAND], "bandpass")


class _Spline100:
    """Samples of one segment -> the 100 Hz grid, tile by tile (see the module docstring)."""

    def __init__(self):
        self.t = np.zeros(0)  # knot times (s, float64) from knot index self.base
        self.y = np.zeros((0, 3))
        self.base = 0
        self.n = 0  # knots seen
        self.t0 = None
        self.k = 0  # next grid point
        self.tile = 0  # next tile to evaluate

    def push(self, t: np.ndarray, y: np.ndarray):
        if self.t0 is None:
            self.t0 = float(t[0])
        self.t = np.concatenate([self.t, t])
        self.y = np.concatenate([self.y, y])
        self.n += t.shape[0]
        return self._tiles(final=False)

    def flush(self):
        return self._tiles(final=True)

    def _tiles(self, final: bool):
        xs, ys = [], []
        while True:
            a, b = self.tile * TILE, (self.tile + 1) * TILE  # knots [a, b) own their span
            if b + OVERLAP > self.n and not final:
                break
            if a >= self.n:
                break
            last = b >= self.n  # the segment's last tile (only when final)
            lo, hi = max(0, a - OVERLAP), min(self.n, b + OVERLAP)
            kt = self.t[lo - self.base:hi - self.base]
            ky = self.y[lo - self.base:hi - self.base]
            t_end = float(self.t[self.n - 1 - self.base]) if last else float(self.t[b - self.base])
            # grid points x_k = t0 + k/100 in [t_a, t_b) (the last tile: up to the last knot)
            n_grid = int(np.floor((t_end - self.t0) / (1.0 / MIMS_HZ) + 1e-10)) + 1
            ks = np.arange(self.k, n_grid, dtype=np.float64)
            xk = self.t0 + ks * (1.0 / MIMS_HZ)
            if not last:
                keep = xk < t_end
                ks, xk = ks[keep], xk[keep]
            if xk.shape[0]:
                xs.append(xk)
                ys.append(_natural_spline(kt, ky, xk))
                self.k = int(ks[-1]) + 1
            self.tile += 1
            drop = max(0, self.tile * TILE - OVERLAP - self.base)
            if drop:
                self.t, self.y = self.t[drop:], self.y[drop:]
                self.base += drop
        if not xs:
            return np.zeros(0), np.zeros((0, 3))
        return np.concatenate(xs), np.concatenate(ys)


@dataclass
class EpochMims:
    """MIMS-units of the epochs an operator completed (one row per epoch and segment)."""

    start_ns: np.ndarray  # (k,) int64 epoch start on the UTC grid
    n: np.ndarray  # (k,) int64 100 Hz samples
    axes: np.ndarray  # (k, 3) per-axis MIMS-units (NaN: undefined)
    mims: np.ndarray  # (k,) their sum (NaN when any axis is undefined)
    segment: np.ndarray  # (k,) int64
    near_range: np.ndarray  # (k,) bool: samples within 0.15 g of the range (not extrapolated)

    def __len__(self) -> int:
        return int(self.start_ns.shape[0])

    def epoch_values(self) -> np.ndarray:
        """What the epoch table adds up over the parts of an epoch: the MIMS-units."""
        return self.mims[:, None]

    @staticmethod
    def empty() -> "EpochMims":
        return EpochMims(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3)),
                         np.zeros(0), np.zeros(0, np.int64), np.zeros(0, bool))

    @staticmethod
    def concat(parts) -> "EpochMims":
        parts = [p for p in parts if len(p)]
        if not parts:
            return EpochMims.empty()
        return EpochMims(**{f.name: np.concatenate([getattr(p, f.name) for p in parts])
                            for f in fields(EpochMims)})


class _SegmentMims:
    def __init__(self, epoch_s: int, range_g):
        from scipy import signal
        self._lfilter = signal.lfilter
        self.b, self.a = _ba()
        self.zi = np.zeros((max(len(self.a), len(self.b)) - 1, 3))
        self.spline = _Spline100()
        self.epoch_s = int(epoch_s)
        self.near = None if range_g is None else float(range_g) - 5 * NOISE_LEVEL_G
        self.open = None  # (x, |y|, near) of the epoch still open

    def _auc(self, x: np.ndarray, y: np.ndarray, raw: np.ndarray, final: bool) -> list:
        """Rectified 100 Hz samples -> the areas of the epochs they complete, as (epoch, n,
        area (3,), near range). The samples of the epoch still open wait in ``self.open``, so
        each epoch's area is summed from its own samples in one pass (the same numbers,
        bit for bit, whatever the block cuts)."""
        r = np.abs(y)
        near = (np.abs(raw) > self.near).any(axis=1) if self.near is not None else \
            np.zeros(x.shape[0], bool)
        if self.open is not None:
            x = np.concatenate([self.open[0], x])
            r = np.concatenate([self.open[1], r])
            near = np.concatenate([self.open[2], near])
            self.open = None
        if not x.shape[0]:
            return []
        e = np.floor(x / self.epoch_s).astype(np.int64)
        starts = np.concatenate([[0], np.flatnonzero(np.diff(e)) + 1])
        stop = x.shape[0] if final else int(starts[-1])  # the last epoch may still grow
        if not final:
            self.open = (x[stop:], r[stop:], near[stop:])
            starts = starts[:-1]
        if not starts.shape[0]:
            return []
        x, r, near, e = x[:stop], r[:stop], near[:stop], e[:stop]
        # trapezoids between consecutive samples of the same epoch (a pair across an epoch
        # boundary belongs to neither), summed per epoch
        tr = np.diff(x)[:, None] * (r[1:] + r[:-1]) / 2.0
        tr[e[1:] != e[:-1]] = 0.0
        tr = np.concatenate([tr, np.zeros((1, 3))])  # so that every epoch has a row
        area = np.add.reduceat(tr, starts, axis=0)
        n = np.diff(np.append(starts, stop))
        nr = np.logical_or.reduceat(near, starts)
        return [(int(e[s]), int(k), area[i], bool(nr[i]))
                for i, (s, k) in enumerate(zip(starts.tolist(), n.tolist()))]

    def _filter(self, y: np.ndarray) -> np.ndarray:
        if not y.shape[0]:
            return y
        f, self.zi = self._lfilter(self.b, self.a, y, axis=0, zi=self.zi)
        return f

    def push(self, t: np.ndarray, a: np.ndarray) -> list:
        x, y = self.spline.push(t, a)
        return self._auc(x, self._filter(y), y, final=False)

    def flush(self) -> list:
        x, y = self.spline.flush()
        return self._auc(x, self._filter(y), y, final=True)


class MimsOperator:
    """push(CorrectedBatch) -> EpochMims of the epochs it completed; flush() -> the rest.
    ``range_g``: the device's dynamic range (the epochs with samples within 0.15 g of it are
    counted in ``near_range_epochs``: the reference would have extrapolated them)."""

    def __init__(self, rate_hz: float, epoch_s: float, range_g=None):
        if float(epoch_s) != int(epoch_s) or epoch_s < 1:
            raise ValueError(f"MIMS-units need a whole-second epoch, not {epoch_s:g} s")
        self.epoch_s = int(epoch_s)
        self.range_g = range_g
        self._seg = None
        self._segment = None
        self.near_range_epochs = 0

    def _rows(self, done: list, segment: int) -> EpochMims:
        if not done:
            return EpochMims.empty()
        e = np.array([d[0] for d in done], np.int64)
        n = np.array([d[1] for d in done], np.int64)
        auc = np.array([d[2] for d in done], np.float64).reshape(-1, 3)
        near = np.array([d[3] for d in done], bool)
        self.near_range_epochs += int(near.sum())
        nominal = self.epoch_s * MIMS_HZ
        auc[auc >= MAX_PER_SAMPLE * nominal] = np.nan
        auc[n < MIN_FILL * nominal] = np.nan
        auc[(auc > 0) & (auc <= TRUNCATE_PER_SAMPLE * nominal)] = 0.0
        return EpochMims(e * self.epoch_s * 10**9, n, auc, auc.sum(axis=1),
                         np.full(len(done), segment, np.int64), near)

    def push(self, batch: CorrectedBatch) -> EpochMims:
        if batch.n == 0:
            return EpochMims.empty()
        parts = []
        if batch.segment != self._segment:
            if self._seg is not None:
                parts.append(self._rows(self._seg.flush(), self._segment))
            self._seg = _SegmentMims(self.epoch_s, self.range_g)
            self._segment = batch.segment
        t = batch.time_ns.astype(np.float64) / 1e9
        parts.append(self._rows(self._seg.push(t, batch.accel), batch.segment))
        return EpochMims.concat(parts)

    def flush(self) -> EpochMims:
        if self._seg is None:
            return EpochMims.empty()
        out = self._rows(self._seg.flush(), self._segment)
        self._seg = None
        self._segment = None
        return out
