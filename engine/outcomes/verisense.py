"""The Verisense step algorithm (Gu et al. 2017, with Verisense's magnitude threshold) as a
streaming operator on the 15 Hz vector magnitude in g.

The rules, in the reference's order (GGIR ``user-scripts/verisense_count_steps.R``, wadpac/GGIR
@388064b7, a copy of ShimmerEngineering/Verisense-Toolbox ``verisense_count_steps.R`` @dc18f76):

1. peaks (R lines 75-106): the samples are cut into consecutive segments of ``k`` from the first
   sample; a segment's first maximum is a peak when it is also the first maximum of the ``2*half_k+1``
   samples centred on it (``half_k = round(k/2)``, R rounds half to even; the window is clipped at
   the end of the input; a peak closer than ``half_k`` samples to the start never qualifies, as
   the clipped window's centre index is then another sample);
2. magnitude (line 109): the peak's value ``> mag_thres``;
3. periodicity (lines 117-119): samples to the next peak of step 2, ``period_min < p < period_max``
   (the last peak has none and is dropped);
4. similarity (lines 135-137): ``-|mag[i+2] - mag[i]| > sim_thres`` over the peaks of step 3 (the
   last two have none and are dropped);
5. continuity (lines 140-158): for each peak ``i`` of step 4 from the ``cont_thres``-th to the one
   before last, of the ``cont_thres`` spans between consecutive peaks ``i-cont_thres+1 .. i+1``
   (both ends included), at least ``cont_win_size`` have a sample variance ``> var_thres``;
   nothing passes when step 4 kept five peaks or fewer.

A step is counted at each peak that passes; steps per second as the reference returns them
(``findInterval`` over 15-sample seconds). Both published parameter sets (R's ``coeffs``):

* ``original``: ``c(3, 5, 15, -0.5, 3, 4, 0.001, 1.2)`` (Verisense-Toolbox ``myscript.R`` line 3);
* ``rowlands2022``: ``c(4, 4, 20, -1.0, 4, 4, 0.01, 1.25)``, the revision evaluated by Rowlands et
  al. 2022 (doi:10.1080/02640414.2022.2147134; GGIR ``docs/articles/StepCadenceAnalysis.md``
  lines 36 and 56-57, and the R file's lines 39-40).

Streaming: each step of the list is a rule over neighbouring peaks, so the operator keeps only the
last few peaks, with the running sums of ``(acc - 1)`` and its square at each (the spans'
variances come from differences of those sums), never the samples between them. The reference
sees one whole input; a stream has no end, so the stream is cut where the peaks of step 3 (or of
step 4) are more than ``horizon_s`` apart (default 10 min), and each part is treated as one
input: its last peaks are dropped as the reference drops the input's last, and its five-peak rule
applies to it. An input with no such gap gives the reference's steps exactly. Not reproduced: the
reference's first rule, no steps at all when the whole input's magnitude has a standard deviation
below 0.025 g (a property of the whole call, which GGIR makes per block of data).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

FS_HZ = 15  # the reference's sample rate (R line 56; GGIR resamples to expected_sample_rate 15)
HORIZON_S = 600.0


@dataclass(frozen=True)
class VerisenseParams:
    name: str
    k: int
    period_min: int
    period_max: int
    sim_thres: float
    cont_win_size: int
    cont_thres: int
    var_thres: float
    mag_thres: float


PARAMETER_SETS = {
    "original": VerisenseParams("original", 3, 5, 15, -0.5, 3, 4, 0.001, 1.2),
    "rowlands2022": VerisenseParams("rowlands2022", 4, 4, 20, -1.0, 4, 4, 0.01, 1.25),
}

_EMPTY = np.zeros((0, 4))  # rows: loc, mag, s1 (sum of acc-1 before loc), s2 (sum of squares)


def _r_round_half(k: int) -> int:
    return int(round(k / 2))  # Python rounds half to even, as R's round()


class VerisenseCounter:
    """Push the 15 Hz magnitude (g) in pieces of any size; ``take()`` returns the sample indices
    (from 0 at the first sample pushed) of the steps decided so far, in increasing order; ``flush()``
    ends the input. ``final_before`` is the sample index below which no step can still be added."""

    def __init__(self, params: VerisenseParams, horizon_s: float = HORIZON_S):
        self.p = params
        self.half_k = _r_round_half(params.k)
        self.horizon = int(round(horizon_s * FS_HZ))
        self.n = 0  # samples pushed
        self._buf = np.zeros(0)  # magnitude from sample _b0
        self._s1 = np.zeros(0)  # running sums before each buffered sample
        self._s2 = np.zeros(0)
        self._b0 = 0
        self._tot1 = 0.0
        self._tot2 = 0.0
        self._next_seg = 0  # first sample of the next segment of k to scan
        self._p1 = _EMPTY  # the last peak of step 2, its period not known yet
        self._p2 = _EMPTY  # up to two peaks of step 3 waiting for their similarity
        self._p2_last = None  # location of the last peak of step 3 in this part
        self._p3 = _EMPTY  # the last cont_thres peaks of step 4 (the last one undecided)
        self._p3_index = 0  # index within the part of the first row of _p3
        self._held: list = []  # steps of a part that has not yet kept six peaks in step 4
        self._out: list = []

    # ------------------------------------------------------------------ input
    def push(self, acc: np.ndarray) -> None:
        acc = np.asarray(acc, dtype=np.float64).ravel()
        if acc.shape[0]:
            y = acc - 1.0
            c1 = np.cumsum(y)
            c2 = np.cumsum(y * y)
            s1 = self._tot1 + np.concatenate([[0.0], c1[:-1]])
            s2 = self._tot2 + np.concatenate([[0.0], c2[:-1]])
            self._tot1 += float(c1[-1])
            self._tot2 += float(c2[-1])
            self._buf = np.concatenate([self._buf, acc])
            self._s1 = np.concatenate([self._s1, s1])
            self._s2 = np.concatenate([self._s2, s2])
            self.n += acc.shape[0]
        self._scan(final=False)

    def flush(self) -> None:
        self._scan(final=True)
        self._p1 = _EMPTY
        self._end_p2_part()

    def take(self) -> np.ndarray:
        out = np.asarray(self._out, dtype=np.int64)
        self._out = []
        return out

    @property
    def final_before(self) -> int:
        cands = [self._next_seg]
        for rows in (self._p1, self._p2, self._p3[-1:]):
            if rows.shape[0]:
                cands.append(int(rows[0, 0]))
        if self._held:
            cands.append(int(self._held[0]))
        return min(cands)

    # ------------------------------------------------------------------ step 1-2
    def _scan(self, final: bool) -> None:
        k, h = self.p.k, self.half_k
        s0 = self._next_seg
        # complete segments whose centred windows are inside the samples (clipped at the end)
        m = max(0, ((self.n if final else self.n - h) - s0) // k)
        peaks = _EMPTY
        if m:
            a0 = s0 - self._b0
            seg = self._buf[a0:a0 + m * k].reshape(m, k)
            loc = s0 + np.arange(m) * k + np.argmax(seg, axis=1)
            pad_r = h if final else 0
            padded = np.concatenate([np.full(h, -np.inf), self._buf, np.full(pad_r, -np.inf)])
            win = sliding_window_view(padded, 2 * h + 1)
            rel = loc - self._b0
            ok = (np.argmax(win[rel], axis=1) == h) & (loc >= h)
            loc = loc[ok]
            rel = rel[ok]
            mag = self._buf[rel]
            keep = mag > self.p.mag_thres
            peaks = np.stack([loc[keep].astype(np.float64), mag[keep], self._s1[rel[keep]],
                              self._s2[rel[keep]]], axis=1)
            self._next_seg = s0 + m * k
        # forget samples no window needs any more
        cut = max(0, self._next_seg - h) - self._b0
        if cut > 0:
            self._buf, self._s1, self._s2 = self._buf[cut:], self._s1[cut:], self._s2[cut:]
            self._b0 += cut
        self._periods(peaks)

    # ------------------------------------------------------------------ step 3
    def _periods(self, peaks: np.ndarray) -> None:
        rows = np.concatenate([self._p1, peaks])
        if rows.shape[0] >= 2:
            per = np.diff(rows[:, 0])
            keep = (per > self.p.period_min) & (per < self.p.period_max)
            done = rows[:-1][keep]
            self._p1 = rows[-1:]
        else:
            done = _EMPTY
            self._p1 = rows
        # a peak with no successor within period_max samples fails its period now
        if self._p1.shape[0] and self._next_seg - self._p1[0, 0] >= self.p.period_max:
            self._p1 = _EMPTY
        self._similarity(done)

    # ------------------------------------------------------------------ step 4
    def _similarity(self, new: np.ndarray) -> None:
        for part in self._split(new, "_p2_last"):
            if part is None:
                self._end_p2_part()
                continue
            rows = np.concatenate([self._p2, part])
            self._p2_last = int(rows[-1, 0])
            if rows.shape[0] >= 3:
                sim = -np.abs(rows[2:, 1] - rows[:-2, 1])
                self._continuity(rows[:-2][sim > self.p.sim_thres])
                self._p2 = rows[-2:]
            else:
                self._p2 = rows
        # no peak of step 3 can come before the pending peak's successor: a gap past the horizon
        known = self._next_seg - self.p.period_max
        if self._p2_last is not None and known - self._p2_last > self.horizon:
            self._end_p2_part()
        elif self._p3.shape[0]:
            first_possible = int(self._p2[0, 0]) if self._p2.shape[0] else known
            if first_possible - int(self._p3[-1, 0]) > self.horizon:
                self._end_p3_part()

    def _split(self, rows: np.ndarray, last_attr: str):
        """``rows`` in parts at gaps longer than the horizon; ``None`` marks a part's end."""
        if not rows.shape[0]:
            return []
        last = getattr(self, last_attr)
        locs = rows[:, 0]
        prev = np.concatenate([[locs[0] if last is None else last], locs[:-1]])
        gaps = np.flatnonzero(locs - prev > self.horizon)
        out, a = [], 0
        for g in gaps.tolist():
            if g > a:
                out.append(rows[a:g])
            out.append(None)
            a = g
        out.append(rows[a:])
        return out

    def _end_p2_part(self) -> None:
        self._p2 = _EMPTY
        self._p2_last = None
        self._end_p3_part()

    # ------------------------------------------------------------------ step 5
    def _continuity(self, new: np.ndarray) -> None:
        if not new.shape[0]:
            return
        if self._p3.shape[0] and new[0, 0] - self._p3[-1, 0] > self.horizon:
            self._end_p3_part()
        # a gap inside the new rows ends the part too
        locs = new[:, 0]
        gaps = np.flatnonzero(np.diff(locs) > self.horizon) + 1
        for part in np.split(new, gaps):
            if self._p3.shape[0] and part[0, 0] - self._p3[-1, 0] > self.horizon:
                self._end_p3_part()
            self._continuity_part(part)

    def _continuity_part(self, new: np.ndarray) -> None:
        c = self.p.cont_thres
        q = np.concatenate([self._p3, new])
        loc = q[:, 0]
        # variance of the span loc[j]..loc[j+1] (both included) from the running sums
        n = loc[1:] - loc[:-1] + 1.0
        y_end = q[1:, 1] - 1.0  # the span's last sample is the next peak: its magnitude
        s1 = q[1:, 2] + y_end - q[:-1, 2]
        s2 = q[1:, 3] + y_end * y_end - q[:-1, 3]
        var = (s2 - s1 * s1 / n) / (n - 1.0)
        v = (var > self.p.var_thres).astype(np.int64)
        cv = np.concatenate([[0], np.cumsum(v)])
        ps = np.arange(max(self._p3.shape[0] - 1, 0), q.shape[0] - 1)
        ps = ps[self._p3_index + ps >= c - 1]  # the reference's loop starts at row cont_thres
        ok = cv[ps + 1] - cv[ps - c + 1] >= self.p.cont_win_size
        steps = loc[ps[ok]].astype(np.int64).tolist()
        count = self._p3_index + q.shape[0]  # peaks of step 4 in this part so far
        if count > 5:
            self._out.extend(self._held + steps)
            self._held = []
        else:
            self._held.extend(steps)
        keep = q[-c:]
        self._p3_index = count - keep.shape[0]
        self._p3 = keep

    def _end_p3_part(self) -> None:
        self._p3 = _EMPTY
        self._p3_index = 0
        self._held = []


def count_steps(acc: np.ndarray, params: VerisenseParams, chunk: int = 0) -> np.ndarray:
    """Step sample indices of a whole 15 Hz magnitude array (pushed in ``chunk``-sample pieces)."""
    vc = VerisenseCounter(params)
    acc = np.asarray(acc, dtype=np.float64)
    step = chunk or max(1, acc.shape[0])
    out = []
    for a in range(0, acc.shape[0], step):
        vc.push(acc[a:a + step])
        out.append(vc.take())
    vc.flush()
    out.append(vc.take())
    return np.concatenate(out) if out else np.zeros(0, np.int64)


def steps_per_second(steps: np.ndarray, n_samples: int) -> np.ndarray:
    """Counts per 15-sample second, as the reference returns them (``ceil(n/15)`` seconds)."""
    n_sec = -(-n_samples // FS_HZ)
    return np.bincount(np.asarray(steps, np.int64) // FS_HZ, minlength=n_sec)[:n_sec]
