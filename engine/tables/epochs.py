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
* ``filter_warmup``: the epoch starts within the BFEN filter's start-up time after a segment start
  (the time its response to a 1 g step needs to fall below 1 mg).

Rows wait for the nonwear decision (about 75 min of data), so memory holds about an hour and a
half of epochs whatever the recording's length.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, fields

import numpy as np

from ..operators.anglez import AnglezOperator
from ..operators.filters import SosStream, bandpass_sos
from ..operators.nonwear import NonwearOperator, NonwearWindows

# Reader QC reasons whose samples are kept but flagged (drivers/cwa_reader.py, drivers/geneactiv.py).
QC_FLAGGED_REASONS = frozenset({
    "bad_timestamp", "bad_anchor", "bad_count", "device_overflow", "axis_swap", "truncated",
    "bad_page_time", "page_time_fixed", "page_count_mismatch", "bad_frequency", "desync",
})
GAP_FILL = 0.5  # an epoch with fewer than half its nominal samples is a gap row
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

    def __len__(self) -> int:
        return int(self.start_ns.shape[0])

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
                                for f in fields(EpochRows)})
        return EpochRows(**{f.name: np.concatenate([getattr(p, f.name) for p in parts])
                            for f in fields(EpochRows)})


FLAGS = ("nonwear", "clipping", "gap", "qc", "filter_warmup")
_SECTORS = re.compile(r"sectors? (\d+)\.\.(\d+)")


