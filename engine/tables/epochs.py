"""The epoch table: one row per epoch for the whole recording span, gaps included, with flags.

``EpochAssembler`` takes what the output pass produces step by step (the raw Block, the corrected
batches, the epoch metrics) and returns ``EpochRows`` once every part of a row is final:

* ENMO, BFEN, MAD, temperature from the metrics operator (an epoch cut by a segment break is
  merged, weighted by samples);
* anglez (GGIR's definition) from ``AnglezOperator``;
* ``nonwear`` and ``clipping`` from ``NonwearOperator`` (its 15-min window holding the epoch);
* ``gap``: fewer than half the epoch's nominal samples (no data at all: values are empty);
* ``qc``: the epoch holds samples of a sector/page the reader kept but flagged (see
  ``QC_FLAGGED_REASONS``);
* ``idle_sleep`` (ActiGraph only): the share of the epoch's samples the device spent in idle sleep
  (its last sample repeated; engine/operators/windows.py keeps them out of the calibration);
* ``filter_warmup``: the epoch starts within the BFEN filter's start-up time after a segment start
  (the time its response to a 1 g step needs to fall below 1 mg);
* when the run computes them, ActiLife counts (``axis1``, ``axis2``, ``axis3``, ``vm``:
  engine/operators/counts.py) and MIMS-units (``mims``: engine/operators/mims.py), summed over
  the parts of an epoch cut by a segment break.

Rows wait for the nonwear decision (about 75 min of data), so memory holds about an hour and a
half of epochs whatever the recording's length.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, fields
from typing import Iterator, Optional

import numpy as np

from ..core.blocks import PER_SAMPLE_IDLE_SLEEP
from ..operators.anglez import AnglezOperator
from ..operators.filters import SosStream, bandpass_sos
from ..operators.nonwear import NonwearOperator, NonwearWindows

# Reader QC reasons whose samples are kept but flagged (drivers/cwa_reader.py, drivers/geneactiv.py).
QC_FLAGGED_REASONS = frozenset({
    "bad_timestamp", "bad_anchor", "bad_count", "device_overflow", "axis_swap", "truncated",
    "bad_page_time", "page_time_fixed", "page_count_mismatch", "bad_frequency", "desync",
})
GAP_FILL = 0.5  # an epoch with fewer than half its nominal samples is a gap row
ROWS_PER_SLICE = 1 << 14  # rows built at once: a gap of months is written a slice at a time
WARMUP_TOLERANCE_G = 0.001  # BFEN start-up: until the 1 g step response is below 1 mg


def filter_warmup_s(rate_hz: float, band) -> float:
    """Seconds after a segment start until the band-pass's response to a 1 g step (gravity
    appearing at the filter's zero initial state) stays below 1 mg."""
    sos = bandpass_sos(rate_hz, band)
    n = int(rate_hz * 120)
    y = SosStream(sos, 1).push(np.ones((n, 1)))[:, 0]
    above = np.flatnonzero(np.abs(y) > WARMUP_TOLERANCE_G)
    return 0.0 if above.shape[0] == 0 else float(above[-1] + 1) / rate_hz


