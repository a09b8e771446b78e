"""Infant leg-movement detection (Smith et al. 2015 as run by the Oh et al. 2024 reference code).

Pure functions over the median-detrended acceleration norm ``a`` (m/s^2) and angular-velocity
norm ``w`` (rad/s) of one leg, sample constants at the nominal rate ``fs`` (integer, as the
reference uses). Exactly the reference rules (spec static-calibration.md §4.3):

1. labels: count[i] = sign(a[i]) where w[i] > 0 else 0 (gate always open when accel-only);
   th[i] = +1 above T+, -1 below T-, else 0;
2. thresholds: mean - SD of peak heights in [1.0, 3.2501) m/s^2, v1 (excursions above 3.2501
   zeroed before peak finding) or v2 (peaks taken first, then those >= 3.2501 dropped);
3. crossing marks: candidates beyond a threshold with count != 0; a mark at j + 2 when count
   keeps the sign for three samples, else at j; skips and de-duplication as the reference;
4. pairing: consecutive opposite marks at most floor(8 fs / 20) samples apart; first crossing,
   start (walk-back on count with the minimum-|a| refinement), end (first sample back on the
   first lobe's side within ceil(1.5 fs) samples of the start);
5. overlap resolution: start 0 dropped; an overlapping row is shifted within its slack or
   cleared; a cleared row clears the following rows that start before the end of the row
   before it.

The loops run over crossing candidates and marks (a few per movement), never over all samples.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.signal import find_peaks

PEAK_MIN_MS2 = 1.0  # inclusive (reference constants, unverified against Smith 2015: spec §6.19)
PEAK_REJECT_MS2 = 3.2501  # exclusive
PAIR_GAP_AT_20HZ = 8  # samples at 20 Hz (0.4 s)
MAX_MOVEMENT_S = 1.5
VARIANTS = ("v1", "v2")


@dataclass
class Thresholds:
    positive: float
    negative: float
    peaks_positive: int
    peaks_negative: int

    @property
    def usable(self) -> bool:
        return bool(np.isfinite(self.positive) and np.isfinite(self.negative))


def _mean_minus_sd(h: np.ndarray) -> float:
    if h.size == 0:
        return float("nan")
    return float(np.mean(h) - np.std(h))


def thresholds(a: np.ndarray, variant: str = "v2") -> Thresholds:
    """Individual thresholds T+ > 0 > T- of one recording (NaN when there is no peak)."""
    a = np.asarray(a, np.float64)
    if variant == "v2":
        loc, pr = find_peaks(a, height=PEAK_MIN_MS2)
        hp = a[loc[pr["peak_heights"] < PEAK_REJECT_MS2]]
        rect = np.minimum(a, 0.0)
        np.negative(rect, out=rect)  # the rectified negative part, without a second temporary
        locn, prn = find_peaks(rect, height=PEAK_MIN_MS2)
        hn = rect[locn[prn["peak_heights"] < PEAK_REJECT_MS2]]
    elif variant == "v1":
        p = np.where((a > 0) & (a < PEAK_REJECT_MS2), a, 0.0)
        q = np.where((a < 0) & (a > -PEAK_REJECT_MS2), np.abs(a), 0.0)
        hp = find_peaks(p, height=PEAK_MIN_MS2)[1]["peak_heights"]
        hn = find_peaks(q, height=PEAK_MIN_MS2)[1]["peak_heights"]
    else:
        raise ValueError(f"variant must be one of {VARIANTS}, not {variant!r}")
    return Thresholds(_mean_minus_sd(hp), -_mean_minus_sd(hn), int(hp.size), int(hn.size))


def labels(a: np.ndarray, w, th: Thresholds):
    """(count, th_crossed) int8 arrays; ``w=None`` opens the gyro gate (accel-only)."""
    s = (a > 0).astype(np.int8)
    s -= (a < 0)  # sign(a) as int8 without a float temporary
    if w is not None:
        s *= np.asarray(w) > 0
    count = s
    with np.errstate(invalid="ignore"):
        crossed = ((a > th.positive).astype(np.int8) - (a < th.negative).astype(np.int8))
    return count, crossed


def _marks_one_sign(cands: np.ndarray, sign: int, count: np.ndarray, n: int) -> list:
    cands = cands[cands < n - 2]
    # whether count keeps this sign for three samples from each candidate (vectorised)
    run3 = ((count[cands] == sign) & (count[cands + 1] == sign)
            & (count[cands + 2] == sign)).tolist()
    placed = set()  # indices marked with this sign
    for j, r in zip(cands.tolist(), run3):
        if j in placed or (j + 1) in placed:
            continue
        placed.add(j + 2 if r else j)
    idx = sorted(placed)
    m = len(idx)
    keep = set(idx)
    for i, j in enumerate(idx):
        if i <= m - 2 and idx[i + 1] == j + 1:
            keep.discard(j)
        elif i == m - 1 and m >= 2 and idx[i - 1] == j - 1:
            keep.discard(j - 1)
    return sorted(keep)


def crossing_marks(a: np.ndarray, count: np.ndarray, crossed: np.ndarray) -> np.ndarray:
    """Mark array (int8, +1/-1 at the marked crossings)."""
    n = a.shape[0]
    mark = np.zeros(n, np.int8)
    for sign in (1, -1):
        cands = np.flatnonzero((crossed == sign) & (count != 0))
        idx = _marks_one_sign(cands, sign, count, n)
        mark[np.asarray(idx, np.int64)] += sign
    return mark


def pair_movements(a: np.ndarray, count: np.ndarray, crossed: np.ndarray, mark: np.ndarray,
                   fs: int) -> np.ndarray:
    """Candidate rows (start, second crossing, end, slack) before overlap resolution; rows
    whose end was not found are all-zero (as the reference's table)."""
    fs = int(fs)
    e = np.flatnonzero(mark)
    rows = np.zeros((e.size, 4), np.int64)
    if e.size < 2:
        return rows
    gap = int(PAIR_GAP_AT_20HZ * fs / 20)
    half = int(MAX_MOVEMENT_S * fs / 2 + 1)
    span = math.ceil(MAX_MOVEMENT_S * fs)
    n = a.shape[0]
    me = mark[e]
    ok = np.flatnonzero((me[1:] != me[:-1]) & (np.diff(e) <= gap))
    for i in ok.tolist():
        e0, e1 = int(e[i]), int(e[i + 1])
        s = int(me[i])
        if crossed[e0] == s:
            f = e0
        elif crossed[(e0 - 1) % n] == s:  # the reference indexes e0 - 1 (wraps at 0)
            f = e0 - 1
        else:
            f = e0 - 2
        budget = half - e1 + f
        if 0 < budget < f:
            k = 0
            target = crossed[f]
            while count[f - k] == target:
                k += 1
                if k > budget:
                    break
            if k == 0:  # the reference would fail on an empty slice here; keep the crossing
                start, slack = f, 0
            else:
                k2 = int(np.argmin(np.abs(a[f - k:f])))
                start, slack = f - k + k2 + 1, k - k2 - 1
        else:
            start, slack = f, 0
        stop = int(start + span)
        seg = count[e1:stop]
        hit = np.flatnonzero(seg == -mark[e1])
        if hit.size == 0:
            continue
        rows[i] = (start, e1, e1 + int(hit[0]), slack)
    return rows


def resolve_overlaps(rows: np.ndarray) -> np.ndarray:
    """Drop start-0 rows, shift or clear overlapping rows; returns (m, 3): start, second, end."""
    mv = rows[rows[:, 0] != 0].copy()
    m = mv.shape[0]
    for i in range(1, m):
        if not mv[i - 1].any():
            j = i
            while j < m:
                if mv[j, 0] < mv[i - 2, 2]:
                    mv[j] = 0
                    j += 1
                else:
                    break
        elif mv[i, 0] < mv[i - 1, 2]:
            if mv[i, 3] > 0:
                st = int(mv[i, 0])
                done = False
                for _ in range(int(mv[i, 3]) + 1):
                    if st >= mv[i - 1, 2]:
                        mv[i, 0] = st
                        done = True
                        break
                    st += 1
                if not done:
                    mv[i] = 0
            else:
                mv[i] = 0
    return mv[mv[:, 0] != 0][:, :3]


def detect_movements(a: np.ndarray, w, fs: int, variant: str = "v2"):
    """The whole detector: returns (movements (m, 3) int64 start/second/end, Thresholds)."""
    a = np.asarray(a, np.float64)
    th = thresholds(a, variant)
    if not th.usable or a.shape[0] < 3:
        return np.zeros((0, 3), np.int64), th
    count, crossed = labels(a, w, th)
    mark = crossing_marks(a, count, crossed)
    rows = pair_movements(a, count, crossed, mark, fs)
    return resolve_overlaps(rows), th
