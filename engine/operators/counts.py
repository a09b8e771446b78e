"""ActiLife activity counts (Neishabouri et al. 2022, Sci Rep 12:11958,
doi 10.1038/s41598-022-16003-x) as a streaming epoch metric.

Per axis, on acceleration in g (raw g with ``--no-calibrate``: ActiLife's numbers):

1. resample to 30 Hz. A 30-100 Hz rate in steps of 10 Hz: upsample by L (zeros between samples),
   a first-order low-pass ``y[k] = a*L*(u[k] + u[k-1]) - b*y[k-1]`` with ``a = pi/(pi + 2L)``,
   ``b = (pi - 2L)/(pi + 2L)`` (zero initial state; skipped for 30, 60 and 90 Hz, which are whole
   multiples of 30), then keep every M-th sample (``RESAMPLE_FACTORS``). A power-of-two rate (32,
   64, 128 Hz): upsample to 256 Hz (zeros, times 256/rate) and the 267-tap low-pass FIR
   (``POW2_FIR``, centred); then (and at 256 Hz directly) a one-pole low-pass (``POW2_POLE``, started at its steady state for
   the first sample), then linear interpolation at 256 Hz positions ``256/30*(j+1) - 1``;
2. round to 3 decimals (numpy's rounding, half to even);
3. the 0.29-1.63 Hz band-pass (``BPF_B``, ``BPF_A``, direct form, started at its steady state for
   the first 30 Hz sample), times the gain ``GAIN`` (= 3/4096 / (2.6/256) * 237.5 = 17.1274);
4. trim: ``|y|`` below 4 is 0, above 128 is 128, else floored; with the low-frequency extension
   (``lfe``) below 1 is 0, 1-4 is ``floor - 1``, above 128 is 128, else floored;
5. sum each three 30 Hz values and floor a third of it (10 Hz), then sum the 10 Hz values of each
   epoch.

Every stage carries its state from block to block, so the counts do not depend on how the stream
was cut; a segment (a gap) starts every stage afresh, as a new file would. Each 10 Hz value takes
the time of the input sample where its three 30 Hz samples begin (input sample ``j*rate/10``), so
epochs are cut on the UTC grid as the other metrics (``[k*epoch, (k+1)*epoch)``); an epoch cut by a
segment break yields one row per segment (the epoch table adds them). The axes are reported in
ActiLife's order: ``axis1`` = Y, ``axis2`` = X, ``axis3`` = Z; the vector magnitude is
``sqrt(axis1^2 + axis2^2 + axis3^2)`` of the epoch's counts.

A rate the paper does not cover (e.g. GENEActiv's 85.7 Hz, 20 Hz, a 200 Hz AX3) is first
interpolated linearly to 30 Hz on the sample times (grid from the segment's first sample); those
counts are not a number ActiLife would give (it gives none for such rates).

Constants: Neishabouri et al. 2022 (Methods, "Activity count algorithm"); the filter coefficients,
the resampling factors, the power-of-two filters and the gain as published by ActiGraph in its
reference implementation (actigraph/agcounts, agcounts/extract.py, legacy.py and pow2.py, v0.2.6;
read for the numbers only).
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from .correction import CorrectedBatch

COUNT_MODES = ("normal", "lfe")

# Band-pass, 30 Hz (agcounts legacy.py INPUT_COEFFICIENTS / OUTPUT_COEFFICIENTS; the ninth
# coefficient of each is zero)
BPF_B = np.array([-0.009341062898525, -0.025470289659360, -0.004235264826105, 0.044152415456420,
                  0.036493718347760, -0.011893961934740, -0.022917390623150, -0.006788163862310])
BPF_A = np.array([1.0, -3.63367395910957, 5.03689812757486, -3.09612247819666,
                  0.50620507633883, 0.32421701566682, -0.15685485875559, 0.01949130205890])
GAIN = (3.0 / 4096.0) / (2.6 / 256.0) * 237.5  # ActiLife's; the firmware uses 17.128125
# (upsample L, downsample M) to 30 Hz (agcounts legacy.py _factors)
RESAMPLE_FACTORS = {30: (1, 1), 40: (3, 4), 50: (3, 5), 60: (1, 2), 70: (3, 7), 80: (3, 8),
                    90: (1, 3), 100: (3, 10)}
NO_LOWPASS = (30, 60, 90)  # whole multiples of 30 Hz: no low-pass before keeping every M-th
POW2_RATES = (32, 64, 128, 256)
TRIM = {"normal": (4.0, 128.0), "lfe": (1.0, 128.0)}  # (dead band, ceiling) of |filtered|
COUNTS_HZ = 10  # values summed per epoch: 10 a second
RESAMPLED_HZ = 30

# power-of-two rates (agcounts pow2.py): 256 Hz low-pass FIR, symmetric, 267 taps (upsample_to_256hz)
_POW2_HALF = [
    -0.000001, -0.000002, -0.000004, -0.000005, -0.000006, -0.000006, -0.000004, 0.000000,
    0.000005, 0.000011, 0.000017, 0.000022, 0.000023, 0.000020, 0.000013, -0.000000, -0.000016,
    -0.000033, -0.000049, -0.000059, -0.000061, -0.000052, -0.000031, -0.000000, 0.000038,
    0.000077, 0.000111, 0.000132, 0.000133, 0.000112, 0.000066, -0.000000, -0.000078, -0.000156,
    -0.000222, -0.000260, -0.000259, -0.000214, -0.000125, 0.000000, 0.000145, 0.000288, 0.000404,
    0.000469, 0.000464, 0.000380, 0.000220, -0.000000, -0.000250, -0.000493, -0.000687, -0.000791,
    -0.000777, -0.000632, -0.000363, 0.000000, 0.000409, 0.000801, 0.001108, 0.001269, 0.001240,
    0.001003, 0.000574, -0.000000, -0.000639, -0.001246, -0.001715, -0.001956, -0.001903,
    -0.001534, -0.000873, 0.000000, 0.000966, 0.001875, 0.002574, 0.002926, 0.002839, 0.002280,
    0.001295, -0.000000, -0.001425, -0.002762, -0.003783, -0.004293, -0.004158, -0.003335,
    -0.001892, 0.000000, 0.002078, 0.004025, 0.005513, 0.006257, 0.006061, 0.004866, 0.002763,
    -0.000000, -0.003045, -0.005909, -0.008115, -0.009237, -0.008981, -0.007240, -0.004131,
    0.000000, 0.004606, 0.009005, 0.012468, 0.014325, 0.014075, 0.011483, 0.006641, -0.000000,
    -0.007655, -0.015271, -0.021640, -0.025543, -0.025900, -0.021926, -0.013250, 0.000000,
    0.017180, 0.037161, 0.058432, 0.079245, 0.097796, 0.112422, 0.121780]
POW2_FIR = np.array(_POW2_HALF + [0.125000] + _POW2_HALF[::-1])
POW2_POLE = 0.307990357416655  # one-pole low-pass at 256 Hz: y = (1-b) y[-1] + b x


def counts_path(rate_hz: float) -> str:
    """How a rate reaches 30 Hz: "factors", "pow2" or "interpolate" (not the paper's)."""
    r = float(rate_hz)
    if r.is_integer() and int(r) in RESAMPLE_FACTORS:
        return "factors"
    if r.is_integer() and int(r) in POW2_RATES:
        return "pow2"
    return "interpolate"


def trim(y: np.ndarray, mode: str) -> np.ndarray:
    """ActiLife's dead band and ceiling on the band-passed, scaled signal (step 4)."""
    a = np.abs(y)
    lo, hi = TRIM[mode]
    out = np.floor(a)
    if mode == "lfe":
        out = np.where(a < 4.0, out - 1.0, out)
    out[a < lo] = 0.0
    out[a > hi] = hi
    return out


class _Lfilter:
    """``scipy.signal.lfilter`` over a signal given piece by piece (state carried)."""

    def __init__(self, b, a, channels: int):
        from scipy import signal
        self._lfilter = signal.lfilter
        self.b, self.a = np.asarray(b, float), np.asarray(a, float)
        self._zi_unit = signal.lfilter_zi(self.b, self.a)
        self.channels = channels
        self.zi = None

    def start_steady(self, x0: np.ndarray) -> None:
        """State of the filter at rest on the constant input ``x0`` (per channel)."""
        self.zi = self._zi_unit[:, None] * np.asarray(x0, float)[None, :]

    def push(self, x: np.ndarray) -> np.ndarray:
        if x.shape[0] == 0:
            return np.zeros((0, self.channels))
        if self.zi is None:
            self.zi = np.zeros((max(len(self.a), len(self.b)) - 1, self.channels))
        y, self.zi = self._lfilter(self.b, self.a, x, axis=0, zi=self.zi)
        return y


class _FactorResampler:
    """30-100 Hz (step 10) to 30 Hz: upsample by L, first-order low-pass, keep every M-th."""

    def __init__(self, rate: int):
        self.L, self.M = RESAMPLE_FACTORS[rate]
        self.lowpass = None
        if rate not in NO_LOWPASS:
            L = self.L
            a = np.pi / (np.pi + 2 * L)
            b = (np.pi - 2 * L) / (np.pi + 2 * L)
            self.lowpass = _Lfilter([a * L, a * L], [1.0, b], 3)
        self.k = 0  # upsampled samples so far (segment)

    def push(self, x: np.ndarray) -> np.ndarray:
        n = x.shape[0]
        if self.L == 1 and self.lowpass is None:
            take = np.arange((-self.k) % self.M, n, self.M)
            self.k += n
            return x[take]
        u = np.zeros((n * self.L, 3))
        u[::self.L] = x
        if self.lowpass is not None:
            u = self.lowpass.push(u)
        take = np.arange((-self.k) % self.M, u.shape[0], self.M)
        self.k += u.shape[0]
        return u[take]

    def flush(self) -> np.ndarray:
        return np.zeros((0, 3))


class _Pow2Resampler:
    """32/64/128/256 Hz to 30 Hz (agcounts pow2.py's steps, streaming): the centred FIR needs
    ``len(POW2_FIR)//2`` samples of look-ahead, so its output lags; ``flush`` ends the signal
    with zeros, as a centred convolution of the whole signal does."""

    def __init__(self, rate: int):
        self.factor = 256 // rate
        self.half = POW2_FIR.shape[0] // 2
        self.buf = np.zeros((self.half, 3))  # zeros before the first sample
        self.emitted = 0  # 256 Hz samples out of the FIR so far
        self.seen = 0  # 256 Hz samples in
        self.pole = None  # one-pole state (previous output)
        self.prev = None  # last 256 Hz value after the pole (for the interpolation)
        self.j = 0  # 30 Hz outputs so far

    def _fir(self, u: np.ndarray, final: bool) -> np.ndarray:
        self.seen += u.shape[0]
        if self.factor == 1:  # already 256 Hz: no FIR (the reference filters upsampled data only)
            return u
        data = np.concatenate([self.buf, u])
        if final:
            data = np.concatenate([data, np.zeros((self.half, 3))])
        n_out = data.shape[0] - 2 * self.half
        if n_out <= 0:
            self.buf = data
            return np.zeros((0, 3))
        out = np.empty((n_out, 3))
        for c in range(3):
            out[:, c] = np.convolve(data[:, c], POW2_FIR, "valid")
        self.buf = data[n_out:]
        return out

    def _pole(self, v: np.ndarray) -> np.ndarray:
        if v.shape[0] == 0:
            return v
        from scipy import signal
        a = 1.0 - POW2_POLE
        x = POW2_POLE * v / a
        if self.pole is None:  # steady state for the first (scaled) value
            zi = signal.lfilter_zi([a], [1.0, -a])[:, None] * x[:1]
        else:
            zi = (a * self.pole)[None, :]
        y, _ = signal.lfilter([a], [1.0, -a], x, axis=0, zi=zi)
        self.pole = y[-1].copy()
        return y

    def _interp(self, v: np.ndarray, final: bool) -> np.ndarray:
        base = self.emitted  # 256 Hz index of v[0]
        self.emitted += v.shape[0]
        data = v if self.prev is None else np.concatenate([self.prev[None, :], v])
        first = base if self.prev is None else base - 1
        if data.shape[0]:
            self.prev = data[-1].copy()
        # output j sits at 256 Hz position p = 256/30*(j+1) - 1, between i = floor(p) and i+1
        total = self.emitted
        n_all = total * 30 // 256 if final else None
        out = []
        while True:
            p = 256.0 / 30.0 * (self.j + 1)
            i = int(np.floor(p)) - 1
            if final:
                if self.j >= n_all - 1:
                    break
            elif i + 1 >= total:
                break
            lo, hi = data[i - first], data[i + 1 - first]
            out.append(lo + (p - 1 - i) * (hi - lo))
            self.j += 1
        if final and self.j < n_all:  # the reference's last value is left at zero
            out.append(np.zeros(3))
            self.j += 1
        return np.array(out).reshape(-1, 3)

    def push(self, x: np.ndarray) -> np.ndarray:
        u = np.zeros((x.shape[0] * self.factor, 3))
        u[::self.factor] = x * self.factor
        return self._interp(self._pole(self._fir(u, False)), False)

    def flush(self) -> np.ndarray:
        return self._interp(self._pole(self._fir(np.zeros((0, 3)), True)), True)


class _LinearResampler:
    """Any other rate: linear interpolation to 30 Hz on the sample times (grid from the segment's
    first sample; not the paper's step)."""

    def __init__(self):
        self.t0 = None
        self.k = 0  # next grid point
        self.last_t = None
        self.last_x = None

    def push_timed(self, t: np.ndarray, x: np.ndarray) -> np.ndarray:
        if self.t0 is None:
            self.t0 = int(t[0])
        if self.last_t is not None:
            t = np.concatenate([[self.last_t], t])
            x = np.concatenate([self.last_x[None, :], x])
        rel = (t - self.t0).astype(np.float64)
        end = int(t[-1] - self.t0)
        k_end = end * RESAMPLED_HZ // 10**9  # last grid point at or before the last sample
        ks = np.arange(self.k, k_end + 1)
        grid = (ks * 10**9 + RESAMPLED_HZ // 2) // RESAMPLED_HZ  # ns from t0, rounded
        out = np.empty((ks.shape[0], 3))
        for c in range(3):
            out[:, c] = np.interp(grid.astype(np.float64), rel, x[:, c])
        self.k = k_end + 1
        self.last_t, self.last_x = int(t[-1]), x[-1].copy()
        return out


@dataclass
class EpochCounts:
    """Counts of the epochs an operator completed (one row per epoch and segment)."""

    start_ns: np.ndarray  # (k,) int64 epoch start on the UTC grid
    n: np.ndarray  # (k,) int64 10 Hz values summed
    counts: np.ndarray  # (k, 3) float64: axis1 (Y), axis2 (X), axis3 (Z)
    segment: np.ndarray  # (k,) int64

    def __len__(self) -> int:
        return int(self.start_ns.shape[0])

    def epoch_values(self) -> np.ndarray:
        """What the epoch table adds up over the parts of an epoch: the axis counts."""
        return self.counts

    @property
    def vm(self) -> np.ndarray:
        return np.sqrt(np.einsum("ij,ij->i", self.counts, self.counts))

    @staticmethod
    def empty() -> "EpochCounts":
        return EpochCounts(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3)),
                           np.zeros(0, np.int64))

    @staticmethod
    def concat(parts) -> "EpochCounts":
        parts = [p for p in parts if len(p)]
        if not parts:
            return EpochCounts.empty()
        return EpochCounts(**{f.name: np.concatenate([getattr(p, f.name) for p in parts])
                              for f in fields(EpochCounts)})


