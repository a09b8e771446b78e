"""Nonwear and clipping per 15-min window: GGIR's rule (van Hees et al. 2013) as a streaming operator.

The rule, as published in GGIR (``detect_nonwear_clipping``, ``g.weardec``):

* **windows**: 15-min *medium* windows (here on the UTC clock grid, :00/:15/:30/:45) and a 60-min
  *long* window that is tested for each medium window;
* **still axis**: over the long window an axis is still when its range (max - min) is below 50 mg
  and its SD below 13 mg; the window's *nonwear score* is the number of still axes (0-3);
  **nonwear** when the score is >= 2. A single score of 1 between two windows scoring >= 2
  becomes 2;
* **2013 form**: the long window is centred on the medium window (it covers half of the window
  two before, the one before, the window, the one after and half of the window two after) and
  only the medium window takes the flag. The first three windows of a recording use the first
  hour; the last four use the last three windows (GGIR's edge rule);
* **2023 form** (default): the long window starts at the medium window's left edge, the range and
  SD are computed on every ``ceil(rate / 5)``-th sample (about 5 Hz), and when an axis is still
  the whole long window (this medium window and the next three) takes that axis's flag;
* **clipping**: per medium window and axis, the share of samples beyond ``clip_g`` (default
  0.5 g below the device range, 7.5 g for a +-8 g device); a single sample beyond 1.5 x
  ``clip_g`` marks the whole window; the window is **clipping** when the largest share is above
  0.3.

Streaming: samples are reduced to statistics of 7.5-min half windows (count, mean, sum of squared
deviations, min, max per axis, of all samples in the 2013 form and of the 5 Hz subsample in the
2023 form; clipping counts), computed on each half window's contiguous samples, and long windows
are combined from them (Chan's pairwise update), so results do not depend on how the input was cut
into blocks. A medium window is final once data 75 min past its start have arrived (or at the end
of the stream); state is a few half-window records. The 5 Hz subsample of the 2023 form starts at
each half window's first sample (GGIR: at the long window's first sample), the only difference from
GGIR's indexing.
Not done here: GGIR's later ``g.weardec`` pass that turns short wear periods between nonwear into
nonwear (it needs the whole recording).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

from .base import ring_capacity
from .binning import BinChunk, TimeBinner, bin_cuts

MEDIUM_S = 900.0  # GGIR windowsizes[2]: 15-min windows for nonwear and clipping
LONG_S = 3600.0  # GGIR windowsizes[3]: the 60-min window tested for each medium window
SD_CRITERION_G = 0.013  # GGIR sdcriter: per-axis SD below 13 mg
RANGE_CRITERION_G = 0.05  # GGIR racriter: per-axis range below 50 mg
NONWEAR_MIN_AXES = 2  # GGIR g.impute wearthreshold: nonwear when >= 2 axes are still
CLIP_SHARE = 0.3  # GGIR g.weardec: clipping when more than 30 % of a window's samples clip
CLIP_MARGIN_G = 0.5  # GGIR: clipping threshold 0.5 g below the device's dynamic range
CLIP_DEFAULT_G = 7.5  # GGIR's threshold for the usual +-8 g devices
SUBSAMPLE_HZ = 5.0  # 2023 form: range and SD on every ceil(sf/5)-th sample
VERSIONS = ("2013", "2023")
DEFAULT_VERSION = "2023"


def clip_threshold_g(range_g) -> float:
    """GGIR's clipping threshold for a device range: range - 0.5 g (7.5 g when unknown)."""
    if range_g is None or not range_g or range_g <= CLIP_MARGIN_G:
        return CLIP_DEFAULT_G
    return float(range_g) - CLIP_MARGIN_G


