"""Sustained inactivity bouts (van Hees et al. 2015) as a streaming operator on 5 s anglez.

A posture change is an epoch ``c`` with ``|anglez[c + 1] - anglez[c]| > 5`` degrees. Two
consecutive changes ``p < q`` more than 5 min apart (``q - p > 60`` epochs) make the epochs
``p .. q`` (both included) a bout; every other epoch is 0 (GGIR's ``HASIB``, vanHees2015).

``SibStream.push(anglez)`` takes the next epochs and returns the values it can now decide: an
epoch is final once the next posture change after it is known, so the undecided tail is the
epochs since the last change. ``release(upto)`` decides the epochs below ``upto`` for a caller
that cannot hold them longer (a still stretch longer than the caller's window: they are 1 when
the stretch already lasts more than 5 min, the value GGIR gives them once a later change comes;
GGIR gives 0 to the epochs before the recording's first change and after its last one, so a
still stretch longer than the window at either end of a recording differs).
``flush()`` decides the rest as GGIR does at the recording's end: the epochs after the last
change are 0 (the last change's own epoch keeps the bout it closes), and when the whole
recording had no 5-min gap between changes, everything is 1 with fewer than 10 changes, else 0.
State is a few integers whatever the recording's length; gaps (NaN) count as 0 degrees.
"""

from __future__ import annotations

import numpy as np

from . import rules


class SibStream:
    def __init__(self, epoch_s: float = rules.EPOCH_S, angle_deg: float = rules.ANGLE_THRESHOLD_DEG,
                 time_min: float = rules.TIME_THRESHOLD_MIN):
        self.angle = float(angle_deg)
        self.gap = int(round(time_min * 60.0 / epoch_s))
        self.n = 0  # epochs seen
        self.done = 0  # epochs below this are decided (handed out)
        self.prev = None  # last anglez seen
        self.last = None  # index of the last posture change
        self.last_closes = False  # the last change closed a bout (its epoch is 1)
        self.changes = 0
        self.any_bout = False

    def _decided(self, stop: int) -> np.ndarray:
        out = np.zeros(stop - self.done, np.int8)
        self.done = stop
        return out

    def push(self, anglez: np.ndarray) -> np.ndarray:
        a = np.nan_to_num(np.asarray(anglez, np.float64), nan=0.0)
        if a.shape[0] == 0:
            return np.zeros(0, np.int8)
        n0 = self.n
        ext = a if self.prev is None else np.concatenate([[self.prev], a])
        base = n0 if self.prev is None else n0 - 1  # index of ext[0]
        ch = np.flatnonzero(np.abs(np.diff(ext)) > self.angle) + base
        self.prev = float(a[-1])
        self.n += a.shape[0]
        if ch.shape[0] == 0:
            return np.zeros(0, np.int8)
        self.changes += ch.shape[0]
        prev_last = self.last
        pts = ch if prev_last is None else np.concatenate([[prev_last], ch])
        long = np.diff(pts) > self.gap  # interval i: [pts[i], pts[i + 1]]
        if long.any():
            self.any_bout = True
        if not self.any_bout and self.changes < rules.FALLBACK_MAX_CHANGES:
            # the recording-wide fallback may still apply: decide nothing yet
            self.last, self.last_closes = int(ch[-1]), False
            return np.zeros(0, np.int8)
        stop = int(ch[-1])  # epochs below the last change are final
        lo = self.done
        vals = np.zeros(stop - lo, np.int8)
        # bouts [pts[i], pts[i + 1]] for long intervals, clipped to [lo, stop)
        d = np.zeros(stop - lo + 1, np.int32)
        for_a = pts[:-1][long]
        for_b = pts[1:][long]
        a0 = np.clip(for_a - lo, 0, stop - lo)
        b0 = np.clip(for_b + 1 - lo, 0, stop - lo)
        np.add.at(d, a0, 1)
        np.add.at(d, b0, -1)
        vals |= (np.cumsum(d)[:-1] > 0).astype(np.int8)
        if prev_last is not None and self.last_closes and prev_last >= lo and prev_last < stop:
            vals[prev_last - lo] = 1
        self.last = stop
        self.last_closes = bool(long[-1])
        self.done = stop
        return vals

    def pending(self) -> int:
        return self.n - self.done

    def release(self, upto: int) -> np.ndarray:
        """Decide the epochs below ``upto`` now (see the module docstring)."""
        upto = min(upto, self.n)
        if upto <= self.done:
            return np.zeros(0, np.int8)
        vals = self.peek(upto)
        self.done = upto
        return vals

    def peek(self, upto: int) -> np.ndarray:
        """The values ``release(upto)`` would give, without deciding them."""
        upto = min(upto, self.n)
        lo = self.done
        vals = np.zeros(max(upto - lo, 0), np.int8)
        last = -1 if self.last is None else self.last
        if self.n - 1 - last > self.gap:  # a still stretch of more than 5 min so far
            vals[max(last, lo) - lo:] = 1
        elif self.last is not None and self.last_closes and lo <= self.last < upto:
            vals[self.last - lo] = 1
        return vals

    def flush(self) -> np.ndarray:
        lo = self.done
        vals = np.zeros(self.n - lo, np.int8)
        if not self.any_bout:
            if self.changes < rules.FALLBACK_MAX_CHANGES:
                vals[:] = 1
        elif self.last is not None and self.last_closes and lo <= self.last < self.n:
            vals[self.last - lo] = 1
        self.done = self.n
        return vals
