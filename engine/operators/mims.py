"""MIMS-units (John et al. 2019, J Meas Phys Behav 2(4):268-281, doi 10.1123/jmpb.2018-0068) as a
streaming epoch metric, reproducing the reference implementation (R package MIMSunit 0.11.2,
mHealthGroup/MIMSunit, MIT; its rules, re-written here):

1. **interpolate to 100 Hz**: a natural cubic spline through the samples (times in seconds),
   evaluated at ``t0 + k * 0.01`` from the segment's first sample (R/extrapolate.R,
   ``extrapolate_single_col``; R/helper.R's grid arithmetic);
2. **extrapolation of near-range samples**: samples within about ``5 * 0.03`` g of the dynamic
   range are replaced as the reference does (R/extrapolate.R; engine/operators/mims_extrapolation.py);
3. **band-pass**: 4th-order Butterworth 0.2-5 Hz (R/filter.R ``iir``, ``signal::butter`` and
   ``signal::filter``: zero initial state at the segment's first sample); samples the
   extrapolation set to -200 skip the filter (R/mims_unit.R: rows with a value below -150);
4. **area under the curve** per axis and epoch: the rectified signal integrated with the
   trapezoidal rule over consecutive 100 Hz samples inside the epoch (R/aggregate_over_epoch.R,
   ``aggregate_for_mims``); an epoch with fewer than 90 % of its samples, or an axis whose area
   reaches ``16 * 100 * epoch_s`` (the largest possible), has no value (the reference writes
   -0.01), and so has an epoch holding a -200 sample;
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
from .mims_extrapolation import ABNORMAL_BELOW, Extrapolator

MIMS_HZ = 100  # resampled rate (R/extrapolate.R: "over sampling to 100Hz")
MIMS_BAND = (0.2, 5.0)  # Hz (R/mims_unit.R mims_unit: cutoffs = c(0.2, 5))
MIMS_ORDER = 4  # R/mims_unit.R: iir(..., order = 4, type = "pass")
MIN_FILL = 0.9  # R/aggregate_over_epoch.R: nrow(rows) >= 0.9 * n_threshold
MAX_PER_SAMPLE = 16.0  # R/aggregate_over_epoch.R: max_values <- 16 * n_threshold (trapz)
TRUNCATE_PER_SAMPLE = 1e-4  # R/mims_unit.R: <= 1e-04 * parse_epoch_string(epoch, sr)
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


# The reference's filter as R's signal 1.8-1 computes it, ``signal::butter(4, c(0.2, 5)/50,
# "pass")`` printed with 17 significant digits: numerator and denominator of an 8th-order IIR run
# by ``signal::filter`` (R/filter.R ``iir``). scipy.signal.butter gives the same filter to within
# an ulp per coefficient (tests/engine/operators/test_mims.py), but this form is so ill-conditioned that one ulp
# moves the 1 s areas by up to 3e-5, enough to put an area that sits on the truncation step on
# the other side of it; with R's own coefficients the areas agree to about 2e-6.
REFERENCE_B = (0.00035884079585594785, 0.0, -0.0014353631834237914, 0.0, 0.0021530447751356872,
               0.0, -0.0014353631834237914, 0.0, 0.00035884079585594785)
REFERENCE_A = (1.0, -7.1989557602839946, 22.71024005695034, -41.012138781845756,
               46.378603842751083, -33.634144664989293, 15.276672513261932, -3.9733824787545169,
               0.45310527307854143)


def _ba():
    """The reference's filter in its own form (``REFERENCE_B``, ``REFERENCE_A``)."""
    return np.array(REFERENCE_B), np.array(REFERENCE_A)


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
    near_range: np.ndarray  # (k,) bool: samples within the near-range band (extrapolated)
    unextrapolated: np.ndarray  # (k,) bool: near-range samples left as recorded (see mims_extrapolation)

    def __len__(self) -> int:
        return int(self.start_ns.shape[0])

    def epoch_values(self) -> np.ndarray:
        """What the epoch table adds up over the parts of an epoch: the MIMS-units."""
        return self.mims[:, None]

    @staticmethod
    def empty() -> "EpochMims":
        return EpochMims(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3)),
                         np.zeros(0), np.zeros(0, np.int64), np.zeros(0, bool), np.zeros(0, bool))

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
        self.extrapolator = None if range_g is None else Extrapolator(float(range_g))
        self.epoch_s = int(epoch_s)
        self.open = None  # (x, |y|, flags) of the epoch still open

    def _auc(self, x: np.ndarray, y: np.ndarray, flags: np.ndarray, final: bool) -> list:
        """Rectified 100 Hz samples -> the areas of the epochs they complete, as (epoch, n,
        area (3,), flags (near range, left as recorded, -200)). The samples of the epoch still
        open wait in ``self.open``, so each epoch's area is summed from its own samples in one
        pass (the same numbers, bit for bit, whatever the block cuts)."""
        r = np.abs(y)
        if self.open is not None:
            x = np.concatenate([self.open[0], x])
            r = np.concatenate([self.open[1], r])
            flags = np.concatenate([self.open[2], flags])
            self.open = None
        if not x.shape[0]:
            return []
        e = np.floor(x / self.epoch_s).astype(np.int64)
        starts = np.concatenate([[0], np.flatnonzero(np.diff(e)) + 1])
        stop = x.shape[0] if final else int(starts[-1])  # the last epoch may still grow
        if not final:
            self.open = (x[stop:], r[stop:], flags[stop:])
            starts = starts[:-1]
        if not starts.shape[0]:
            return []
        x, r, flags, e = x[:stop], r[:stop], flags[:stop], e[:stop]
        # trapezoids between consecutive samples of the same epoch (a pair across an epoch
        # boundary belongs to neither), summed per epoch
        tr = np.diff(x)[:, None] * (r[1:] + r[:-1]) / 2.0
        tr[e[1:] != e[:-1]] = 0.0
        tr = np.concatenate([tr, np.zeros((1, 3))])  # so that every epoch has a row
        area = np.add.reduceat(tr, starts, axis=0)
        n = np.diff(np.append(starts, stop))
        fl = np.logical_or.reduceat(flags, starts, axis=0)
        return [(int(e[s]), int(k), area[i], fl[i])
                for i, (s, k) in enumerate(zip(starts.tolist(), n.tolist()))]

    def _filter(self, y: np.ndarray) -> tuple:
        """Filtered samples, and which are the extrapolation's -200 (they skip the filter and
        go on as they are)."""
        abnormal = (y < ABNORMAL_BELOW).any(axis=1)
        if not y.shape[0]:
            return y, abnormal
        if abnormal.any():
            f = y.copy()
            if (~abnormal).any():
                f[~abnormal], self.zi = self._lfilter(self.b, self.a, y[~abnormal], axis=0,
                                                      zi=self.zi)
            return f, abnormal
        f, self.zi = self._lfilter(self.b, self.a, y, axis=0, zi=self.zi)
        return f, abnormal

    def _stage(self, x: np.ndarray, y: np.ndarray, final: bool) -> list:
        if self.extrapolator is not None:
            if final:
                x0, y0, f0 = self.extrapolator.push(x, y)
                x1, y1, f1 = self.extrapolator.flush()
                x, y, fl = np.concatenate([x0, x1]), np.concatenate([y0, y1]), np.concatenate([f0, f1])
            else:
                x, y, fl = self.extrapolator.push(x, y)
        else:
            fl = np.zeros((x.shape[0], 2), bool)
        f, abnormal = self._filter(y)
        return self._auc(x, f, np.concatenate([fl, abnormal[:, None]], axis=1), final)

    def push(self, t: np.ndarray, a: np.ndarray) -> list:
        x, y = self.spline.push(t, a)
        return self._stage(x, y, final=False)

    def flush(self) -> list:
        x, y = self.spline.flush()
        return self._stage(x, y, final=True)