@dataclass
class NonwearWindows:
    """One row per medium window (consecutive, gaps included)."""

    start_ns: np.ndarray  # (k,) int64 window start on the UTC grid
    n: np.ndarray  # (k,) int64 samples in the window
    score: np.ndarray  # (k,) int8 still axes, 0-3 (after the single-1 rule)
    nonwear: np.ndarray  # (k,) bool
    clip_share: np.ndarray  # (k,) float largest per-axis share of clipping samples (NaN: no data)
    clipping: np.ndarray  # (k,) bool

    def __len__(self) -> int:
        return int(self.start_ns.shape[0])

    @staticmethod
    def empty() -> "NonwearWindows":
        return NonwearWindows(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int8),
                              np.zeros(0, bool), np.zeros(0), np.zeros(0, bool))

    @staticmethod
    def concat(parts) -> "NonwearWindows":
        parts = [p for p in parts if len(p)]
        if not parts:
            return NonwearWindows.empty()
        return NonwearWindows(**{f.name: np.concatenate([getattr(p, f.name) for p in parts])
                                 for f in fields(NonwearWindows)})


class _Stats:
    """Per-axis count, mean, sum of squared deviations, min, max (mergeable)."""

    __slots__ = ("n", "mean", "m2", "lo", "hi")

    def __init__(self, n, mean, m2, lo, hi):
        self.n, self.mean, self.m2, self.lo, self.hi = float(n), mean, m2, lo, hi

    def merge(self, o: "_Stats") -> "_Stats":
        if o.n == 0:
            return self
        if self.n == 0:
            return o
        n = self.n + o.n
        d = o.mean - self.mean
        return _Stats(n, self.mean + d * (o.n / n), self.m2 + o.m2 + d * d * (self.n * o.n / n),
                      np.minimum(self.lo, o.lo), np.maximum(self.hi, o.hi))

    def still(self, sd_g: float, range_g: float) -> np.ndarray:
        """(3,) bool: range below ``range_g`` and sample SD below ``sd_g`` (R's ``sd``: n - 1)."""
        if self.n < 2:
            return np.zeros(3, bool)
        sd = np.sqrt(self.m2 / (self.n - 1.0))
        return ((self.hi - self.lo) < range_g) & (sd < sd_g)


_EMPTY = _Stats(0, np.zeros(3), np.zeros(3), np.full(3, np.inf), np.full(3, -np.inf))


def _bin_stats(a: np.ndarray, st: np.ndarray, cnt: np.ndarray) -> list:
    """_Stats of each bin of rows a[st[i]:st[i]+cnt[i]] (two passes: mean, then deviations)."""
    mean = np.empty((len(cnt), 3))
    m2 = np.empty((len(cnt), 3))
    for j in range(3):
        c = a[:, j]
        m = np.add.reduceat(c, st) / cnt
        mean[:, j] = m
        dev = c - np.repeat(m, cnt)
        m2[:, j] = np.add.reduceat(dev * dev, st)
    lo = np.minimum.reduceat(a, st, axis=0)
    hi = np.maximum.reduceat(a, st, axis=0)
    return [_Stats(cnt[i], mean[i], m2[i], lo[i], hi[i]) for i in range(len(cnt))]


def subsample_rows(st: np.ndarray, cnt: np.ndarray, step: int) -> tuple:
    """Every ``step``-th row of each bin of rows ``st[i] : st[i] + cnt[i]``, counted from the
    bin's first row: (rows, bin starts and counts within the subsample)."""
    sub_cnt = (cnt + (step - 1)) // step
    sub_st = np.concatenate([[0], np.cumsum(sub_cnt)[:-1]]).astype(np.int64)
    rows = np.arange(int(sub_cnt.sum()), dtype=np.int64) * step - np.repeat(sub_st * step - st, sub_cnt)
    return rows, sub_st, sub_cnt


def within(a: np.ndarray, limit: float) -> bool:
    """No sample of a (n, 3) beyond +-``limit`` on any axis (False when a holds NaN)."""
    return bool(a.max() <= limit and a.min() >= -limit)