@dataclass
class EpochRows:
    start_ns: np.ndarray  # (k,) int64, UTC (device clock when the zone is unknown)
    n: np.ndarray  # samples
    enmo_mg: np.ndarray
    bfen_mg: np.ndarray
    mad_mg: np.ndarray
    anglez_deg: np.ndarray
    temperature_c: np.ndarray
    nonwear: np.ndarray  # bool
    clipping: np.ndarray
    gap: np.ndarray
    qc: np.ndarray
    filter_warmup: np.ndarray
    # share of the epoch's samples an ActiGraph spent in idle sleep (its last sample repeated);
    # None for sources without idle sleep
    idle_sleep: Optional[np.ndarray] = None
    # (k, len(EXTRA_COLUMNS)): counts and MIMS-units when the run computes them, else NaN
    extra: Optional[np.ndarray] = None

    def __post_init__(self):
        if self.extra is None:
            self.extra = np.full((len(self), len(EXTRA_COLUMNS)), np.nan)

    def __len__(self) -> int:
        return int(self.start_ns.shape[0])

    def __getattr__(self, name):  # axis1, axis2, axis3, vm, mims
        if name in EXTRA_COLUMNS:
            return self.extra[:, EXTRA_COLUMNS.index(name)]
        raise AttributeError(name)

    @property
    def clean(self) -> np.ndarray:
        """Rows that may enter summaries: no flag set."""
        return ~(self.nonwear | self.clipping | self.gap | self.qc | self.filter_warmup)

    @staticmethod
    def concat(parts) -> "EpochRows":
        parts = [p for p in parts if len(p)]
        if not parts:
            return EpochRows(**{f.name: np.zeros(0, np.int64 if f.name in ("start_ns", "n") else
                                                 (bool if f.name in FLAGS else np.float64))
                                for f in fields(EpochRows) if f.name not in ("idle_sleep", "extra")})
        idle = None
        if any(p.idle_sleep is not None for p in parts):
            idle = np.concatenate([p.idle_sleep if p.idle_sleep is not None else np.zeros(len(p))
                                   for p in parts])
        return EpochRows(**{f.name: np.concatenate([getattr(p, f.name) for p in parts])
                            for f in fields(EpochRows) if f.name != "idle_sleep"}, idle_sleep=idle)


FLAGS = ("nonwear", "clipping", "gap", "qc", "filter_warmup")
# optional metric columns: ActiLife counts (ActiLife's order) and MIMS-units, per epoch
COUNT_COLUMNS = ("axis1", "axis2", "axis3", "vm")
EXTRA_COLUMNS = COUNT_COLUMNS + ("mims",)
EXTRA_WIDTH = {"counts": 3, "mims": 1}  # per-epoch sums the assembler keeps for each
_SECTORS = re.compile(r"sectors? (\d+)\.\.(\d+)")


