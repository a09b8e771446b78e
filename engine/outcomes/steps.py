"""Steps from the corrected stream: each segment of corrected samples is resampled to 15 Hz
(linear interpolation between the two samples around each grid time, the grid starting at the
segment's first sample), its vector magnitude is pushed to one ``VerisenseCounter`` per parameter
set, and the step indices come back as UTC times. A new segment (a gap in the recording) ends the
counters' input, as the end of a file does.

The 15 Hz rate and the linear interpolation follow GGIR's external-function interface, which
resamples to ``expected_sample_rate = 15`` before calling the Verisense function (GGIR
``docs/articles/StepCadenceAnalysis.md`` line 38). Memory: the last sample and the counters' few
peaks, whatever the recording's length.
"""

from __future__ import annotations

import numpy as np

from .verisense import FS_HZ, HORIZON_S, PARAMETER_SETS, VerisenseCounter

ALGORITHM = "verisense"
GRID_NS = 10**9 / FS_HZ


def step_column(set_name: str) -> str:
    """Column name of a parameter set's step counts: the algorithm and the set."""
    return f"steps_{ALGORITHM}_{set_name}"


class Resampler15:
    """Corrected samples of one segment in, the 15 Hz grid's (x, y, z) out."""

    def __init__(self, t0_ns: int):
        self.t0 = int(t0_ns)
        self.g = 0  # next grid index
        self._t = np.zeros(0, np.int64)
        self._xyz = np.zeros((0, 3))

    def push(self, time_ns: np.ndarray, xyz: np.ndarray) -> np.ndarray:
        t = np.concatenate([self._t, np.asarray(time_ns, np.int64)])
        x = np.concatenate([self._xyz, np.asarray(xyz, np.float64)])
        self._t, self._xyz = t[-1:], x[-1:]
        if t.shape[0] == 0:
            return np.zeros((0, 3))
        g_end = int(np.floor((int(t[-1]) - self.t0) / GRID_NS)) + 1
        if g_end <= self.g:
            return np.zeros((0, 3))
        tg = np.arange(self.g, g_end, dtype=np.float64) * (1.0 / FS_HZ)
        ts = (t - self.t0).astype(np.float64) * 1e-9
        self.g = g_end
        return np.stack([np.interp(tg, ts, x[:, i]) for i in range(3)], axis=1)


class StepOperator:
    """Push corrected batches; ``take()`` gives {set: step times (int64 ns)} decided since the
    last call; ``final_before_ns``: no step earlier than this can still come."""

    def __init__(self, sets=tuple(PARAMETER_SETS), horizon_s: float = HORIZON_S):
        self.sets = tuple(sets)
        self.horizon_s = horizon_s
        self._segment = None
        self._rs = None
        self._counters = {}
        self._out = {s: [] for s in self.sets}
        self.samples_15hz = 0

    def _times(self, idx: np.ndarray) -> np.ndarray:
        return self._rs.t0 + np.round(idx.astype(np.float64) * GRID_NS).astype(np.int64)

    def _collect(self) -> None:
        for s, c in self._counters.items():
            idx = c.take()
            if idx.shape[0]:
                self._out[s].append(self._times(idx))

    def _end_segment(self) -> None:
        if self._rs is None:
            return
        for c in self._counters.values():
            c.flush()
        self._collect()
        self._rs = None
        self._counters = {}

    def push(self, batch) -> None:
        if batch.time_ns.shape[0] == 0:
            return
        if batch.segment != self._segment:
            self._end_segment()
            self._segment = batch.segment
            self._rs = Resampler15(int(batch.time_ns[0]))
            self._counters = {s: VerisenseCounter(PARAMETER_SETS[s], self.horizon_s)
                              for s in self.sets}
        xyz = self._rs.push(batch.time_ns, batch.accel)
        if xyz.shape[0]:
            self.samples_15hz += xyz.shape[0]
            # summed in the reference's order (x^2 + y^2 + z^2), so the values are the same bits
            mag = np.sqrt(xyz[:, 0] * xyz[:, 0] + xyz[:, 1] * xyz[:, 1] + xyz[:, 2] * xyz[:, 2])
            for c in self._counters.values():
                c.push(mag)
        self._collect()

    def flush(self) -> None:
        self._end_segment()

    def take(self) -> dict:
        out = {}
        for s in self.sets:
            parts = self._out[s]
            out[s] = np.concatenate(parts) if parts else np.zeros(0, np.int64)
            self._out[s] = []
        return out

    @property
    def final_before_ns(self) -> int | None:
        """None when nothing is pending (every step so far is out)."""
        if self._rs is None:
            return None
        idx = min(c.final_before for c in self._counters.values())
        return int(self._times(np.array([idx]))[0])