def clip_counts(a: np.ndarray, st: np.ndarray, clip_g: float) -> tuple[np.ndarray, np.ndarray]:
    """Per bin of rows from ``st`` and axis: samples beyond ``clip_g`` (int64) and whether any is
    beyond 1.5 x ``clip_g`` (bool); (k, 3) each."""
    if within(a, clip_g):
        return np.zeros((st.shape[0], 3), np.int64), np.zeros((st.shape[0], 3), bool)
    over = np.abs(a) > clip_g
    hard = np.abs(a) > 1.5 * clip_g
    return np.add.reduceat(over.astype(np.int64), st, axis=0), np.logical_or.reduceat(hard, st, axis=0)


@dataclass
class HalfWindows:
    """Half windows reduced to what the rule uses: bin numbers, sample counts, the statistics the
    rule tests (``_Stats`` each), clipping counts and flags beyond 1.5 x the threshold ((k, 3))."""

    bins: np.ndarray
    n: np.ndarray
    still: list
    clip: np.ndarray
    hard: np.ndarray


class SubsampleBinner:
    """The half windows of a stream, cut where a clock-aligned ``TimeBinner`` cuts them, reduced as
    the 2023 form needs them without holding their samples: per half window its sample count,
    clipping counts and every ``step``-th sample from its first one, gathered across blocks.
    ``push(segment, time_ns, accel=(n, 3))`` / ``flush()`` -> list of ``HalfWindows`` now complete."""

    def __init__(self, width_s: float, step: int, clip_g: float):
        self.width_ns = int(round(width_s * 1e9))
        self.step, self.clip_g = step, clip_g
        self.segment = None
        self.pending_bin = None  # the half window still open
        self._open()

    def _open(self) -> None:
        self._n = 0  # samples of the open half window so far
        self._sub = []  # its subsample rows, (m, 3) C-ordered copies
        self._clip = np.zeros(3, np.int64)
        self._hard = np.zeros(3, bool)

    def _extend(self, a: np.ndarray) -> None:
        """Rows of the open half window (its subsample continues from its first sample)."""
        if not a.shape[0]:
            return
        self._sub.append(np.ascontiguousarray(a[(-self._n) % self.step::self.step]))
        clip, hard = clip_counts(a, np.zeros(1, np.int64), self.clip_g)
        self._clip += clip[0]
        self._hard |= hard[0]
        self._n += a.shape[0]

    def _close(self) -> list:
        if self.pending_bin is None:
            return []
        sub = np.concatenate(self._sub)
        out = HalfWindows(np.array([self.pending_bin], np.int64), np.array([self._n], np.int64),
                          _bin_stats(sub, np.zeros(1, np.int64), np.array([sub.shape[0]], np.int64)),
                          self._clip[None, :], self._hard[None, :])
        self.pending_bin = None
        self._open()
        return [out]

    def push(self, segment: int, time_ns: np.ndarray, accel: np.ndarray) -> list:
        n = time_ns.shape[0]
        if n == 0:
            return []
        out = []
        if segment != self.segment:
            out += self._close()
            self.segment = segment
        start, stop, st, bins, last = bin_cuts(time_ns, 0, self.width_ns, self.pending_bin)
        if self.pending_bin is not None:
            self._extend(accel[:start])
            if start == n:
                return out
            out += self._close()
        if stop > start:
            a = accel[start:stop]
            cnt = np.diff(np.append(st, a.shape[0]))
            rows, sub_st, sub_cnt = subsample_rows(st, cnt, self.step)
            clip, hard = clip_counts(a, st, self.clip_g)
            out.append(HalfWindows(bins, cnt, _bin_stats(a[rows], sub_st, sub_cnt), clip, hard))
        self.pending_bin = last
        self._extend(accel[stop:])
        return out

    def flush(self) -> list:
        return self._close()


class _Half:
    """Statistics of one 7.5-min half window (merged over segments in arrival order): ``still``
    holds those the rule tests (all samples in the 2013 form, the 5 Hz subsample in the 2023 form)."""

    __slots__ = ("still", "clip", "hard", "n")

    def __init__(self):
        self.still = _EMPTY
        self.clip = np.zeros(3)
        self.hard = np.zeros(3, bool)
        self.n = 0