def fold_sums(idx: np.ndarray, sums: np.ndarray, new_idx: np.ndarray,
              new_sums: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-epoch sums ``(idx, sums)`` (idx sorted and unique, sums (k, c)) with the rows
    ``(new_idx, new_sums)`` added; the rows of one epoch are added in the order they arrived."""
    idx = np.concatenate([idx, new_idx])
    sums = np.concatenate([sums, new_sums])
    order = np.argsort(idx, kind="stable")
    idx, sums = idx[order], sums[order]
    first = np.ones(idx.shape[0], bool)
    first[1:] = idx[1:] != idx[:-1]
    if first.all():
        return idx, sums
    out = sums[first]
    group = np.cumsum(first) - 1
    for i in np.flatnonzero(~first).tolist():  # an epoch cut by a segment break
        out[group[i]] += sums[i]
    return idx[first], out


def sums_between(idx: np.ndarray, sums: np.ndarray, lo: int, hi: int) -> tuple[np.ndarray, np.ndarray]:
    """The per-epoch sums of epochs ``lo <= idx < hi``: (offsets from lo, sums)."""
    a, b = np.searchsorted(idx, [lo, hi])
    return idx[a:b] - lo, sums[a:b]


class EpochAssembler:
    def __init__(self, rate_hz: float, epoch_s: float, band, *, source=None,
                 nonwear_version: str = "2023", clip_g: float = 7.5, extras=()):
        self.rate_hz = float(rate_hz)
        self.epoch_ns = int(round(epoch_s * 1e9))
        self.nominal = epoch_s * rate_hz
        self.source = source
        self.nonwear = NonwearOperator(rate_hz, version=nonwear_version, clip_g=clip_g)
        self.anglez = AnglezOperator(rate_hz, epoch_s)
        self.warmup_ns = int(round(filter_warmup_s(rate_hz, band) * 1e9))
        # per-epoch sums waiting for their row: (epoch indices, sorted; sums)
        self._metrics = (np.zeros(0, np.int64), np.zeros((0, 5)))  # n, enmo*n, bfen*n, mad*n, temp*n
        self._angle = (np.zeros(0, np.int64), np.zeros((0, 2)))  # n, anglez*n
        # optional metrics ("counts": axis sums (3); "mims": MIMS-units (1)): per-epoch sums
        # and the epoch below which they are final
        self._extras = {k: (np.zeros(0, np.int64), np.zeros((0, EXTRA_WIDTH[k]))) for k in extras}
        self._extras_done = {k: None for k in extras}
        # medium windows (indices, increasing; (k, 2) nonwear, clipping)
        self._windows = (np.zeros(0, np.int64), np.zeros((0, 2), bool))
        self.medium_ns = self.nonwear.medium_ns
        self._metrics_done = None  # epochs below this index are final in the metrics
        self._angle_done = None
        self._windows_done = None  # medium windows below this are final
        self._next = None  # next epoch index to emit
        # epochs older than the rows already written (a restart that sent the clock back): the
        # log holds them, the table cannot (it is written in time order as the run goes)
        self.epochs_not_in_table = 0
        self._segment = None
        self._warmups: list[tuple[int, int]] = []  # [start, end) ns after each segment start
        self._units = []  # (unit_index, first_ns, last_ns) arrays of recent Blocks
        self._qc_seen = 0
        self._qc_intervals: list[tuple[int, int]] = []
        self._qc_units: list[tuple[int, int]] = []  # flagged unit ranges not yet placed in time
        self._idle = None  # ActiGraph: (epoch indices, idle-sleep sample counts); None: no idle sleep

    # ------------------------------------------------------------------ inputs
    def _take_metrics(self, m) -> None:
        if m is None or not len(m):
            return
        idx = m.start_ns // self.epoch_ns
        if self._next is not None:  # a segment whose clock went back: its rows were written
            late = idx < self._next
            if late.any():
                self.epochs_not_in_table += int(np.unique(idx[late]).shape[0])
        w = m.n.astype(np.float64)
        rows = np.stack([w, m.enmo_mg * w, m.bfen_mg * w, m.mad_mg * w, m.temperature * w], axis=1)
        self._metrics = fold_sums(*self._metrics, idx, rows)
        # metrics are emitted in time order: the last row's epoch may still get a second part
        last = int(idx[-1])
        self._metrics_done = last if self._metrics_done is None else max(self._metrics_done, last)

    def _take_extras(self, extras) -> None:
        for k, m in (extras or {}).items():
            if k not in self._extras or m is None or not len(m):
                continue
            idx = m.start_ns // self.epoch_ns
            self._extras[k] = fold_sums(*self._extras[k], idx, m.epoch_values())
            last = int(idx[-1])
            done = self._extras_done[k]
            self._extras_done[k] = last if done is None else max(done, last)

    def _take_angle(self, res) -> None:
        s, n, v = res
        if not s.shape[0]:
            return
        idx = s // self.epoch_ns
        w = n.astype(np.float64)
        self._angle = fold_sums(*self._angle, idx, np.stack([w, v * w], axis=1))
        last = int(idx[-1])
        self._angle_done = last if self._angle_done is None else max(self._angle_done, last)

    def _take_windows(self, w: NonwearWindows) -> None:
        if not len(w):
            return
        idx = w.start_ns // self.medium_ns
        flags = np.stack([w.nonwear, w.clipping], axis=1).astype(bool)
        self._windows = (np.concatenate([self._windows[0], idx]),
                         np.concatenate([self._windows[1], flags]))
        self._windows_done = int(idx[-1]) + 1

    def _take_block(self, block) -> None:
        if block is None or block.m == 0:
            return
        idle = block.per_sample.get(PER_SAMPLE_IDLE_SLEEP)
        if idle is not None:
            if self._idle is None:
                self._idle = (np.zeros(0, np.int64), np.zeros((0, 1)))
            if idle.any():
                e, c = np.unique(block.time_ns[idle != 0] // self.epoch_ns, return_counts=True)
                self._idle = fold_sums(*self._idle, e.astype(np.int64), c[:, None].astype(np.float64))
        ends = np.append(block.unit_start[1:], block.n) - 1
        self._units.append((block.unit_index.copy(), block.time_ns[block.unit_start].copy(),
                            block.time_ns[ends].copy()))

    def _take_qc(self) -> None:
        events = getattr(getattr(self.source, "qc", None), "events", None) or []
        while self._qc_seen < len(events):
            e = events[self._qc_seen]
            self._qc_seen += 1
            if e.reason not in QC_FLAGGED_REASONS or e.samples:
                continue  # not a flag on kept data (or the unit's samples were dropped)
            m = _SECTORS.search(e.detail or "")
            lo, hi = (int(m.group(1)), int(m.group(2))) if m else (e.index, e.index)
            self._qc_units.append((lo, hi))
            if not self._units and e.time_ns is not None:  # no unit map (e.g. replayed log)
                self._qc_intervals.append((int(e.time_ns), int(e.time_ns) + 1))
        if self._qc_units and self._units:
            ui = np.concatenate([u[0] for u in self._units])
            t0 = np.concatenate([u[1] for u in self._units])
            t1 = np.concatenate([u[2] for u in self._units])
            left = []
            for lo, hi in self._qc_units:
                sel = (ui >= lo) & (ui <= hi)
                if sel.any():
                    self._qc_intervals.append((int(t0[sel].min()), int(t1[sel].max()) + 1))
                if not sel.any() or ui.max() < hi:
                    left.append((lo, hi))  # units not seen yet (or not any more)
            self._qc_units = left[-1000:]

    def _take_batches(self, batches) -> list:
        out = []
        for b in batches:
            if b.n == 0:
                continue
            if b.segment != self._segment:
                self._segment = b.segment
                t0 = int(b.time_ns[0])
                self._warmups.append((t0, t0 + self.warmup_ns))
            self._take_windows(self.nonwear.push(b))
            self._take_angle(self.anglez.push(b))
        return out

    # ------------------------------------------------------------------ rows
    def push(self, block, batches, metrics, extras=None) -> Iterator[EpochRows]:
        """Take one output step; returns the rows it made final, in slices of at most
        ``ROWS_PER_SLICE`` (an iterator: consume it before the next push). A recording with a
        gap of months has millions of gap rows; they are never one array."""
        self._take_block(block)
        self._take_batches(batches)
        self._take_metrics(metrics)
        self._take_extras(extras)
        self._take_qc()
        return self._emit(final=False)

    def flush(self, metrics=None, extras=None) -> Iterator[EpochRows]:
        """The rows still held, in slices as ``push``."""
        self._take_metrics(metrics)
        self._take_extras(extras)
        self._take_windows(self.nonwear.flush())
        self._take_angle(self.anglez.flush())
        self._take_qc()
        return self._emit(final=True)

    def _emit(self, final: bool) -> Iterator[EpochRows]:
        pending = [i for i in (self._metrics[0], self._angle[0]) if i.shape[0]]
        pending += [e[0] for e in self._extras.values() if e[0].shape[0]]
        if self._next is None:
            if not pending:
                return
            self._next = min(int(i[0]) for i in pending)
        if final:
            stop = max(int(i[-1]) for i in pending) + 1 if pending else self._next
        else:
            extra_done = list(self._extras_done.values())
            if None in (self._metrics_done, self._angle_done, self._windows_done, *extra_done):
                return
            stop = min(self._metrics_done, self._angle_done,
                       (self._windows_done * self.medium_ns) // self.epoch_ns, *extra_done)
        while self._next < stop:
            end = min(stop, self._next + ROWS_PER_SLICE)
            rows = self._rows(np.arange(self._next, end, dtype=np.int64))
            self._next = end
            self._forget(end)
            yield rows

    def _rows(self, k: np.ndarray) -> EpochRows:
        m = len(k)
        lo, hi = int(k[0]), int(k[-1]) + 1
        n = np.zeros(m, np.int64)
        vals = np.full((m, 5), np.nan)
        at, r = sums_between(*self._metrics, lo, hi)
        ok = r[:, 0] > 0
        at, r = at[ok], r[ok]
        n[at] = r[:, 0].astype(np.int64)
        vals[at, 0] = r[:, 0]
        vals[at, 1:] = r[:, 1:] / r[:, :1]
        ang = np.full(m, np.nan)
        at, a = sums_between(*self._angle, lo, hi)
        ok = a[:, 0] > 0
        ang[at[ok]] = a[ok, 1] / a[ok, 0]
        start = k * self.epoch_ns
        nonwear, clipping = self._window_flags(start // self.medium_ns)
        end = start + self.epoch_ns
        qc = np.zeros(m, bool)
        for a0, a1 in self._qc_intervals:
            qc |= (start < a1) & (end > a0)
        warm = np.zeros(m, bool)
        for a0, a1 in self._warmups:
            warm |= (start < a1) & (end > a0)
        gap = n < GAP_FILL * self.nominal
        extra = None
        if self._extras:
            extra = np.full((m, len(EXTRA_COLUMNS)), np.nan)
            if "counts" in self._extras:
                at, c = sums_between(*self._extras["counts"], lo, hi)
                extra[at, :3] = c
                extra[at, 3] = np.sqrt(np.einsum("ij,ij->i", c, c))
            if "mims" in self._extras:
                at, v = sums_between(*self._extras["mims"], lo, hi)
                extra[at, 4] = v[:, 0]

        idle = None
        if self._idle is not None:
            idle = np.zeros(m)
            at, c = sums_between(*self._idle, lo, hi)
            idle[at] = c[:, 0]
            idle = np.where(n > 0, idle / np.maximum(n, 1), np.nan)
        return EpochRows(start, n, vals[:, 1], vals[:, 2], vals[:, 3], ang, vals[:, 4], nonwear,
                         clipping, gap, qc, warm, idle, extra)

    def _window_flags(self, wi: np.ndarray) -> np.ndarray:
        """(2, k): nonwear and clipping of the medium windows ``wi`` (False for windows not seen)."""
        idx, flags = self._windows
        out = np.zeros((2, wi.shape[0]), bool)
        if idx.shape[0]:
            j = np.searchsorted(idx, wi, side="right") - 1
            seen = (j >= 0) & (idx[np.maximum(j, 0)] == wi)
            out[:, seen] = flags[j[seen]].T
        return out

    def _forget(self, stop: int) -> None:
        t = stop * self.epoch_ns
        w = t // self.medium_ns
        self._metrics = tuple(x[self._metrics[0] >= stop] for x in self._metrics)
        self._angle = tuple(x[self._angle[0] >= stop] for x in self._angle)
        if self._idle is not None:
            self._idle = tuple(x[self._idle[0] >= stop] for x in self._idle)
        for k, e in self._extras.items():
            self._extras[k] = tuple(x[e[0] >= stop] for x in e)
        self._windows = tuple(x[self._windows[0] >= w] for x in self._windows)
        self._warmups = [x for x in self._warmups if x[1] > t] or self._warmups[-1:]
        self._qc_intervals = [x for x in self._qc_intervals if x[1] > t - 3600 * 10**9]
        horizon = t - 3 * 3600 * 10**9  # a late QC event can still place units of the last 3 h
        self._units = [u for u in self._units if u[2].shape[0] and u[2][-1] >= horizon]
