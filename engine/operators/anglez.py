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

from ..core.kernels import scipy_extension
from .base import ring_capacity
from .binning import TimeBinner

EPOCH_S = 5.0
MEDIAN_S = 5.0  # GGIR: rolling median over 5 s
MEDIAN_HZ = 10.0  # GGIR: the median runs on data subsampled to ~10 Hz


_RANK = getattr(scipy_extension("ndimage", "_rank_filter_1d"), "rank_filter", None)


def window_medians(x: np.ndarray, k: int) -> np.ndarray:
    """Median of every complete window of ``k`` (odd) consecutive values of a 1-D float64 array:
    (m,) -> (m - k + 1,), each an element of its window (``np.median``'s value for odd k). The
    rank kernel of :func:`_medians` when it loads, else ``scipy.ndimage.median_filter``."""
    h = k // 2
    m = x.shape[0]
    if _RANK is not None and m >= k and x.dtype == np.float64:
        full = np.empty(m)
        _RANK(np.ascontiguousarray(x), h, k, full, 0, 0.0, 0)
        return full[h:m - h]
    from scipy.ndimage import median_filter
    return median_filter(x, size=k, mode="nearest")[h:m - h]


def _medians(sub: np.ndarray, k: int) -> np.ndarray:
    """Rolling medians of every complete window of k subsamples, one row per axis:
    (3, m) -> (3, m - k + 1) (scipy's compiled median filter on each contiguous axis row; only the
    windows that lie inside the row are kept, so the edge mode never matters). The 1-D rank
    kernel that ``scipy.ndimage.median_filter`` runs is called directly when it loads (rank
    k // 2, nearest edges, origin 0: the same numbers without importing scipy.ndimage)."""
    h = k // 2
    m = sub.shape[1]
    out = np.empty((3, m - k + 1))
    if _RANK is not None and m >= k and sub.dtype == np.float64:
        full = np.empty(m)
        for j in range(3):
            _RANK(np.ascontiguousarray(sub[j]), h, k, full, 0, 0.0, 0)
            out[j] = full[h:m - h]
        return out
    from scipy.ndimage import median_filter
    for j in range(3):
        out[j] = median_filter(sub[j], size=k, mode="nearest")[h:m - h]
    return out


def anglez_deg(m: np.ndarray) -> np.ndarray:
    return np.degrees(np.arctan2(m[:, 2], np.sqrt(m[:, 0] ** 2 + m[:, 1] ** 2)))  # = atan(z / r), r >= 0


def first_subsample(p: int, step: int) -> int:
    """Offset from segment position ``p`` to the first subsample at or after it (subsamples are
    the positions that are multiples of ``step``)."""
    return (-p) % step


def hold_angles(angle: np.ndarray, a0: int, p0: int, p1: int, step: int) -> np.ndarray:
    """Per-sample angles of segment positions ``p0 <= p < p1``: sample p takes the angle of its
    subsample position ``p // step``; ``angle`` covers subsample positions ``a0 ...``, and positions
    outside it take the nearest end (the segment's ends take the nearest complete median)."""
    q0, q1 = p0 // step, (p1 - 1) // step  # first and last subsample position held
    idx = np.clip(np.arange(q0 - a0, q1 - a0 + 1), 0, angle.shape[0] - 1)
    counts = np.full(q1 - q0 + 1, step, np.int64)
    counts[0] -= p0 - q0 * step
    counts[-1] -= (q1 + 1) * step - p1
    return np.repeat(angle[idx], counts)


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
        self._sub = np.zeros((3, 0))  # subsamples from index self._q0 on, one row per axis
        self._q0 = 0
        self._angle = np.zeros(0)  # anglez of subsample positions [self._a0, self._a0 + len)
        self._a0 = 0
        self._w = 0  # segment position of the first sample waiting for its angle
        self._t = np.zeros(0, np.int64)  # times of the waiting samples (positions self._w ...)

    # ------------------------------------------------------------------ per segment
    def _take(self, accel: np.ndarray) -> None:
        """Append the block's subsamples to the carried ones (the last k - 1 at most)."""
        new = accel[first_subsample(self._p, self.step)::self.step]
        c = self._sub.shape[1]
        sub = np.empty((3, c + new.shape[0]))
        sub[:, :c] = self._sub
        sub[:, c:] = new.T
        self._sub = sub

    def _extend_angles(self) -> None:
        """Angles of the subsample positions whose median window is now complete."""
        if self._sub.shape[1] < self.k:
            return
        ang = anglez_deg(_medians(self._sub, self.k).T)  # centres q0 + half ... total - 1 - half
        centre0 = self._q0 + self.half
        if self._angle.shape[0]:
            ang = ang[max(0, self._a0 + self._angle.shape[0] - centre0):]
        else:
            self._a0 = centre0
        self._angle = np.concatenate([self._angle, ang])
        drop = self._sub.shape[1] - (self.k - 1)  # the next window needs the last k - 1 subsamples
        if drop > 0:
            self._sub = self._sub[:, drop:]
            self._q0 += drop

    def _release(self, stop: int, vals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Hand out the waiting samples of positions below ``stop`` with their angles."""
        r = stop - self._w
        out = (self._t[:r], vals)
        self._t = self._t[r:]
        self._w = stop
        return out

    def _resolve(self, final: bool) -> tuple[np.ndarray, np.ndarray]:
        """Angles of the waiting samples whose median is known; returns (times, angles)."""
        self._extend_angles()
        if final:
            if not self._angle.shape[0]:  # segment shorter than one median window
                if self._sub.shape[1]:
                    whole = anglez_deg(np.median(self._sub.T, axis=0)[None, :])[0]
                else:
                    whole = np.nan
                return self._release(self._p, np.full(self._p - self._w, whole))
            return self._release(self._p, self._held(self._p))
        if not self._angle.shape[0]:
            return np.zeros(0, np.int64), np.zeros(0)
        known_end = self._a0 + self._angle.shape[0]  # positions < known_end have a median
        stop = min(self._p, known_end * self.step)  # samples whose subsample position is known
        out = self._release(stop, self._held(stop))
        # angles below the lowest waiting position are no longer needed
        low = self._w // self.step if self._w < self._p else known_end
        cut = min(max(0, low - self._a0), self._angle.shape[0] - 1)
        if cut > 0:
            self._angle = self._angle[cut:]
            self._a0 += cut
        return out

    def _held(self, stop: int) -> np.ndarray:
        """Angles of the waiting samples of positions below ``stop``."""
        if stop <= self._w:
            return np.zeros(0)
        return hold_angles(self._angle, self._a0, self._w, stop, self.step)

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
        self._take(np.asarray(batch.accel, np.float64))
        self._p += n
        self._t = np.concatenate([self._t, batch.time_ns])
        chunks += self._emit(self._segment, *self._resolve(final=False))
        return self._rows(chunks)

    def flush(self):
        chunks = []
        if self._segment is not None:
            chunks += self._emit(self._segment, *self._resolve(final=True))
        chunks += self._binner.flush()
        return self._rows(chunks)
