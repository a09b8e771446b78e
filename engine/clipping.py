"""Clipping: samples at the accelerometer's range limit, counted as the data stream by.

A clipped sample (any axis at +-range) carries no information about how far beyond the range the
acceleration went; long stretches of them (a device on a vibrating machine, a range set too
low) bias ENMO and the calibration. ``ClippingMonitor.observe(block)`` counts them per block
(vectorised); ``flagged`` is True once the clipped time passes ``FLAG_S`` (one minute), and
``as_dict()`` gives the samples, the seconds and the longest run, for the summaries.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

FLAG_S = 60.0  # clipped data time from which a recording is flagged
LIMIT_FRACTION = 0.995  # |a| >= 99.5 % of the range counts as at the limit (one count below)


class ClippingMonitor:
    def __init__(self, range_g: Optional[float], rate_hz: Optional[float]):
        self.range_g = float(range_g) if range_g else None
        self.rate_hz = float(rate_hz) if rate_hz else None
        self.samples = 0
        self.clipped = 0
        self.longest = 0  # longest run of consecutive clipped samples
        self._run = 0  # clipped samples at the end of the last block (a run may span blocks)

    def observe(self, block) -> None:
        n = block.n
        if not n or self.range_g is None or block.accel.shape[1] != 3:
            return
        self.samples += n
        if not self._may_clip(block):
            self._run = 0
            return
        a = block.accel_g(np.float32)
        clip = (np.abs(a) >= LIMIT_FRACTION * self.range_g).any(axis=1)
        k = int(clip.sum())
        if not k:
            self._run = 0
            return
        self.clipped += k
        # longest run: boundaries of runs of True
        d = np.diff(np.concatenate([[0], clip.view(np.int8), [0]]))
        starts, ends = np.flatnonzero(d == 1), np.flatnonzero(d == -1)
        lengths = ends - starts
        if starts[0] == 0:
            lengths[0] += self._run
        self.longest = max(self.longest, int(lengths.max()))
        self._run = int(lengths[-1]) if ends[-1] == n else 0

    def _may_clip(self, block) -> bool:
        """False when no sample of the block can reach the limit: the extreme counts (two
        passes over the int16 counts) are more than 0.1 % below it in g, far beyond any float32
        rounding of the exact test; otherwise the exact per-sample test decides."""
        acc = block.accel
        zero = getattr(block, "accel_zero", None)
        cpg = getattr(block, "accel_counts_per_g", None)
        if acc.dtype.kind not in "iu" or zero is None or cpg is None:
            return True
        lo, hi = float(acc.min()), float(acc.max())  # no copy of a column-major block
        zero = np.asarray(zero, np.float64)
        cpg = np.abs(np.asarray(cpg, np.float64))
        if not (np.all(np.isfinite(zero)) and np.all(cpg > 0)):
            return True
        worst = float(np.max(np.maximum(np.abs(hi - zero), np.abs(lo - zero)) / cpg))
        return worst >= LIMIT_FRACTION * self.range_g * (1.0 - 1e-3)

    @property
    def clipped_s(self) -> float:
        return self.clipped / self.rate_hz if self.rate_hz else 0.0

    @property
    def flagged(self) -> bool:
        return self.clipped_s >= FLAG_S

    def as_dict(self) -> dict:
        return {"samples": self.clipped, "fraction": self.clipped / self.samples if self.samples else 0.0,
                "seconds": round(self.clipped_s, 3),
                "longest_run_s": round(self.longest / self.rate_hz, 3) if self.rate_hz else None,
                "flagged": self.flagged, "range_g": self.range_g}

    def describe(self) -> str:
        return (f"{self.clipped_s / 3600:.2f} h of data ({100 * self.clipped / max(self.samples, 1):.1f} % "
                f"of samples) at the +-{self.range_g:g} g limit, longest run "
                f"{self.longest / self.rate_hz / 60:.1f} min")
