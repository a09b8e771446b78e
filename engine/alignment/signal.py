"""The alignment signal: each device's stream put on a common-rate time grid and turned into
the Brønd et al. (2021) activity signal, incrementally.

Two stages, both streaming:

* ``GridResampler`` takes a device's Blocks one at a time and yields ‖a‖ − 1 (g) on the uniform
  grid ``t0 + k / rate`` of the device's own clock (linear interpolation between samples; grid
  points in a gap between samples, or across a segment boundary, are NaN: nothing is imputed).
  It carries the last sample across Blocks, so the output does not depend on how the input was cut.
* ``brond_filter`` turns a stretch of that grid signal into the correlation signal: dead band
  (|x| < 0.068 g -> 0), 4th-order Butterworth band-pass 0.1-7 Hz run forward and backward, absolute
  value. The lag estimator filters each 1 h block together with a few minutes of its neighbours
  (``FILTER_PAD_S``), which reproduces a whole-recording forward-backward pass to far below the
  correlation noise while holding only one block in memory.

Per-unit temperatures are binned into 60 s bins (``TemperatureTrack``) for the optional
crystal-temperature drift term.

Method constants are the paper's (Brønd JC, Pedersen NH, Froberg A, Aadland E, Grøntved A,
Sensors 21:4777, 2021; see /work/shared/specs/alignment.md); they are not device constants.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator, Optional

import numpy as np

from stillpoint.engine.core.blocks import Block
from stillpoint.engine.operators.base import accel_g_columns

from . import filtering

# ---------------------------------------------------------------- Brønd 2021 method constants
COMMON_RATE_HZ = 30.0  # both recordings resampled to 30 Hz before anything else
DEAD_BAND_G = 0.068  # |‖a‖-1| below this is set to zero
BAND_HZ = (0.1, 7.0)  # Butterworth band-pass edges
BUTTER_ORDER = 4  # Butterworth order (Matlab butter(4, [..], 'bandpass'): 8 poles)
ACTIVITY_MIN_G = 0.01  # a block is used only if mean |‖a‖-1| exceeds this in both devices
BLOCK_S = 3600.0  # non-overlapping 1 h blocks
MAX_LAG_SAMPLES = 1000  # cross-correlation search +-1000 samples (33.3 s at 30 Hz)
MIN_BLOCKS = 4  # fewer valid blocks -> the second recording is not aligned

# ---------------------------------------------------------------- our choices (documented)
FILTER_PAD_S = 180.0  # neighbouring signal filtered with each block (0.1 Hz high-pass settles)
GAP_FACTOR = 4.0  # samples further apart than GAP_FACTOR nominal periods form a gap
MAX_PIECE = 1 << 16  # grid samples per yielded piece (bounded memory across long gaps)
TEMP_BIN_S = 60.0  # temperature track resolution


def magnitude_minus_one(block: Block, out: Optional[np.ndarray] = None) -> np.ndarray:
    """‖a‖ − 1 in g per sample, float64, column by column (several times faster than the (n, 3)
    forms; the squares are added in the order numpy's ``einsum("ij,ij->i")`` adds three terms,
    x + z then + y, so the numbers are those of the einsum form).

    Signed counts of at most 16 bits with no zero offset and one power-of-two scale (every AX file):
    the sum of the squared counts is an exact integer (< 2**32, summed in uint32) and
    ``sqrt(sum) / counts_per_g`` is bit for bit ``sqrt(sum of (counts / counts_per_g)**2)``
    (every step is exact or a correctly rounded operation scaled by a power of two), at a
    third of the memory traffic. ``out``: an (n,) float64 array to write into."""
    acc = block.accel
    cpg = np.asarray(block.accel_counts_per_g, np.float64)
    if (acc.dtype.kind == "i" and acc.dtype.itemsize <= 2 and acc.ndim == 2
            and not np.any(block.accel_zero) and np.all(cpg == cpg[0])
            and cpg[0] > 0 and np.frexp(cpg[0])[0] == 0.5):
        n = acc.shape[0]
        s = np.empty(n, np.uint32)
        t = np.empty(n, np.uint32)
        s[...] = acc[:, 0]  # negative counts wrap modulo 2**32: their squares are still exact
        np.multiply(s, s, out=s)
        for j in (2, 1):
            t[...] = acc[:, j]
            np.multiply(t, t, out=t)
            np.add(s, t, out=s)
        out = np.sqrt(s, out=out, dtype=np.float64)
        out *= 1.0 / cpg[0]
        out -= 1.0
        return out
    g = accel_g_columns(block)
    x, y, z = g[:, 0], g[:, 1], g[:, 2]
    out = np.multiply(x, x, out=out)
    out += z * z
    out += y * y
    np.sqrt(out, out=out)
    out -= 1.0
    return out


def band_pass_sos(rate: float, order: int = BUTTER_ORDER, band: tuple = BAND_HZ) -> np.ndarray:
    """``scipy.signal.butter(order, band, btype="bandpass", fs=rate, output="sos")``."""
    return filtering.band_pass_sos(rate, order, band)


def brond_filter(x: np.ndarray, rate: float, dead_band: float = DEAD_BAND_G) -> np.ndarray:
    """Dead band, zero-phase band-pass, absolute value (NaN = no data, treated as 0 g)."""
    y = np.nan_to_num(np.asarray(x, dtype=np.float64), nan=0.0, copy=True)
    y[np.abs(y) < dead_band] = 0.0
    sos = band_pass_sos(float(rate))
    if y.size > 3 * (2 * sos.shape[0] + 1):
        y = filtering.sosfiltfilt(sos, y)  # scipy.signal.sosfiltfilt's numbers
    else:  # too short to filter: no usable signal
        y[:] = 0.0
    return np.abs(y)


class GridResampler:
    """Streaming resampling of one device's ‖a‖ − 1 onto the grid ``t0_ns + k / rate``.

    ``push(block)`` yields ``(k0, values)`` pieces in increasing, contiguous k (the first piece
    starts at the first grid point after the device's first sample; across a segment break
    longer than ``MAX_PIECE`` grid points k jumps, the points between being NaN). ``nominal_rate`` sets the gap
    tolerance: consecutive samples further apart than ``GAP_FACTOR / nominal_rate`` seconds (or in
    different segments) leave the grid points between them NaN.
    """

    def __init__(self, t0_ns: int, rate: float = COMMON_RATE_HZ, nominal_rate: float = 100.0,
                 gap_s: Optional[float] = None):
        self.t0_ns = int(t0_ns)
        self.rate = float(rate)
        self.gap_s = float(gap_s) if gap_s is not None else GAP_FACTOR / float(nominal_rate)
        self.k_next: Optional[int] = None  # next grid index to emit
        self._last_t: Optional[float] = None  # carried last sample (s since t0)
        self._last_v: float = np.nan
        self._last_segment: Optional[int] = None
        self.samples_in = 0
        self.samples_dropped = 0  # non-increasing timestamps
        self.first_time_s: Optional[float] = None
        self.last_time_s: Optional[float] = None
        self.gaps: list[tuple[float, float]] = []  # (last sample before, first after), s
        self.min_gap_report_s = max(1.0, self.gap_s)
        self._buf_t = self._buf_v = self._buf_d = np.empty(0)

    def _buffers(self, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Times, values and differences of n + 1 samples in arrays reused across blocks (fresh
        ~2 MB temporaries every block cost more in page faults than the arithmetic on them)."""
        if self._buf_t.shape[0] < n + 1:
            size = max(n + 1, 2 * self._buf_t.shape[0])
            self._buf_t, self._buf_v, self._buf_d = np.empty(size), np.empty(size), np.empty(size)
        return self._buf_t[:n + 1], self._buf_v[:n + 1], self._buf_d[:n]

    def push(self, block: Block) -> Iterator[tuple[int, np.ndarray]]:
        if block.n == 0:
            return
        bt, bv, _ = self._buffers(block.n)
        # slot 0 stays free for the sample carried from the previous block
        t = np.subtract(block.time_ns, self.t0_ns, out=bt[1:], casting="unsafe")  # exact ints
        t *= 1e-9
        v = magnitude_minus_one(block, out=bv[1:])
        yield from self._push(t, v, block.segment, front=True)

    def push_arrays(self, t: np.ndarray, v: np.ndarray, segment: int = 0
                    ) -> Iterator[tuple[int, np.ndarray]]:
        """Same as ``push`` from times (s since t0, increasing) and values."""
        yield from self._push(np.asarray(t, np.float64), np.asarray(v, np.float64), segment)

    def _push(self, t: np.ndarray, v: np.ndarray, segment: int, front: bool = False
              ) -> Iterator[tuple[int, np.ndarray]]:
        """``front``: t and v are views of ``_buf_t[1:]`` / ``_buf_v[1:]`` (slot 0 is free)."""
        self.samples_in += t.size
        # drop samples that do not advance the clock (they cannot be placed on the grid)
        if t.size > 1:
            if not np.all(t[1:] > t[:-1]):  # np.diff(t) > 0, without the differences
                run_max = np.maximum.accumulate(t)
                ok = np.concatenate([[True], t[1:] > run_max[:-1]])
                self.samples_dropped += int((~ok).sum())
                t, v, front = t[ok], v[ok], False
        break_before = self._last_segment is not None and segment != self._last_segment
        if self._last_t is not None:
            if t[0] <= self._last_t:
                keep = t > self._last_t
                self.samples_dropped += int((~keep).sum())
                t, v, front = t[keep], v[keep], False
                if t.size == 0:
                    return
            if not break_before:
                if front:  # the carried sample goes into the free slot
                    n = t.size
                    t, v = self._buf_t[:n + 1], self._buf_v[:n + 1]
                    t[0], v[0] = self._last_t, self._last_v
                else:
                    t = np.concatenate([[self._last_t], t])
                    v = np.concatenate([[self._last_v], v])
        dt = None
        if t.size > 1:
            dt = self._buf_d[:t.size - 1] if front and self._buf_d.shape[0] >= t.size - 1 \
                else np.empty(t.size - 1)
            np.subtract(t[1:], t[:-1], out=dt)  # np.diff(t)
        if self.first_time_s is None:
            self.first_time_s = float(t[0])
        # record interruptions of sampling (halts, restarts) for the report
        if break_before and self._last_t is not None and t[0] - self._last_t >= 0:
            self.gaps.append((self._last_t, float(t[0])))
        if t.size > 1:
            big = np.nonzero(dt >= self.min_gap_report_s)[0]
            for i in big[:1000]:
                if not (i == 0 and self._last_t is not None and t[0] == self._last_t
                        and self.gaps and self.gaps[-1][1] == float(t[1])):
                    self.gaps.append((float(t[i]), float(t[i + 1])))
        self._last_segment = segment
        self.last_time_s = float(t[-1])
        k_first = int(np.ceil(t[0] * self.rate - 1e-9))
        if self.k_next is None:
            self.k_next = k_first
        k_last = int(np.floor(t[-1] * self.rate + 1e-9))
        # grid points between the previous segment's last sample and this one's first: NaN
        # (across a break longer than a piece, k jumps instead: the points between are NaN to
        # every consumer, and a clock that jumps months would be millions of them)
        if self.k_next < k_first:
            if k_first - self.k_next <= MAX_PIECE:
                yield from self._nan_pieces(self.k_next, k_first)
            self.k_next = k_first
        self._last_t, self._last_v = float(t[-1]), float(v[-1])
        if k_last < self.k_next:
            return
        big_gap = dt > self.gap_s if dt is not None else np.zeros(0, bool)
        for k0 in range(self.k_next, k_last + 1, MAX_PIECE):
            k1 = min(k_last + 1, k0 + MAX_PIECE)
            tk = np.arange(k0, k1, dtype=np.float64) / self.rate
            out = np.interp(tk, t, v)
            if big_gap.any():
                j = np.clip(np.searchsorted(t, tk, side="right") - 1, 0, max(t.size - 2, 0))
                exact = (np.abs(t[j] - tk) <= 1e-9) | (np.abs(t[np.minimum(j + 1, t.size - 1)] - tk) <= 1e-9)
                if t.size > 1:
                    out[big_gap[j] & ~exact] = np.nan
            yield k0, out
        self.k_next = k_last + 1

    def _nan_pieces(self, k0: int, k1: int) -> Iterator[tuple[int, np.ndarray]]:
        for a in range(k0, k1, MAX_PIECE):
            yield a, np.full(min(k1, a + MAX_PIECE) - a, np.nan)


