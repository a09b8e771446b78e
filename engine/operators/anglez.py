"""anglez per epoch, GGIR's definition (``g.applymetrics``), as a streaming operator.

Per segment: each axis is subsampled to about 10 Hz (every ``max(floor(rate / 10), 1)``-th
sample), smoothed by a centred rolling median of ``round(10 * 5)`` = 51 subsamples (5 s; made odd),
and held over the original samples again; per sample ``anglez = atan(z / sqrt(x^2 + y^2))`` in
degrees; the epoch value is the mean over its samples. At the ends of a segment, where the median
window is incomplete, the nearest complete median is used (GGIR fills the ends the same way).

The median of a position needs the 25 subsamples after it, so output lags input by 2.5 s; a
segment's end (a new segment or ``flush()``) releases the rest. Results do not depend on how the
input is cut into blocks (positions are counted from the segment start; medians are computed on
contiguous windows only).
"""

from __future__ import annotations

import numpy as np

from .base import ring_capacity
from .binning import TimeBinner

EPOCH_S = 5.0
MEDIAN_S = 5.0  # GGIR: rolling median over 5 s
MEDIAN_HZ = 10.0  # GGIR: the median runs on data subsampled to ~10 Hz


def _medians(x: np.ndarray, k: int) -> np.ndarray:
    """Rolling medians of every complete window of k rows of x (m, 3) -> (m - k + 1, 3)
    (scipy's compiled median filter; only the windows that lie inside x are kept)."""
    from scipy.ndimage import median_filter
    h = k // 2
    out = np.empty((x.shape[0] - k + 1, 3))
    for j in range(3):
        out[:, j] = median_filter(np.ascontiguousarray(x[:, j]), size=k, mode="nearest")[h:x.shape[0] - h]
    return out


def anglez_deg(m: np.ndarray) -> np.ndarray:
    return np.degrees(np.arctan2(m[:, 2], np.sqrt(m[:, 0] ** 2 + m[:, 1] ** 2)))  # = atan(z / r), r >= 0


class AnglezOperator:
    """push(batch: time_ns, accel (n, 3) g, segment) -> (start_ns, n, anglez_deg) of completed
    epochs; flush() -> the rest."""

    def __init__(self, rate_hz: float, epoch_s: float = EPOCH_S):
        self.step = max(int(np.floor(rate_hz / MEDIAN_HZ)), 1)
        sub_hz = MEDIAN_HZ if self.step > 1 else rate_hz
        k = int(round(sub_hz * MEDIAN_S))
        self.k = k + 1 if k % 2 == 0 else k
        self.half = self.k // 2
        self._binner = TimeBinner(epoch_s, {"angle": (np.float64, ())}, align="clock",
                                  capacity=ring_capacity(epoch_s, rate_hz))
        self.width_ns = self._binner.width_ns
        self._segment = None
        self._reset()

    def _reset(self) -> None:
        self._p = 0  # samples seen in this segment
        self._sub = np.zeros((0, 3))  # subsamples from index self._q0 on
        self._q0 = 0
        self._angle = np.zeros(0)  # anglez of subsample positions [self._a0, self._a0 + len)
        self._a0 = 0
        self._head = None  # first complete median's angle (fills the segment's first positions)
        self._t = np.zeros(0, np.int64)  # samples waiting for their angle
        self._q = np.zeros(0, np.int64)

    # ------------------------------------------------------------------ per segment
    def _resolve(self, final: bool) -> tuple[np.ndarray, np.ndarray]:
        """Angles of the waiting samples whose median is known; returns (times, angles)."""
        total = self._q0 + self._sub.shape[0]  # subsamples so far in the segment
        if self._sub.shape[0] >= self.k:
            med = _medians(self._sub, self.k)  # centres q0 + half ... total - 1 - half
            ang = anglez_deg(med)
            centre0 = self._q0 + self.half
            new = ang[max(0, self._a0 + self._angle.shape[0] - centre0):] if self._angle.shape[0] \
                else ang
            if not self._angle.shape[0]:
                self._a0 = centre0
                self._head = float(ang[0])
            self._angle = np.concatenate([self._angle, new])
            keep = self.k - 1  # the next window needs the last k - 1 subsamples
            drop = self._sub.shape[0] - keep
            if drop > 0:
                self._sub = self._sub[drop:]
                self._q0 += drop
        known_end = self._a0 + self._angle.shape[0]  # positions < known_end have a median
        q = self._q
        if final:
            if not self._angle.shape[0]:  # segment shorter than one median window
                if self._sub.shape[0]:
                    whole = anglez_deg(np.median(self._sub, axis=0)[None, :])[0]
                else:
                    whole = np.nan
                vals = np.full(q.shape[0], whole)
            else:
                idx = np.clip(q - self._a0, 0, self._angle.shape[0] - 1)
                vals = self._angle[idx]
            out = (self._t, vals)
            self._t, self._q = np.zeros(0, np.int64), np.zeros(0, np.int64)
            return out
        if not self._angle.shape[0]:
            return np.zeros(0, np.int64), np.zeros(0)
        ready = int(np.searchsorted(q, known_end, side="left"))
        idx = np.maximum(q[:ready] - self._a0, 0)  # head positions take the first median
        vals = self._angle[idx]
        out = (self._t[:ready], vals)
        self._t, self._q = self._t[ready:], self._q[ready:]
        # angles below the lowest waiting position are no longer needed
        low = int(self._q[0]) if self._q.shape[0] else known_end
        cut = min(max(0, low - self._a0), self._angle.shape[0] - 1)
        if cut > 0:
            self._angle = self._angle[cut:]
            self._a0 += cut
        return out

    def _emit(self, segment, t, v):
        if t.shape[0] == 0:
            return []
        return self._binner.push(segment, t, angle=v)

    def _rows(self, chunks):
        if not chunks:
            return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
        s, n, v = [], [], []
        for c in chunks:
            cnt = c.counts
            s.append(c.bin_start_ns(self.width_ns))
            n.append(cnt)
            v.append(np.add.reduceat(c.cols["angle"], c.starts) / cnt)
        return np.concatenate(s), np.concatenate(n).astype(np.int64), np.concatenate(v)

    def push(self, batch):
        n = batch.time_ns.shape[0]
        chunks = []
        if n == 0:
            return self._rows(chunks)
        if batch.segment != self._segment:
            if self._segment is not None:
                chunks += self._emit(self._segment, *self._resolve(final=True))
            self._segment = batch.segment
            self._reset()
        a = np.asarray(batch.accel, np.float64)
        p = self._p + np.arange(n, dtype=np.int64)
        self._p += n
        take = p % self.step == 0
        self._sub = np.concatenate([self._sub, a[take]])
        self._t = np.concatenate([self._t, batch.time_ns])
        self._q = np.concatenate([self._q, p // self.step])
        chunks += self._emit(self._segment, *self._resolve(final=False))
        return self._rows(chunks)

    def flush(self):
        chunks = []
        if self._segment is not None:
            chunks += self._emit(self._segment, *self._resolve(final=True))
        chunks += self._binner.flush()
        return self._rows(chunks)
