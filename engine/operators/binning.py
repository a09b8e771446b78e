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

The times may come as an array or as a sample clock (``.n``, ``.at(rows)``, ``.times(start,
stop)``, ``.search(edges)``, e.g. ``drivers.cwa_decode.SampleClock``): then only the times of the
rows where bins start and of the samples held between pushes are computed, and the chunks of
whole bins carry ``time_ns=None`` (their row count in ``rows``).

A column may also come per unit (``units=(unit_start, {name: values})``: one value held over each
unit's samples, e.g. a .cwa sector's temperature): a chunk of whole bins then carries each bin's
sum of it in ``sums`` (the value times the unit's samples in the bin, through a running total), and
only the samples held between pushes get it per sample. The sums are those of the per-sample
values whenever every partial sum is exact (see ``windows.exact_unit_sums``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Optional

import numpy as np

from ..core.ringbuffer import RingBuffer


@dataclass
class BinChunk:
    """Whole bins of one segment: ``starts[i]`` is the first row of bin ``bins[i]`` in the columns."""

    segment: int
    origin_ns: int
    bins: np.ndarray  # (k,) int64 bin numbers
    starts: np.ndarray  # (k,) int64 row offsets (increasing, starts[0] == 0)
    time_ns: Optional[np.ndarray]  # (n,) int64; None when the times came as a sample clock
    cols: Mapping[str, np.ndarray]
    rows: Optional[int] = None  # n, when time_ns is None
    sums: Optional[Mapping[str, np.ndarray]] = None  # (k,) per-bin sums of the per-unit columns

    @property
    def counts(self) -> np.ndarray:
        n = self.time_ns.shape[0] if self.time_ns is not None else self.rows
        return np.diff(np.append(self.starts, n))

    def bin_start_ns(self, width_ns: int) -> np.ndarray:
        return self.origin_ns + self.bins * width_ns


def _bin_starts(b: np.ndarray) -> np.ndarray:
    """Row offsets where the (sorted) bin number changes, starting with 0."""
    return np.concatenate([[0], np.flatnonzero(b[1:] != b[:-1]) + 1]).astype(np.int64)


def _bin_rows(tt: np.ndarray, origin: int, w: int, last: int) -> tuple:
    """(row offsets, bin numbers) of the bins of samples ``tt`` (times, sorted), which end
    before bin ``last`` starts; bin edges searched in the times, not every time divided."""
    b0 = (int(tt[0]) - origin) // w
    edges = origin + np.arange(b0 + 1, last, dtype=np.int64) * w
    st = np.concatenate([[0], np.searchsorted(tt, edges, side="left")]).astype(np.int64)
    st = st[st < tt.shape[0]]
    st = st[np.concatenate([[True], st[1:] != st[:-1]])]  # bins without samples
    return st, (tt[st] - origin) // w


def bin_cuts(time_ns: np.ndarray, origin: int, width_ns: int, pending_bin) -> tuple:
    """Where one piece of a segment's (sorted) times falls into bins, given the bin left open by
    earlier pieces (``pending_bin``, None: none): returns ``(start, stop, starts, bins, last)``.
    Rows ``[0, start)`` join the open bin (``start == n``: it stays open and nothing else is
    returned); rows ``[start, stop)`` are whole bins, bin ``bins[i]`` beginning at row
    ``start + starts[i]``; rows ``[stop, n)`` open bin ``last``."""
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
        st, bins = _bin_rows(time_ns[start:stop], origin, w, last)
    return start, stop, st, bins, int(last)


def _whole_bins(segment: int, origin: int, w: int, last: int, tt: np.ndarray,
                cols: Mapping[str, np.ndarray]) -> BinChunk:
    """The chunk of samples ``tt`` (times, sorted), which end before bin ``last`` starts."""
    st, bins = _bin_rows(tt, origin, w, last)
    return BinChunk(segment, origin, bins, st, tt, cols)


def _whole_bins_clocked(segment: int, origin: int, w: int, last: int, clock, start: int,
                        stop: int, cols: Mapping[str, np.ndarray], edge_rows: np.ndarray,
                        first_edge: int) -> BinChunk:
    """:func:`_whole_bins` of the clock's rows ``start .. stop-1``: the same bins and row
    offsets, from the times of the rows where bins start alone. ``edge_rows``: the row of
    every bin edge from bin ``first_edge`` on (``clock.search``)."""
    b0 = (int(clock.at(start)) - origin) // w
    found = edge_rows[b0 + 1 - first_edge:last - first_edge]  # edges b0+1 .. last-1
    st = np.concatenate([[0], found - start]).astype(np.int64)
    st = st[st < stop - start]
    st = st[np.concatenate([[True], st[1:] != st[:-1]])]  # bins without samples
    return BinChunk(segment, origin, (clock.at(st + start) - origin) // w, st, None, cols,
                    rows=stop - start)


def held_per_sample(unit_start: np.ndarray, values: np.ndarray, start: int, stop: int,
                    n: int) -> np.ndarray:
    """Rows ``start .. stop-1`` of a per-unit column as per-sample values (``n`` rows in all)."""
    lo = max(int(np.searchsorted(unit_start, start, side="right")) - 1, 0)
    hi = int(np.searchsorted(unit_start, stop, side="left"))  # units lo .. hi-1 reach the rows
    ends = np.append(unit_start[lo + 1:hi + 1], n)[:hi - lo]
    counts = np.clip(np.minimum(ends, stop) - np.maximum(unit_start[lo:hi], start), 0, None)
    return np.repeat(values[lo:hi], counts)


def unit_bin_sums(unit_start: np.ndarray, values: np.ndarray, row_starts: np.ndarray,
                  row_stop: int) -> np.ndarray:
    """Sum of a per-unit column over the bins starting at rows ``row_starts`` (the last ending at
    ``row_stop``): each unit's value times its samples in the bin, as differences of the
    running total at the bins' edges."""
    edges = np.append(row_starts, row_stop)
    u = np.searchsorted(unit_start, edges, side="right") - 1
    counts = np.diff(unit_start)
    before = np.zeros(values.shape[0])
    np.cumsum(values[:-1] * counts, out=before[1:])
    total = before[u] + values[u] * (edges - unit_start[u])
    return np.diff(total)


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

    def push(self, segment: int, time_ns, *, units=None, **cols) -> list[BinChunk]:
        """Samples of ``segment`` with their times (an int64 array or a sample clock), their
        columns, and ``units=(unit_start, {name: values})`` for columns held per unit (see the
        module docstring); returns the chunks of bins they complete."""
        out: list[BinChunk] = []
        clock = None if isinstance(time_ns, np.ndarray) else time_ns
        n = time_ns.shape[0] if clock is None else clock.n
        if n == 0:
            return out
        unit_start, unit_cols = units if units is not None else (None, {})

        def rows(a, b):
            """Every column for rows a..b-1, per sample."""
            return {c: (held_per_sample(unit_start, unit_cols[c], a, b, n) if c in unit_cols
                        else cols[c][a:b]) for c in self._names}
        if clock is None:
            def at(i):
                return int(time_ns[i])

            def search(edge):
                return int(np.searchsorted(time_ns, edge, side="left"))

            def times(a, b):
                return time_ns[a:b]
        else:
            ends = clock.at(np.array([0, n - 1], np.int64)).tolist()

            def at(i):
                if i == 0 or i == n - 1:
                    return ends[0 if i == 0 else 1]
                return int(clock.at(i))

            def search(edge):
                return edge_rows[(edge - self.origin) // self.width_ns - first_edge]

            times = clock.times
        if segment != self.segment:
            out += self._emit_pending()
            self.segment = segment
            self.origin = at(0) if self.align == "segment" else 0
        if clock is not None:  # every bin edge the block can ask for, searched at once
            first_edge = (self.pending_bin if self.pending_bin is not None
                          else (at(0) - self.origin) // self.width_ns)
            last_edge = max((at(n - 1) - self.origin) // self.width_ns, first_edge + 1)
            edge_rows = clock.search(self.origin + np.arange(first_edge, last_edge + 1,
                                                             dtype=np.int64) * self.width_ns)
        # bin numbers only where needed: bins change at origin + k * width, so the rows where
        # they change are found by searching those edges in the (sorted) times, not by dividing
        # every sample's time
        w, origin = self.width_ns, self.origin
        start = 0
        if self.pending_bin is not None:
            k = search(origin + (self.pending_bin + 1) * w)
            if k == n:  # the pending bin is still open
                self._ring.append(time=times(0, n), **rows(0, n))
                return out
            held = self._ring.view()
            head = rows(0, k)
            chunk = BinChunk(segment, self.origin, np.array([self.pending_bin], np.int64),
                             np.zeros(1, np.int64), np.concatenate([held["time"], times(0, k)]),
                             {c: np.concatenate([held[c], head[c]]) for c in self._names})
            self._ring.clear()
            self.pending_bin = None
            out.append(chunk)
            start = k
        last = (at(n - 1) - origin) // w
        k2 = search(origin + last * w)
        if k2 > start:
            body = {c: cols[c][start:k2] for c in self._names if c not in unit_cols}
            if clock is None:
                chunk = _whole_bins(segment, origin, w, last, time_ns[start:k2], body)
            else:
                chunk = _whole_bins_clocked(segment, origin, w, last, clock, start, k2, body,
                                            edge_rows, first_edge)
            if unit_cols:
                chunk.sums = {c: unit_bin_sums(unit_start, v, chunk.starts + start, k2)
                              for c, v in unit_cols.items()}
            out.append(chunk)
        self._ring.append(time=times(k2, n), **rows(k2, n))
        self.pending_bin = int(last)
        return out

    def flush(self) -> list[BinChunk]:
        return self._emit_pending()
