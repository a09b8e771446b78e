"""After detection (reference rules, spec static-calibration.md §4.4): the cycle filter for
rhythmic non-infant motion, the sleep/inactive estimate, the rate per hour awake and the
per-movement kinematics. Pure functions on the (m, 3) movement table (start, second, end).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import numpy as np

CYCLE_GAP_S = 0.2  # movements this close chain together
CYCLE_MIN_CHAIN = 41  # a chain of at least this many is removed (j - i > 39)
CYCLE_TAIL_MAX = 3  # and up to this many following movements
CYCLE_TAIL_S = 12.0  # ... starting within this time after the chain
SLEEP_SPAN_S = 300.0  # 5 min
SLEEP_FLOOR_MIN = 5  # sleep minutes rounded down to a multiple of this
MAX_MOVES_IN_SPAN = 3  # anchor advances when more than this many movements are in the span


def cycle_filter(mv: np.ndarray, fs: int) -> tuple[np.ndarray, np.ndarray]:
    """(kept movements, removed mask): chains of >= 41 movements with gaps <= floor(0.2 fs)
    samples are removed, with up to 3 following movements starting < 12 s after the chain."""
    fs = int(fs)
    n = mv.shape[0]
    gap = int(math.floor(CYCLE_GAP_S * fs))
    drop = np.zeros(n, bool)
    if n == 0:
        return mv, drop
    start, end = mv[:, 0], mv[:, 2]
    close = (start[1:] - end[:-1]) <= gap  # close[i]: movement i+1 chains to i
    i = 0
    while i < n - 2:
        if close[i]:
            j = i + 1
            while j < n - 1 and close[j]:
                j += 1
            if j - i > CYCLE_MIN_CHAIN - 2:
                drop[i:j + 1] = True
                k = j + 1
                while k < n - 1 and k - (j + 1) < CYCLE_TAIL_MAX and start[k] - end[j] < CYCLE_TAIL_S * fs:
                    drop[k] = True
                    k += 1
                i = k
            else:
                i = j + 1
        else:
            i += 1
    return mv[~drop], drop


def sleep_samples(mv: np.ndarray, n_samples: int, fs: int) -> int:
    """The reference's sleep/inactive samples (spans > 5 min holding at most ~3 movements);
    the whole recording when there is no movement."""
    fs = int(fs)
    m = mv.shape[0]
    if m == 0:
        return int(n_samples)
    span = SLEEP_SPAN_S * fs
    start = mv[:, 0].tolist()
    anchor, target, t0, sleep = 0, 1, 0, 0
    while target < m - 1:
        if target - anchor > MAX_MOVES_IN_SPAN:
            anchor += 1
            t0 = start[anchor]
        t1 = start[target] - 1
        if t1 - t0 > span:
            sleep += t1 - t0
            anchor = target
            t0 = start[anchor]
        target += 1
    tail = (n_samples - 1) - (int(mv[-1, 2]) + 1)
    if tail > span:
        sleep += tail
    return int(sleep)


@dataclass
class Rate:
    movements: int
    recording_hours: float
    sleep_hours: float  # floored to 5 min
    awake_hours: float
    per_hour_awake: Optional[float]  # None when no awake time (flagged)
    flags: list


def rate(count: int, n_samples: int, sleep: int, fs_time: float) -> Rate:
    """Movements per hour awake. ``fs_time``: samples per second used to turn samples into time
    (the nominal rate in reference mode, the effective rate from the timestamps otherwise)."""
    flags = []
    sleep_min = math.floor(sleep / (60.0 * fs_time) / SLEEP_FLOOR_MIN) * SLEEP_FLOOR_MIN
    sleep_h = sleep_min / 60.0
    rec_h = n_samples / (3600.0 * fs_time)
    awake = rec_h - sleep_h
    if count == 0:
        flags.append("no movements: sleep is the whole recording, rate 0")
    if awake <= 0:
        flags.append("no awake time: rate undefined")
        per = 0.0 if count == 0 else None
    else:
        per = count / awake
    return Rate(int(count), rec_h, sleep_h, max(awake, 0.0), per, flags)


def kinematics(a: np.ndarray, mv: np.ndarray, time_s: Optional[np.ndarray], fs: float):
    """Per movement: duration (s), average and peak |a| (m/s^2) over start..end inclusive.
    Durations use the sample times when given ((t_end - t_start) + 1/fs), else (end-start+1)/fs."""
    m = mv.shape[0]
    if m == 0:
        z = np.zeros(0)
        return z, z, z
    st, en = mv[:, 0], mv[:, 2]
    absa = np.abs(a)
    c = np.concatenate(([0.0], np.cumsum(absa)))
    avg = (c[en + 1] - c[st]) / (en - st + 1)
    # peak: maximum over each (short, < 1.5 s) span
    width = int((en - st).max()) + 1
    offs = np.arange(width)
    idx = np.minimum(st[:, None] + offs[None, :], en[:, None])
    peak = absa[idx].max(axis=1)
    if time_s is not None:
        dur = (time_s[en] - time_s[st]) + 1.0 / fs
    else:
        dur = (en - st + 1) / fs
    return dur, avg, peak
