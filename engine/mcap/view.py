"""The view topic ``/view/accel``: the corrected stream decimated to a few samples per second,
one message per sample (``AccelSample``: x, y, z and norm in g), so Foxglove's Plot panel draws
it against time (the batched ``/corrected/accel`` messages hold ~1000 samples each, which a
plot cannot place in time).

The kept samples are the first corrected sample in each period of ``1 / view_hz`` on the UTC
grid (period index = time_ns // period_ns), so the choice does not depend on how the stream
was cut into blocks, and replay reproduces it exactly. Values are the corrected stream's own
(quantised) float32 values; norm is computed in float32 from them.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from .schemas import VIEW_SAMPLE

TOPIC_VIEW = "/view/accel"

PAYLOAD_DTYPE = np.dtype([("hdr", "V4"), ("sec", "<i4"), ("nsec", "<u4"), ("x", "<f4"),
                          ("y", "<f4"), ("z", "<f4"), ("norm", "<f4")])  # the CDR layout, packed


class ViewDecimator:
    """Picks the view samples of a time-ordered stream (state: the last period seen)."""

    def __init__(self, view_hz: float):
        if not view_hz > 0:
            raise ValueError("view_hz must be positive")
        self.period_ns = int(round(1e9 / float(view_hz)))
        self._last: Optional[int] = None

    def pick(self, time_ns: np.ndarray) -> np.ndarray:
        """Indices of the samples that open a new period."""
        if time_ns.shape[0] == 0:
            return np.zeros(0, np.int64)
        g = time_ns // self.period_ns
        new = np.empty(g.shape[0], bool)
        new[0] = self._last is None or g[0] != self._last
        np.not_equal(g[1:], g[:-1], out=new[1:])
        self._last = int(g[-1])
        return np.flatnonzero(new)


    def pick_sorted(self, time_ns: np.ndarray) -> np.ndarray:
        """``pick`` for nondecreasing times: the period boundaries are found by binary search
        instead of a division per sample (same indices, same state)."""
        n = time_ns.shape[0]
        if n == 0:
            return np.zeros(0, np.int64)
        p = self.period_ns
        g0, g1 = int(time_ns[0]) // p, int(time_ns[-1]) // p
        idx = np.searchsorted(time_ns, np.arange(g0 + 1, g1 + 1, dtype=np.int64) * p, side="left")
        if idx.shape[0] > 1:
            idx = np.unique(idx)
        if self._last is None or g0 != self._last:
            idx = np.concatenate([[0], idx])
        self._last = g1
        return idx.astype(np.int64, copy=False)


def view_records(time_ns: np.ndarray, x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray:
    """AccelSample payloads (one structured row each) of the given samples (float32 g)."""
    k = time_ns.shape[0]
    a = np.zeros(k, PAYLOAD_DTYPE)
    a["hdr"] = np.void(b"\x00\x01\x00\x00")
    a["sec"], a["nsec"] = np.divmod(time_ns, 10**9)
    a["x"], a["y"], a["z"] = x, y, z
    xf, yf, zf = (np.asarray(v, np.float32) for v in (x, y, z))
    a["norm"] = np.sqrt(xf * xf + yf * yf + zf * zf)
    return a


assert PAYLOAD_DTYPE.itemsize == 4 + 8 + 16, VIEW_SAMPLE.name
