"""Cut a stream of per-sample columns into time bins (windows, epochs) that never span a segment.

``TimeBinner`` is the shared machinery of the window-features and epoch-metrics operators. Samples
arrive in arbitrary pieces; the binner hands back *chunks*, each a contiguous set of whole bins, so
that the statistics computed on a chunk do not depend on how the stream was cut: a bin completed
inside one block is a view of that block; a bin that straddles blocks is gathered (ring buffer +
head of the new block) into one small array first.

A bin is complete when a sample of a later bin of the same segment arrives, when the segment
changes, or at ``flush()``. Bin ``k`` of a segment covers ``[origin + k*width, origin +
(k+1)*width)``; ``origin`` is the segment's first sample time (``align="segment"``) or the Unix
epoch (``align="clock"``: bins on the UTC grid, e.g. 5 s epochs at :00, :05, ...).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np

from ..ringbuffer import RingBuffer


@dataclass
class BinChunk:
    """Whole bins of one segment: ``starts[i]`` is the first row of bin ``bins[i]`` in the columns."""

    segment: int
    origin_ns: int
    bins: np.ndarray  # (k,) int64 bin numbers
    starts: np.ndarray  # (k,) int64 row offsets (increasing, starts[0] == 0)
    time_ns: np.ndarray  # (n,) int64
    cols: Mapping[str, np.ndarray]

    @property
    def counts(self) -> np.ndarray:
        return np.diff(np.append(self.starts, self.time_ns.shape[0]))

    def bin_start_ns(self, width_ns: int) -> np.ndarray:
        return self.origin_ns + self.bins * width_ns


def bin_cuts(time_ns: np.ndarray, origin: int, width_ns: int, pending_bin) -> tuple:
    """Where one piece of a segment's (sorted) times falls into bins, given the bin left open by
    earlier pieces (``pending_bin``, None: none): returns ``(start, stop, starts, bins, last)``.
    Rows ``[0, start)`` join the open bin (``start == n``: it stays open and nothing else is
    returned); rows ``[start, stop)`` are whole bins, bin ``bins[i]`` beginning at row
    ``start + starts[i]``; rows ``[stop, n)`` open bin ``last``. Bin edges are found by searching
    them in the times, not by dividing every sample's time."""
    n = time_ns.shape[0]
    w = width_ns
    start = 0
    if pending_bin is not None:
        start = int(np.searchsorted(time_ns, origin + (pending_bin + 1) * w, side="left"))
        if start == n:  # the pending bin is still open
            return n, n, np.zeros(0, np.int64), np.zeros(0, np.int64), pending_bin
    last = (int(time_ns[-1]) - origin) // w
    stop = int(np.searchsorted(time_ns, origin + last * w, side="left"))
    st, bins = np.zeros(0, np.int64), np.zeros(0, np.int64)
    if stop > start:
        tt = time_ns[start:stop]
        b0 = (int(tt[0]) - origin) // w
        edges = origin + np.arange(b0 + 1, last, dtype=np.int64) * w
        st = np.concatenate([[0], np.searchsorted(tt, edges, side="left")]).astype(np.int64)
        st = st[st < tt.shape[0]]
        st = st[np.concatenate([[True], st[1:] != st[:-1]])]  # bins without samples
        bins = (tt[st] - origin) // w
    return start, stop, st, bins, int(last)


def _bin_starts(b: np.ndarray) -> np.ndarray:
    """Row offsets where the (sorted) bin number changes, starting with 0."""
    return np.concatenate([[0], np.flatnonzero(b[1:] != b[:-1]) + 1]).astype(np.int64)


class TimeBinner:
    def __init__(self, width_s: float, columns: Mapping[str, tuple], *, align: str = "segment",
                 capacity: int = 1 << 16):
        if align not in ("segment", "clock"):
            raise ValueError("align must be 'segment' or 'clock'")
        self.width_ns = int(round(width_s * 1e9))
        if self.width_ns <= 0:
            raise ValueError("bin width must be positive")
        self.align = align
        self._ring = RingBuffer(capacity, time=(np.int64, ()), **columns)
        self._names = tuple(columns)
        self.segment = None
        self.origin = 0
        self.pending_bin = None  # bin number of the samples held in the ring

    def _emit_pending(self) -> list[BinChunk]:
        if self.pending_bin is None or len(self._ring) == 0:
            self.pending_bin = None
            return []
        v = self._ring.view()
        chunk = BinChunk(self.segment, self.origin, np.array([self.pending_bin], np.int64),
                         np.zeros(1, np.int64), np.array(v["time"]),
                         {k: np.array(v[k]) for k in self._names})
        self._ring.clear()
        self.pending_bin = None
        return [chunk]

    def push(self, segment: int, time_ns: np.ndarray, **cols) -> list[BinChunk]:
        out: list[BinChunk] = []
        n = time_ns.shape[0]
        if n == 0:
            return out
        if segment != self.segment:
            out += self._emit_pending()
            self.segment = segment
            self.origin = int(time_ns[0]) if self.align == "segment" else 0
        start, k2, st, bins, last = bin_cuts(time_ns, self.origin, self.width_ns, self.pending_bin)
        if self.pending_bin is not None:
            if start == n:  # the pending bin is still open
                self._ring.append(time=time_ns, **cols)
                return out
            held = self._ring.view()
            chunk = BinChunk(segment, self.origin, np.array([self.pending_bin], np.int64),
                             np.zeros(1, np.int64), np.concatenate([held["time"], time_ns[:start]]),
                             {c: np.concatenate([held[c], cols[c][:start]]) for c in self._names})
            self._ring.clear()
            self.pending_bin = None
            out.append(chunk)
        if k2 > start:
            out.append(BinChunk(segment, self.origin, bins, st, time_ns[start:k2],
                                {c: cols[c][start:k2] for c in self._names}))
        self._ring.append(time=time_ns[k2:], **{c: cols[c][k2:] for c in self._names})
        self.pending_bin = last
        return out

    def flush(self) -> list[BinChunk]:
        return self._emit_pending()