@dataclass
class TemperatureTrack:
    """Mean device temperature per ``TEMP_BIN_S`` bin of the grid time axis (s since t0)."""

    bin_s: float = TEMP_BIN_S

    def __post_init__(self):
        self._sum: dict[int, float] = {}
        self._cnt: dict[int, int] = {}

    def push(self, time_s: np.ndarray, temperature_c: np.ndarray) -> None:
        ok = np.isfinite(temperature_c) & np.isfinite(time_s)
        if not ok.any():
            return
        b = np.floor(np.asarray(time_s)[ok] / self.bin_s).astype(np.int64)
        ub, inv = np.unique(b, return_inverse=True)
        s = np.bincount(inv, weights=np.asarray(temperature_c)[ok])
        c = np.bincount(inv)
        for key, ss, cc in zip(ub.tolist(), s.tolist(), c.tolist()):
            self._sum[key] = self._sum.get(key, 0.0) + ss
            self._cnt[key] = self._cnt.get(key, 0) + cc

    def push_block(self, block: Block, t0_ns: int) -> None:
        if block.m == 0 or block.temperature_c.size == 0:
            return
        idx = np.clip(block.unit_start, 0, block.n - 1)
        self.push((block.time_ns[idx] - t0_ns).astype(np.float64) * 1e-9, block.temperature_c)

    def __len__(self) -> int:
        return len(self._sum)

    def series(self, b0: int, b1: int) -> np.ndarray:
        """Temperature for bins [b0, b1), gaps filled with the nearest known value (NaN if none)."""
        n = b1 - b0
        out = np.full(n, np.nan)
        if not self._sum:
            return out
        keys = np.array(sorted(self._sum))
        vals = np.array([self._sum[k] / self._cnt[k] for k in keys])
        idx = np.arange(b0, b1)
        pos = np.clip(np.searchsorted(keys, idx), 0, keys.size - 1)
        prev = np.clip(pos - 1, 0, keys.size - 1)
        use_prev = np.abs(keys[prev] - idx) < np.abs(keys[pos] - idx)
        out[:] = np.where(use_prev, vals[prev], vals[pos])
        return out