class MimsOperator:
    """push(CorrectedBatch) -> EpochMims of the epochs it completed; flush() -> the rest.
    ``range_g``: the device's dynamic range (None: unknown, and nothing is extrapolated). The
    epochs holding samples of the near-range band are counted in ``near_range_epochs``, those
    holding near-range samples left as recorded in ``unextrapolated_epochs``."""

    def __init__(self, rate_hz: float, epoch_s: float, range_g=None):
        if float(epoch_s) != int(epoch_s) or epoch_s < 1:
            raise ValueError(f"MIMS-units need a whole-second epoch, not {epoch_s:g} s")
        self.epoch_s = int(epoch_s)
        self.range_g = range_g
        self._seg = None
        self._segment = None
        self.near_range_epochs = 0
        self.unextrapolated_epochs = 0

    def _rows(self, done: list, segment: int) -> EpochMims:
        if not done:
            return EpochMims.empty()
        e = np.array([d[0] for d in done], np.int64)
        n = np.array([d[1] for d in done], np.int64)
        auc = np.array([d[2] for d in done], np.float64).reshape(-1, 3)
        fl = np.array([d[3] for d in done], bool).reshape(-1, 3)
        self.near_range_epochs += int(fl[:, 0].sum())
        self.unextrapolated_epochs += int(fl[:, 1].sum())
        nominal = self.epoch_s * MIMS_HZ
        auc[auc >= MAX_PER_SAMPLE * nominal] = np.nan
        auc[n < MIN_FILL * nominal] = np.nan
        auc[fl[:, 2]] = np.nan  # R: a -200 sample makes the epoch -0.01
        auc[(auc > 0) & (auc <= TRUNCATE_PER_SAMPLE * nominal)] = 0.0
        return EpochMims(e * self.epoch_s * 10**9, n, auc, auc.sum(axis=1),
                         np.full(len(done), segment, np.int64), fl[:, 0], fl[:, 1])

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
