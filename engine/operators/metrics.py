"""Epoch metrics (default 5 s epochs on the UTC clock grid): ENMO, BFEN and MAD, in mg.

Per sample, on calibrated acceleration in g with norm r = |a|:

* ENMO: ``max(r - 1, 0)`` (negative values set to zero, as GGIR), averaged over the epoch;
* BFEN: ``|bandpass(a)|``: each axis through a 4th-order Butterworth band-pass (0.2-15 Hz, GGIR's
  default; 0.5-15 Hz as in van Hees et al. 2013 selectable), then the Euclidean norm, averaged.
  The filter runs over each segment as one signal (state carried across blocks, reset at a gap);
* MAD: mean over the epoch of ``|r - mean(r)|``.

Epochs are cut on the UTC grid (``[k*5 s, (k+1)*5 s)``) and never span a segment: an epoch cut by
a gap yields two rows (one per segment), each with its sample count ``n``. Also reported: mean x,
y, z (g) and mean temperature per epoch (the plot-friendly preview of the corrected stream).
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from .base import ring_capacity
from .binning import BinChunk, TimeBinner
from .correction import CorrectedBatch
from .filters import BFEN_BAND_GGIR, SosStream, bandpass_sos

EPOCH_S = 5.0  # GGIR default short epoch (windowsizes[1] = 5 s)


@dataclass
class EpochMetrics:
    start_ns: np.ndarray  # (k,) int64 epoch start on the UTC grid
    n: np.ndarray  # (k,) int64 samples
    enmo_mg: np.ndarray
    bfen_mg: np.ndarray
    mad_mg: np.ndarray
    mean: np.ndarray  # (k, 3) g
    temperature: np.ndarray  # (k,) degC
    segment: np.ndarray  # (k,) int64

    def __len__(self) -> int:
        return int(self.start_ns.shape[0])

    @staticmethod
    def empty() -> "EpochMetrics":
        z = np.zeros(0)
        return EpochMetrics(np.zeros(0, np.int64), np.zeros(0, np.int64), z, z, z, np.zeros((0, 3)),
                            z, np.zeros(0, np.int64))

    @staticmethod
    def concat(parts) -> "EpochMetrics":
        parts = [p for p in parts if len(p)]
        if not parts:
            return EpochMetrics.empty()
        return EpochMetrics(**{f.name: np.concatenate([getattr(p, f.name) for p in parts])
                               for f in fields(EpochMetrics)})


def _norm_in_place(x: np.ndarray) -> np.ndarray:
    """Euclidean norm of the columns of a (3, n) array the caller gives up, computed in its
    first row: ``sqrt((x0*x0 + x1*x1) + x2*x2)``, the sum in ``einsum("ij,ij->i")``'s order."""
    x0, x1, x2 = x
    np.multiply(x0, x0, out=x0)
    np.multiply(x1, x1, out=x1)
    x0 += x1
    np.multiply(x2, x2, out=x2)
    x0 += x2
    return np.sqrt(x0, out=x0)


def chunk_metrics(chunk: BinChunk, width_ns: int) -> EpochMetrics:
    st, cnt = chunk.starts, chunk.counts
    c = chunk.cols
    r = c["norm"]
    mean_r = np.add.reduceat(r, st) / cnt
    dev = np.repeat(mean_r, cnt)
    np.subtract(r, dev, out=dev)
    mad = np.add.reduceat(np.abs(dev, out=dev), st) / cnt
    return EpochMetrics(
        start_ns=chunk.bin_start_ns(width_ns), n=cnt.astype(np.int64),
        enmo_mg=np.add.reduceat(c["enmo"], st) / cnt * 1000.0,
        bfen_mg=np.add.reduceat(c["bfen"], st) / cnt * 1000.0,
        mad_mg=mad * 1000.0,
        mean=np.add.reduceat(c["accel"], st, axis=0) / cnt[:, None],
        temperature=np.add.reduceat(c["temperature"], st) / cnt,
        segment=np.full(len(cnt), chunk.segment, np.int64))


class MetricsOperator:
    """push(CorrectedBatch) -> EpochMetrics of the epochs it completed; flush() -> the rest."""

    def __init__(self, rate_hz: float, epoch_s: float = EPOCH_S, band=BFEN_BAND_GGIR):
        self.rate_hz = float(rate_hz)
        self.epoch_s = float(epoch_s)
        self.band = tuple(band)
        self._filter = SosStream(bandpass_sos(rate_hz, band), 3)
        self._segment = None
        self._binner = TimeBinner(epoch_s, {"norm": (np.float64, ()), "enmo": (np.float64, ()),
                                            "bfen": (np.float64, ()), "accel": (np.float64, (3,)),
                                            "temperature": (np.float64, ())},
                                  align="clock", capacity=ring_capacity(epoch_s, rate_hz))
        self.enmo_sum_mg = 0.0  # sum over samples of ENMO (mg), for the run's mean
        self.samples = 0

    def _rows(self, chunks) -> EpochMetrics:
        if not chunks:
            return EpochMetrics.empty()
        return EpochMetrics.concat([chunk_metrics(c, self._binner.width_ns) for c in chunks])

    def push(self, batch: CorrectedBatch) -> EpochMetrics:
        if batch.n == 0:
            return EpochMetrics.empty()
        if batch.segment != self._segment:
            self._filter.reset()
            self._segment = batch.segment
        a = batch.accel
        r = np.sqrt(np.einsum("ij,ij->i", a, a))
        enmo = np.subtract(r, 1.0)
        np.maximum(enmo, 0.0, out=enmo)
        bfen = _norm_in_place(self._filter.push(a).T)
        self.enmo_sum_mg += float(enmo.sum()) * 1000.0
        self.samples += batch.n
        return self._rows(self._binner.push(batch.segment, batch.time_ns, norm=r, enmo=enmo,
                                            bfen=bfen, accel=a, temperature=batch.temperature))

    def flush(self) -> EpochMetrics:
        return self._rows(self._binner.flush())

    @property
    def enmo_mean_mg(self) -> float:
        return self.enmo_sum_mg / self.samples if self.samples else float("nan")
