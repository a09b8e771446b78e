"""The output pass: raw blocks -> correction -> epoch metrics -> counts / MIMS-units -> taps.

``OutputPass`` is the one wiring of "correct, then epoch metrics, then the consumers" (the epoch
and day tables, sleep, ...: taps with ``push(block, corrected batches, epoch metrics, extras)``
and ``flush(last metrics, last extras)``). ``OutputStage`` is the run's pipeline stage over it:
it also logs the raw, corrected and metric streams, the reader's QC events, segment starts and
clipping to the MCAP log. The tables from a log and an online run's tables use ``OutputPass``
itself (``engine.tables.estimate_pass``).
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from ..calibration.estimate import CalibrationEstimate
from ..clipping import ClippingMonitor
from ..core.blocks import Block
from ..mcap.sink import McapSink
from ..operators.correction import CorrectionOperator
from ..operators.extras import ExtraMetrics
from ..operators.metrics import EpochMetrics, MetricsOperator


class OutputPass:
    """Block -> correction -> epoch metrics (and counts, MIMS-units when on) -> ``taps``."""

    def __init__(self, correction: CorrectionOperator, settings, rate_hz: float,
                 range_g: Optional[float]):
        self.correction = correction
        self.metrics = MetricsOperator(rate_hz, settings.epoch_s, settings.bfen_band_hz)
        self.extras = ExtraMetrics(settings, rate_hz, range_g)  # counts, MIMS-units (when on)
        self.taps: list = []  # consumers of (block, corrected batches, epoch metrics, extras)

    def push(self, block: Block) -> None:
        """Correct one block and hand what it gives to the taps."""
        self._step(block, self.correction.push(block))

    def flush(self) -> None:
        """End of the stream: the correction's, the metrics' and the extras' last output."""
        self._step(None, self.correction.flush())
        self._deliver_last(self.metrics.flush(), self.extras.flush())

    def _step(self, block: Optional[Block], batches) -> None:
        ms = [self.metrics.push(b) for b in batches]
        m = EpochMetrics.concat(ms) if len(ms) != 1 else ms[0]
        self._deliver(block, batches, m, self.extras.push(batches))

    def _deliver(self, block: Optional[Block], batches, m: EpochMetrics, ex: dict) -> None:
        for tap in self.taps:
            tap.push(block, batches, m, ex)

    def _deliver_last(self, m: EpochMetrics, ex: dict) -> None:
        for tap in self.taps:
            tap.flush(m, ex)


class OutputStage(OutputPass):
    """A run's output stage: the output pass, logging raw + corrected + metrics to MCAP."""

    def __init__(self, s, rate_hz: float, sink: McapSink, source,
                 initial: CalibrationEstimate, gate=None):
        range_g = getattr(getattr(source, "info", None), "accel_range_g", None)
        super().__init__(CorrectionOperator(initial, rate_hz=rate_hz, gate=gate), s, rate_hz,
                         range_g)
        self.sink = sink
        self.source = source
        self.epochs = 0
        self.enmo_weighted = 0.0
        self.samples_metrics = 0
        self._qc_logged = 0
        self._last_ns = 0
        self._segment = None
        self.clipping = ClippingMonitor(range_g, rate_hz)

    def _log_reader_qc(self) -> None:
        events = getattr(getattr(self.source, "qc", None), "events", [])
        while self._qc_logged < len(events):
            e = events[self._qc_logged]
            t = e.time_ns if e.time_ns is not None else self._last_ns
            # an event without a time of its own is pinned to the data time it was logged at, so
            # a replay (which may see it at another block boundary) logs it at the same time
            d = dict(e.as_dict(), source="reader", time_ns=t)
            self.sink.write_qc(d, t)
            self._qc_logged += 1

    def _tally(self, m: EpochMetrics) -> None:
        if len(m):
            self.epochs += len(m)
            self.enmo_weighted += float(np.dot(m.enmo_mg, m.n))
            self.samples_metrics += int(m.n.sum())

    def _deliver(self, block, batches, m, ex) -> None:
        self._tally(m)
        self.sink.write_slices(block, batches, m)
        if ex:
            self.sink.write_extras(ex)
        super()._deliver(block, batches, m, ex)

    def _deliver_last(self, m, ex) -> None:
        if len(m):
            self._tally(m)
            self.sink.write_slices(None, [], m)
        if ex:
            self.sink.write_extras(ex)
        super()._deliver_last(m, ex)

    def push(self, block: Block) -> None:
        """Log the reader's QC and a new segment, watch clipping, then run the output pass."""
        self._last_ns = int(block.time_ns[0])
        self._log_reader_qc()
        if block.segment != self._segment:
            self._segment = block.segment
            self.sink.write_qc({"source": "engine", "reason": "segment_start",
                                "segment": block.segment, "index": int(block.unit_index[0])
                                if block.m else -1, "time_ns": self._last_ns}, self._last_ns)
        self.clipping.observe(block)
        super().push(block)

    def flush(self) -> None:
        """End of the stream: the last QC events, then the output pass's last output."""
        self._log_reader_qc()
        super().flush()

    @property
    def enmo_mean_mg(self) -> Optional[float]:
        """Mean ENMO (mg) over every epoch's samples; None before any epoch."""
        return self.enmo_weighted / self.samples_metrics if self.samples_metrics else None