ACTILIFE_ORDER = (1, 0, 2)  # axis1 = Y, axis2 = X, axis3 = Z


class _SegmentCounts:
    """The counts pipeline of one segment: resample, round, band-pass, trim, 10 Hz."""

    def __init__(self, rate_hz: float, mode: str):
        self.mode = mode
        self.rate = float(rate_hz)
        self.path = counts_path(rate_hz)
        if self.path == "factors":
            self.resampler = _FactorResampler(int(rate_hz))
        elif self.path == "pow2":
            self.resampler = _Pow2Resampler(int(rate_hz))
        else:
            self.resampler = _LinearResampler()
        self.bpf = _Lfilter(BPF_B, BPF_A, 3)
        self.started = False
        self.pending = np.zeros((0, 3))  # trimmed 30 Hz values not yet in a group of 3
        self.j = 0  # 10 Hz values so far
        self.t0 = None
        # input sample times not yet used to time a 10 Hz value: (index of times[0], times)
        self.times_base = 0
        self.times = np.zeros(0, np.int64)

    def _after_resample(self, r: np.ndarray) -> np.ndarray:
        """30 Hz values -> 10 Hz values (n, 3), in ActiLife's axis order."""
        if r.shape[0] == 0:
            return np.zeros((0, 3))
        r = np.round(r, 3)
        if not self.started:
            self.bpf.start_steady(r[0])
            self.started = True
        y = trim(self.bpf.push(r) * GAIN, self.mode)
        y = np.concatenate([self.pending, y])
        m = y.shape[0] // 3
        self.pending = y[3 * m:]
        g = y[:3 * m].reshape(m, 3, 3).sum(axis=1)
        return np.floor(g / 3.0)[:, ACTILIFE_ORDER]

    def _times_of(self, m: int) -> np.ndarray:
        """Times of the next ``m`` 10 Hz values."""
        j = self.j + np.arange(m)
        if self.path == "interpolate":
            t = self.t0 + (3 * j * 10**9 + RESAMPLED_HZ // 2) // RESAMPLED_HZ
        else:
            idx = (j * self.rate) // COUNTS_HZ
            idx = idx.astype(np.int64) - self.times_base
            idx = np.minimum(idx, self.times.shape[0] - 1)
            t = self.times[idx]
        self.j += m
        if self.path != "interpolate" and m:
            nxt = int((self.j * self.rate) // COUNTS_HZ) - self.times_base
            drop = max(0, min(nxt, self.times.shape[0] - 1))
            self.times = self.times[drop:]
            self.times_base += drop
        return np.asarray(t, np.int64)

    def push(self, t: np.ndarray, a: np.ndarray):
        if self.t0 is None:
            self.t0 = int(t[0])
        if self.path == "interpolate":
            r = self.resampler.push_timed(t, a)
        else:
            self.times = np.concatenate([self.times, t])
            r = self.resampler.push(a)
        v = self._after_resample(r)
        return self._times_of(v.shape[0]), v

    def flush(self):
        if self.path == "pow2":
            v = self._after_resample(self.resampler.flush())
            return self._times_of(v.shape[0]), v
        return np.zeros(0, np.int64), np.zeros((0, 3))


class CountsOperator:
    """push(CorrectedBatch) -> EpochCounts of the epochs it completed; flush() -> the rest."""

    def __init__(self, rate_hz: float, epoch_s: float, mode: str = "normal"):
        if mode not in COUNT_MODES:
            raise ValueError(f"counts mode must be one of {COUNT_MODES}, not {mode!r}")
        if float(epoch_s) != int(epoch_s) or epoch_s < 1:
            raise ValueError(f"counts need a whole-second epoch, not {epoch_s:g} s")
        self.rate_hz = float(rate_hz)
        self.mode = mode
        self.epoch_ns = int(epoch_s) * 10**9
        self._seg = None
        self._segment = None
        self._open = None  # [epoch index, n, sums (3,)] of the epoch still filling

    def _bin(self, t: np.ndarray, v: np.ndarray, segment: int, final: bool) -> EpochCounts:
        out = []
        if t.shape[0]:
            e = t // self.epoch_ns
            cut = np.flatnonzero(np.diff(e)) + 1
            starts = np.concatenate([[0], cut])
            sums = np.add.reduceat(v, starts, axis=0)
            ns = np.diff(np.append(starts, t.shape[0]))
            idx = e[starts]
            if self._open is not None and self._open[0] == idx[0]:
                sums[0] += self._open[2]
                ns[0] += self._open[1]
                self._open = None
            if self._open is not None:
                out.append((self._open[0], self._open[1], self._open[2]))
                self._open = None
            for k in range(len(idx) - 1):
                out.append((int(idx[k]), int(ns[k]), sums[k]))
            self._open = [int(idx[-1]), int(ns[-1]), sums[-1].copy()]
        if final and self._open is not None:
            out.append((self._open[0], self._open[1], self._open[2]))
            self._open = None
        if not out:
            return EpochCounts.empty()
        return EpochCounts(np.array([o[0] for o in out], np.int64) * self.epoch_ns,
                           np.array([o[1] for o in out], np.int64),
                           np.array([o[2] for o in out], np.float64).reshape(-1, 3),
                           np.full(len(out), segment, np.int64))

    def _end_segment(self) -> EpochCounts:
        if self._seg is None:
            return EpochCounts.empty()
        t, v = self._seg.flush()
        return self._bin(t, v, self._segment, final=True)

    def push(self, batch: CorrectedBatch) -> EpochCounts:
        if batch.n == 0:
            return EpochCounts.empty()
        parts = []
        if batch.segment != self._segment:
            parts.append(self._end_segment())
            self._seg = _SegmentCounts(self.rate_hz, self.mode)
            self._segment = batch.segment
        t, v = self._seg.push(batch.time_ns, batch.accel)
        parts.append(self._bin(t, v, batch.segment, final=False))
        return EpochCounts.concat(parts)

    def flush(self) -> EpochCounts:
        out = self._end_segment()
        self._seg = None
        self._segment = None
        return out
