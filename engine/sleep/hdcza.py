"""HDCZA (van Hees et al. 2018): the sleep period time window of one night window of 5 s epochs.

``hdcza(anglez, invalid, options)`` works on one window (noon to noon, at most 30 h with the
daysleeper re-run: see ``engine.sleep.nights``); everything is vectorised numpy. ``start`` /
``end`` are GGIR's ``SPTE_start`` / ``SPTE_end`` (R/HASPT.R): positions in the no-movement
sequence GGIR pads with a leading 0, so the SPT is the window's epochs ``start - 1`` up to
``end - 1`` (exclusive); ``SptEstimate.epochs()`` gives that range. See rules.py for sources.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from ..operators.anglez import window_medians
from . import rules

MEDIAN_ROWS = 2048  # windows whose median is taken at once (about 1 MB of scratch)


@dataclass(frozen=True)
class HdczaOptions:
    """GGIR's ``params_sleep`` for HDCZA. ``threshold``: (percentile, multiplier) or one fixed
    value in degrees; ``ignore_invalid``: False (nonwear is judged on its anglez, GGIR's
    default), True (nonwear is movement) or None (nonwear is no movement; GGIR's NA)."""
    threshold: tuple = rules.HDCZA_THRESHOLD
    ignore_invalid: Optional[bool] = False
    min_block_min: float = rules.SPT_MIN_BLOCK_MIN
    max_gap_min: float = rules.SPT_MAX_GAP_MIN
    max_gap_ratio: float = rules.SPT_MAX_GAP_RATIO
    epoch_s: float = rules.EPOCH_S


@dataclass
class SptEstimate:
    start: Optional[int]  # GGIR's SPTE_start (None: no window found)
    end: Optional[int]  # GGIR's SPTE_end
    threshold: float
    guider: str  # "HDCZA", "HDCZA+invalid" or "none" (all nonwear)

    def epochs(self) -> Optional[tuple]:
        """The SPT as window epoch indices [first, stop) (None without a window)."""
        if self.start is None:
            return None
        return self.start - 1, self.end - 1


def movement(anglez: np.ndarray, epoch_s: float = rules.EPOCH_S) -> np.ndarray:
    """x: per epoch the median of |diff(anglez)| over the 5-min window centred as zoo's
    ``rollapply(width = k, align = "center", fill = 0)`` (offsets -(k-1)//2 .. k//2)."""
    k = int(round(rules.HDCZA_WINDOW_MIN * 60 / epoch_s))
    n = anglez.shape[0]
    x = np.zeros(n)
    if n < k:
        return x
    ad = np.abs(np.diff(anglez))  # the window at i holds ad[i .. i + k - 2]
    win = np.lib.stride_tricks.sliding_window_view(ad, k - 1)
    h = (k - 1) // 2
    if (k - 1) % 2 == 1 and not np.isnan(ad).any():  # odd windows: the middle value, selected
        x[h:h + win.shape[0]] = window_medians(np.asarray(ad, np.float64), k - 1)
        return x
    for a in range(0, win.shape[0], MEDIAN_ROWS):  # bounded scratch: MEDIAN_ROWS x (k - 1)
        b = min(a + MEDIAN_ROWS, win.shape[0])
        x[h + a:h + b] = np.median(win[a:b], axis=1)
    return x


def threshold_of(x: np.ndarray, opts: HdczaOptions) -> float:
    th = tuple(opts.threshold) if np.ndim(opts.threshold) else (opts.threshold,)
    if len(th) == 2:
        t = float(np.quantile(x, th[0] / 100.0)) * th[1]  # numpy's default = R's type 7
        return min(max(t, rules.HDCZA_CLAMP[0]), rules.HDCZA_CLAMP[1])
    return float(th[0])


def _runs(seq: np.ndarray):
    """Run-length encoding: (values, starts, lengths)."""
    b = np.flatnonzero(np.diff(seq)) + 1
    starts = np.concatenate([[0], b])
    lengths = np.diff(np.concatenate([starts, [seq.shape[0]]]))
    return seq[starts], starts, lengths


def hdcza(anglez: np.ndarray, invalid: np.ndarray, opts: HdczaOptions = HdczaOptions()) -> SptEstimate:
    n = anglez.shape[0]
    a = np.nan_to_num(np.asarray(anglez, np.float64), nan=0.0)
    inv = np.asarray(invalid, bool)
    x = movement(a, opts.epoch_s)
    thr = threshold_of(x, opts)
    if opts.ignore_invalid is None:
        nomov = (x < thr) | inv
    elif opts.ignore_invalid:
        nomov = (x < thr) & ~inv
    else:
        nomov = x < thr
    if n == 0 or inv.all():
        return SptEstimate(None, None, thr, "none")
    per_min = 60.0 / opts.epoch_s
    seq = np.concatenate([[0], nomov.astype(np.int8), [0]])
    # step -3: blocks of no movement of at most spt_min_block_dur are dropped
    v, s, ln = _runs(seq)
    drop = np.flatnonzero((v == 1) & (ln <= per_min * opts.min_block_min))
    drop = drop[(drop != 0) & (drop != v.shape[0] - 1)]
    if drop.shape[0]:
        for i in drop.tolist():
            seq[s[i]:s[i] + ln[i]] = 0
        seq = seq[:n]
    # step -2: gaps shorter than spt_max_gap_dur are filled
    v, s, ln = _runs(seq)
    m = v.shape[0]
    if opts.max_gap_ratio < 1 and m > 3:
        after = np.concatenate([ln[1:], [0]])
        before = np.concatenate([[0], ln[:-1]])
        with np.errstate(divide="ignore"):
            fill = ((v == 0) & (ln < per_min * opts.max_gap_min)
                    & (ln / after < opts.max_gap_ratio) & (ln / before < opts.max_gap_ratio))
    else:
        fill = (v == 0) & (ln < per_min * opts.max_gap_min)
    fill = np.flatnonzero(fill)
    fill = fill[(fill != 0) & (fill != m - 1)]
    if fill.shape[0]:
        for i in fill.tolist():
            seq[s[i]:s[i] + ln[i]] = 1
        seq = seq[:n]
    # step -1: the longest block (the first of equal ones)
    v, s, ln = _runs(seq)
    ones = np.flatnonzero(v == 1)
    guider = "HDCZA"  # GGIR names the guider even when no block is found
    if not ones.shape[0]:
        return SptEstimate(None, None, thr, guider)
    best = ones[np.argmax(ln[ones])]
    start, stop = int(s[best]), int(s[best] + ln[best])
    if start >= n:  # the block lies in the padding only
        return SptEstimate(None, None, thr, guider)
    stop = min(stop, n)
    if opts.ignore_invalid is None:
        lo, hi = max(start - 1, 0), max(stop - 1, 0)
        if inv[lo:hi + 1].any():  # GGIR marks spt_long[SPTE_start:SPTE_end] (R, inclusive)
            guider = "HDCZA+invalid"
    return SptEstimate(start, stop, thr, guider)
