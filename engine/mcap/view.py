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

from ..operators.correction import CorrectedBatch
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
        if idx.shape[0] > 1:  # nondecreasing: a gap over several periods repeats an index
            keep = np.empty(idx.shape[0], bool)
            keep[0] = True
            np.not_equal(idx[1:], idx[:-1], out=keep[1:])
            idx = idx[keep]
        if self._last is None or g0 != self._last:
            idx = np.concatenate([[0], idx])
        self._last = g1
        return idx.astype(np.int64, copy=False)

    def thin(self, batches: list) -> list:
        """What a sink that writes no corrected message (a lean log) needs of one step's
        corrected batches: of each, the view samples only (a small batch of the same segment;
        none when it has no view sample). A sink with its own decimator of the same rate, fed
        the thinned steps in order instead of the whole ones, writes the same bytes: it picks
        every sample it gets (each opens a new period: the samples skipped between two picks
        share the first one's period) and so keeps the same state; each view sample keeps its
        batch and cell, so the records, their order among the epochs' cells and the places a
        chunk may end are the same; the samples dropped only changed which of the sink's two
        framing paths ran (engine/mcap/sink.py: the same bytes either way). A step whose times
        go backwards (in a batch or from one batch to the next) comes back whole (its pieces
        may then wait behind an earlier cell's); this decimator still picks it, so its state
        follows the sink's."""
        live = [b for b in batches if b.n]
        last = None
        for b in live:
            t = b.time_ns
            if (last is not None and t[0] < last) or bool(np.any(t[1:] < t[:-1])):
                for c in live:
                    self.pick(c.time_ns)
                return list(batches)
            last = t[-1]
        out = []
        for b in live:
            i = self.pick_sorted(b.time_ns)
            if i.shape[0]:
                # accel[i], not take(): take() first copies a strided (column-major) array whole
                out.append(CorrectedBatch(b.time_ns.take(i), b.accel[i], b.temperature.take(i),
                                          b.segment))
        return out


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