class EpochAssembler:
    def __init__(self, rate_hz: float, epoch_s: float, band, *, source=None,
                 nonwear_version: str = "2023", clip_g: float = 7.5):
        self.rate_hz = float(rate_hz)
        self.epoch_ns = int(round(epoch_s * 1e9))
        self.nominal = epoch_s * rate_hz
        self.source = source
        self.nonwear = NonwearOperator(rate_hz, version=nonwear_version, clip_g=clip_g)
        self.anglez = AnglezOperator(rate_hz, epoch_s)
        self.warmup_ns = int(round(filter_warmup_s(rate_hz, band) * 1e9))
        self._metrics: dict[int, list] = {}  # epoch index -> [n, enmo*n, bfen*n, mad*n, temp*n]
        self._angle: dict[int, list] = {}  # epoch index -> [n, sum]
        self._windows: dict[int, tuple] = {}  # medium window index -> (nonwear, clipping)
        self.medium_ns = self.nonwear.medium_ns
        self._metrics_done = None  # epochs below this index are final in the metrics
        self._angle_done = None
        self._windows_done = None  # medium windows below this are final
        self._next = None  # next epoch index to emit
        self._segment = None
        self._warmups: list[tuple[int, int]] = []  # [start, end) ns after each segment start
        self._units = []  # (unit_index, first_ns, last_ns) arrays of recent Blocks
        self._qc_seen = 0
        self._qc_intervals: list[tuple[int, int]] = []
        self._qc_units: list[tuple[int, int]] = []  # flagged unit ranges not yet placed in time

    # ------------------------------------------------------------------ inputs
    def _take_metrics(self, m) -> None:
        if m is None or not len(m):
            return
        idx = m.start_ns // self.epoch_ns
        for i in range(len(m)):
            k = int(idx[i])
            w = float(m.n[i])
            r = self._metrics.get(k)
            vals = [w, m.enmo_mg[i] * w, m.bfen_mg[i] * w, m.mad_mg[i] * w, m.temperature[i] * w]
            if r is None:
                self._metrics[k] = vals
            else:
                for j in range(5):
                    r[j] += vals[j]
        # metrics are emitted in time order: the last row's epoch may still get a second part
        last = int(idx[-1])
        self._metrics_done = last if self._metrics_done is None else max(self._metrics_done, last)

    def _take_angle(self, res) -> None:
        s, n, v = res
        if not s.shape[0]:
            return
        idx = s // self.epoch_ns
        for i in range(s.shape[0]):
            k = int(idx[i])
            r = self._angle.get(k)
            if r is None:
                self._angle[k] = [float(n[i]), float(v[i]) * n[i]]
            else:
                r[0] += n[i]
                r[1] += float(v[i]) * n[i]
        last = int(idx[-1])
        self._angle_done = last if self._angle_done is None else max(self._angle_done, last)

    def _take_windows(self, w: NonwearWindows) -> None:
        if not len(w):
            return
        idx = w.start_ns // self.medium_ns
        for i in range(len(w)):
            self._windows[int(idx[i])] = (bool(w.nonwear[i]), bool(w.clipping[i]))
        self._windows_done = int(idx[-1]) + 1

    def _take_block(self, block) -> None:
        if block is None or block.m == 0:
            return
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
    def push(self, block, batches, metrics) -> EpochRows:
        self._take_block(block)
        self._take_batches(batches)
        self._take_metrics(metrics)
        self._take_qc()
        return self._emit(final=False)

    def flush(self, metrics=None) -> EpochRows:
        self._take_metrics(metrics)
        self._take_windows(self.nonwear.flush())
        self._take_angle(self.anglez.flush())
        self._take_qc()
        return self._emit(final=True)

    def _emit(self, final: bool) -> EpochRows:
        keys = list(self._metrics) + list(self._angle)
        if self._next is None:
            if not keys:
                return EpochRows.concat([])
            self._next = min(keys)
        if final:
            stop = max(keys) + 1 if keys else self._next
        else:
            if None in (self._metrics_done, self._angle_done, self._windows_done):
                return EpochRows.concat([])
            stop = min(self._metrics_done, self._angle_done,
                       (self._windows_done * self.medium_ns) // self.epoch_ns)
        if stop <= self._next:
            return EpochRows.concat([])
        k = np.arange(self._next, stop, dtype=np.int64)
        rows = self._rows(k)
        self._next = stop
        self._forget(stop)
        return rows

    def _rows(self, k: np.ndarray) -> EpochRows:
        m = len(k)
        n = np.zeros(m, np.int64)
        vals = np.full((m, 5), np.nan)
        ang = np.full(m, np.nan)
        for i, e in enumerate(k.tolist()):
            r = self._metrics.pop(e, None)
            if r is not None and r[0] > 0:
                n[i] = int(r[0])
                vals[i] = [r[0]] + [x / r[0] for x in r[1:]]
            a = self._angle.pop(e, None)
            if a is not None and a[0] > 0:
                ang[i] = a[1] / a[0]
        start = k * self.epoch_ns
        wi = start // self.medium_ns
        nonwear = np.array([self._windows.get(int(w), (False, False))[0] for w in wi], bool)
        clipping = np.array([self._windows.get(int(w), (False, False))[1] for w in wi], bool)
        end = start + self.epoch_ns
        qc = np.zeros(m, bool)
        for a0, a1 in self._qc_intervals:
            qc |= (start < a1) & (end > a0)
        warm = np.zeros(m, bool)
        for a0, a1 in self._warmups:
            warm |= (start < a1) & (end > a0)
        gap = n < GAP_FILL * self.nominal
        return EpochRows(start, n, vals[:, 1], vals[:, 2], vals[:, 3], ang, vals[:, 4], nonwear,
                         clipping, gap, qc, warm)

    def _forget(self, stop: int) -> None:
        t = stop * self.epoch_ns
        w = t // self.medium_ns
        for d in [x for x in self._windows if x < w]:
            del self._windows[d]
        self._warmups = [x for x in self._warmups if x[1] > t] or self._warmups[-1:]
        self._qc_intervals = [x for x in self._qc_intervals if x[1] > t - 3600 * 10**9]
        horizon = t - 3 * 3600 * 10**9  # a late QC event can still place units of the last 3 h
        self._units = [u for u in self._units if u[2].shape[0] and u[2][-1] >= horizon]