class NonwearOperator:
    """push(batch with ``time_ns``, ``accel`` (n, 3) g, ``segment``) -> NonwearWindows now final;
    flush() -> the rest."""

    def __init__(self, rate_hz: float, *, version: str = DEFAULT_VERSION, clip_g: float = CLIP_DEFAULT_G,
                 sd_g: float = SD_CRITERION_G, range_g: float = RANGE_CRITERION_G,
                 medium_s: float = MEDIUM_S, long_s: float = LONG_S):
        if version not in VERSIONS:
            raise ValueError(f"nonwear version must be one of {VERSIONS}, not {version!r}")
        ratio = long_s / medium_s
        if ratio != int(ratio) or int(ratio) < 1:
            raise ValueError("the long window must be a whole number of medium windows")
        self.version = version
        self.rate_hz = float(rate_hz)
        self.clip_g = float(clip_g)
        self.sd_g, self.range_g = float(sd_g), float(range_g)
        self.medium_ns = int(round(medium_s * 1e9))
        self.per_long = int(ratio)  # medium windows per long window (4)
        self.step = max(1, math.ceil(self.rate_hz / SUBSAMPLE_HZ))
        if version == "2013":  # statistics of all samples: half windows gathered whole
            self._binner = TimeBinner(medium_s / 2.0, {"accel": (np.float64, (3,))}, align="clock",
                                      capacity=ring_capacity(medium_s / 2.0, rate_hz))
        else:
            self._binner = SubsampleBinner(medium_s / 2.0, self.step, self.clip_g)
        self._half: dict[int, _Half] = {}
        self._checks: dict[int, np.ndarray] = {}  # 2023: still axes of the long window at window c
        self._flags: dict[int, np.ndarray] = {}  # per window: still axes (3,) bool before scoring
        self.first_w = None
        self.last_w = None
        self.next_w = None  # next window to emit
        self.windows = 0
        self.nonwear_windows = 0
        self.clipping_windows = 0

    # ------------------------------------------------------------------ statistics
    def _reduce(self, chunks: list[BinChunk]) -> list:
        """2013 form: whole half windows reduced to the statistics of all their samples."""
        out = []
        for ch in chunks:
            a, st, cnt = ch.cols["accel"], ch.starts, ch.counts
            clip, hard = clip_counts(a, st, self.clip_g)
            out.append(HalfWindows(ch.bins, cnt, _bin_stats(a, st, cnt), clip, hard))
        return out

    def _take(self, parts: list) -> None:
        for part in parts:
            for i, b in enumerate(part.bins):
                h = self._half.get(int(b))
                if h is None:
                    h = self._half[int(b)] = _Half()
                h.still = h.still.merge(part.still[i])
                h.clip = h.clip + part.clip[i]
                h.hard = h.hard | part.hard[i]
                h.n += int(part.n[i])

    def _parts(self, got: list) -> list:
        """``HalfWindows`` of what the binner returned (the 2013 form's binner returns samples)."""
        return self._reduce(got) if self.version == "2013" else got

    def _long(self, h0: int, h1: int) -> _Stats:
        s = _EMPTY
        for h in range(h0, h1):
            x = self._half.get(h)
            if x is not None:
                s = s.merge(x.still)
        return s

    # ------------------------------------------------------------------ the rule
    def _still_2013(self, w: int, final: bool) -> np.ndarray:
        k = w - self.first_w
        crit = self.per_long // 2 + 1  # GGIR: (window / window2) / 2 + 1 = 3
        if k + 1 <= crit:  # first windows: the first long window of the recording
            h0, h1 = 2 * self.first_w, 2 * (self.first_w + self.per_long)
        elif final and k + 1 >= (self.last_w - self.first_w + 1) - crit:  # last windows
            h0, h1 = 2 * (self.last_w + 1 - crit), 2 * (self.last_w + 1)
        else:  # centred on the middle of window w
            h0, h1 = 2 * w + 1 - self.per_long, 2 * w + 1 + self.per_long
        return self._long(h0, h1).still(self.sd_g, self.range_g)

    def _check_2023(self, c: int) -> np.ndarray:
        r = self._checks.get(c)
        if r is None:
            r = self._long(2 * c, 2 * (c + self.per_long)).still(self.sd_g, self.range_g)
            self._checks[c] = r
        return r

    def _axes(self, w: int, final: bool) -> np.ndarray:
        f = self._flags.get(w)
        if f is None:
            if self.version == "2013":
                f = self._still_2013(w, final)
            else:
                f = np.zeros(3, bool)
                for c in range(max(self.first_w, w - self.per_long + 1), w + 1):
                    f = f | self._check_2023(c)
            self._flags[w] = f
        return f

    def _score(self, w: int, final: bool) -> int:
        s = int(self._axes(w, final).sum())
        if s == 1 and w > self.first_w and w < self.last_w:
            if self._axes(w - 1, final).sum() > 1 and self._axes(w + 1, final).sum() > 1:
                s = 2
        return s

    def _emit(self, final: bool) -> NonwearWindows:
        if self.first_w is None:
            return NonwearWindows.empty()
        # window w is final once data from window w + per_long + 1 on have been seen
        stop = self.last_w + 1 if final else self.last_w - self.per_long
        if stop <= self.next_w:
            return NonwearWindows.empty()
        ws = range(self.next_w, stop)
        k = len(ws)
        n = np.zeros(k, np.int64)
        score = np.zeros(k, np.int8)
        share = np.full(k, np.nan)
        for i, w in enumerate(ws):
            score[i] = self._score(w, final)
            a, b = self._half.get(2 * w), self._half.get(2 * w + 1)
            parts = [x for x in (a, b) if x is not None and x.n]
            if parts:
                cnt = sum(x.n for x in parts)
                clip = sum(x.clip for x in parts) / cnt
                hard = np.logical_or.reduce([x.hard for x in parts])
                clip = np.where(hard, 1.0, clip)
                n[i], share[i] = cnt, float(clip.max())
        self.next_w = stop
        self._forget()
        nonwear = score >= NONWEAR_MIN_AXES
        clipping = np.nan_to_num(share, nan=0.0) > CLIP_SHARE
        self.windows += k
        self.nonwear_windows += int(nonwear.sum())
        self.clipping_windows += int(clipping.sum())
        start = np.arange(ws.start, ws.stop, dtype=np.int64) * self.medium_ns
        return NonwearWindows(start, n, score, nonwear, share, clipping)

    def _forget(self) -> None:
        """Drop the statistics no window still to be emitted can use."""
        keep_w = self.next_w - self.per_long - 1  # 2013 centred window reaches 2 windows back
        first_hour = self.next_w <= self.first_w + self.per_long  # 2013 edge rule still needs it
        for h in [h for h in self._half if h < 2 * keep_w]:
            if not (first_hour and h < 2 * (self.first_w + self.per_long)):
                del self._half[h]
        for d in (self._checks, self._flags):
            for w in [w for w in d if w < keep_w]:
                del d[w]

    # ------------------------------------------------------------------ operator
    def push(self, batch) -> NonwearWindows:
        t = batch.time_ns
        if t.shape[0] == 0:
            return NonwearWindows.empty()
        if self.first_w is None:
            self.first_w = self.next_w = int(t[0]) // self.medium_ns
        self.last_w = max(self.last_w if self.last_w is not None else self.first_w,
                          int(t[-1]) // self.medium_ns)
        a = np.asarray(batch.accel, np.float64)
        self._take(self._parts(self._binner.push(batch.segment, t, accel=a)))
        return self._emit(final=False)

    def flush(self) -> NonwearWindows:
        self._take(self._parts(self._binner.flush()))
        return self._emit(final=True)
