"""Correction: apply the calibration estimate in force at each sample, with interpolated temperature.

Temperature interpolation (stated once, used everywhere a per-sample temperature is corrected):
a sector's (.cwa) or page's (.bin) temperature is taken as measured at the time of its **last
sample** (the device reads the sensor when it closes the unit). A sample between the last samples
of units i-1 and i gets the linear interpolation of their two temperatures; samples of the first
unit of a segment take that unit's value (nothing to interpolate from across a gap). Interpolation
uses times relative to the segment start, so it never depends on how the stream was cut. The
price is a latency of one unit: a unit's samples are released once the unit is complete.

The estimate in force at a sample is the one with the latest ``effective_from_ns`` not after the
sample time (``None`` counts as "from the start"). In online mode the estimates for a stretch of
data are only final once the calibrator has seen it, so an optional ``gate`` callable returns the
data time before which the schedule is final; later samples wait in a ring buffer.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Optional

import numpy as np

from ..core.blocks import Block
from ..calibration.estimate import CalibrationEstimate
from ..core.ringbuffer import RingBuffer
from .base import accel_g_columns, apply_columns, ring_capacity


@dataclass
class CorrectedBatch:
    """Consecutive corrected samples of one segment."""

    time_ns: np.ndarray  # (n,) int64
    accel: np.ndarray  # (n, 3) float64 g, calibrated
    temperature: np.ndarray  # (n,) float64 degC, interpolated
    segment: int

    @property
    def n(self) -> int:
        return int(self.time_ns.shape[0])

    @staticmethod
    def concat(parts) -> "CorrectedBatch":
        parts = [p for p in parts if p.n]
        return CorrectedBatch(np.concatenate([p.time_ns for p in parts]),
                              np.concatenate([p.accel for p in parts]),
                              np.concatenate([p.temperature for p in parts]), parts[0].segment)


class TemperatureInterpolator:
    """push(Block) -> list[CorrectedBatch] of raw g with per-sample temperature (not yet calibrated)."""

    def __init__(self, capacity: int = 1 << 16):
        self._ring = RingBuffer(capacity, time=(np.int64, ()), accel=(np.float64, (3,)))
        self.segment = None
        self._t0 = 0
        self._prev = None  # (relative time of the previous unit's last sample, its temperature)
        self._open_unit = None  # file index of the unit whose samples are in the ring
        self._open_temp = np.nan
        self._open_last = 0

    def _release(self, time_ns, accel, anchors_t, anchors_v) -> CorrectedBatch:
        rel = (time_ns - self._t0).astype(np.float64)
        if anchors_t:
            temp = np.interp(rel, np.asarray(anchors_t, np.float64), np.asarray(anchors_v, np.float64))
        else:
            temp = np.full(time_ns.shape[0], np.nan)
        return CorrectedBatch(time_ns, accel, temp, self.segment)

    def _finish_segment(self) -> list[CorrectedBatch]:
        if self._open_unit is None or len(self._ring) == 0:
            self._open_unit = None
            return []
        held = self._ring.view()
        at, av = self._anchors_with_open()
        out = self._release(np.array(held["time"]), np.array(held["accel"]), at, av)
        self._ring.clear()
        self._open_unit = None
        return [out]

    def _anchors_with_open(self):
        at, av = [], []
        if self._prev is not None:
            at.append(self._prev[0])
            av.append(self._prev[1])
        at.append(float(self._open_last - self._t0))
        av.append(self._open_temp)
        return at, av

    def push(self, block: Block) -> list[CorrectedBatch]:
        out: list[CorrectedBatch] = []
        n = block.n
        if n == 0:
            return out
        if block.segment != self.segment:
            out += self._finish_segment()
            self.segment = block.segment
            self._t0 = int(block.time_ns[0])
            self._prev = None
        if block.m:
            us, uidx, utemp = block.unit_start, block.unit_index, block.temperature_c
        else:  # a block without unit arrays: one unit of unknown temperature
            us, uidx, utemp = np.zeros(1, np.int64), np.array([-1]), np.array([np.nan])
        t = block.time_ns
        continuing = self._open_unit is not None and uidx[0] == self._open_unit and uidx[0] >= 0
        if continuing and len(us) == 1:
            self._ring.append(time=t, accel=accel_g_columns(block))
            self._open_last = int(t[-1])
            return out
        anchors_t, anchors_v = [], []
        if self._prev is not None:
            anchors_t.append(self._prev[0])
            anchors_v.append(self._prev[1])
        if self._open_unit is not None and not continuing:
            anchors_t.append(float(self._open_last - self._t0))
            anchors_v.append(self._open_temp)
        ends = us[1:]  # exclusive ends of the complete units in this block
        anchors_t += (t[ends - 1] - self._t0).astype(np.float64).tolist()
        anchors_v += utemp[:len(ends)].tolist()
        cut = int(us[-1])
        if len(self._ring):  # the held samples, then the block's, in one (3, h + n) buffer
            held = self._ring.view()
            tt = np.concatenate([held["time"], t[:cut]])
            h = held["time"].shape[0]
            gc = np.empty((3, h + n))  # column by column, like g: (n, 3) view of (3, n)
            gc[:, :h] = held["accel"].T
            g = accel_g_columns(block, gc[:, h:])
            gg = gc[:, :h + cut].T
            self._ring.clear()
        else:
            g = accel_g_columns(block)
            tt, gg = t[:cut], g[:cut]
        if tt.shape[0]:
            out.append(self._release(tt, gg, anchors_t, anchors_v))
        if anchors_t:
            self._prev = (anchors_t[-1], anchors_v[-1])
        self._ring.append(time=t[cut:], accel=g[cut:])
        self._open_unit = int(uidx[-1])
        self._open_temp = float(utemp[-1])
        self._open_last = int(t[-1])
        return out

    def flush(self) -> list[CorrectedBatch]:
        return self._finish_segment()


class EstimateSchedule:
    """The estimates in force over data time: each applies from its ``effective_from_ns``."""

    def __init__(self, initial: Optional[CalibrationEstimate] = None):
        self._est: list[CalibrationEstimate] = [initial or CalibrationEstimate.identity()]
        self._from: list[float] = [-np.inf]

    def add(self, est: CalibrationEstimate) -> None:
        t = -np.inf if est.effective_from_ns is None else float(est.effective_from_ns)
        if t == -np.inf:
            self._est, self._from = [est], [t]
            return
        i = int(np.searchsorted(self._from, t, side="right"))
        self._est.insert(i, est)
        self._from.insert(i, t)

    @property
    def current(self) -> CalibrationEstimate:
        return self._est[-1]

    @property
    def estimates(self) -> list[CalibrationEstimate]:
        return list(self._est)

    def apply(self, batch: CorrectedBatch) -> CorrectedBatch:
        """Calibrate a batch of raw g (per-sample estimate in force); the result is the (n, 3)
        view of a (3, n) array (``CalibrationEstimate.apply``'s numbers, column by column)."""
        if len(self._est) == 1:
            return CorrectedBatch(batch.time_ns, apply_columns(self._est[0], batch.accel,
                                                               batch.temperature),
                                  batch.temperature, batch.segment)
        # compare in int64 ns (exact); -inf entries map to the smallest int64
        eff = np.array([np.iinfo(np.int64).min if f == -np.inf else int(e.effective_from_ns)
                        for f, e in zip(self._from, self._est)], np.int64)
        one = self._one_estimate(eff, batch.time_ns)
        if one is not None:
            out = apply_columns(self._est[one], batch.accel, batch.temperature)
        else:
            out_t = np.empty((3, batch.n))
            idx = np.searchsorted(eff, batch.time_ns, side="right") - 1
            idx = np.maximum(idx, 0)
            bounds = np.concatenate([[0], np.flatnonzero(idx[1:] != idx[:-1]) + 1, [batch.n]])
            for a, b in zip(bounds[:-1], bounds[1:]):
                apply_columns(self._est[int(idx[a])], batch.accel[a:b], batch.temperature[a:b],
                              out_t[:, a:b])
            out = out_t.T
        return CorrectedBatch(batch.time_ns, out, batch.temperature, batch.segment)

    @staticmethod
    def _one_estimate(eff: np.ndarray, time_ns: np.ndarray) -> Optional[int]:
        """The index of the one estimate in force at every sample time, or None when the
        samples span a change. Between two refits (nearly every batch) this takes the extremes
        of the times instead of a binary search per sample; the choice is the per-sample
        search's: every time in [eff[i], eff[i + 1]) maps to i."""
        if time_ns.shape[0] == 0:
            return None
        lo, hi = int(time_ns.min()), int(time_ns.max())
        i = int(np.searchsorted(eff, lo, side="right")) - 1
        if i < 0 or (i + 1 < eff.shape[0] and hi >= int(eff[i + 1])):
            return None
        return i


class CorrectionOperator:
    """push(Block) -> list[CorrectedBatch] (calibrated g); flush() releases everything held.

    ``gate()`` (optional) returns the data time (ns) before which the estimate schedule is final;
    samples at or after it are held until a later push or ``flush()``.
    """

    def __init__(self, initial: Optional[CalibrationEstimate] = None, *, rate_hz: float = 100.0,
                 gate: Optional[Callable[[], Optional[int]]] = None):
        self.schedule = EstimateSchedule(initial)
        self._temp = TemperatureInterpolator(ring_capacity(5.0, rate_hz, minimum=1 << 15))
        self.gate = gate
        self._held: list[CorrectedBatch] = []  # interpolated, awaiting the gate (bounded by gate lag)
        self.samples = 0

    def add_estimate(self, est: CalibrationEstimate) -> None:
        self.schedule.add(est)

    def _release(self, batches, final_until) -> list[CorrectedBatch]:
        out = []
        if final_until is None:
            ready, self._held = self._held + batches, []
        else:
            ready, keep = [], []
            for b in self._held + batches:
                k = int(np.searchsorted(b.time_ns, final_until, side="left"))
                if k == b.n:
                    ready.append(b)
                elif k == 0:
                    keep.append(b)
                else:
                    ready.append(CorrectedBatch(b.time_ns[:k], b.accel[:k], b.temperature[:k], b.segment))
                    keep.append(CorrectedBatch(b.time_ns[k:], b.accel[k:], b.temperature[k:], b.segment))
            self._held = keep
        for b in ready:
            c = self.schedule.apply(b)
            self.samples += c.n
            out.append(c)
        return out

    def push(self, block: Block) -> list[CorrectedBatch]:
        batches = self._temp.push(block)
        return self._release(batches, self.gate() if self.gate else None)

    def flush(self) -> list[CorrectedBatch]:
        return self._release(self._temp.flush(), None)
