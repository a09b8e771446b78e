"""The window-feature stage of a run: blocks -> 10 s window features -> nonmovement windows.

A batch run's first pass keeps the nonmovement windows and every window's start for the fit; an
online run hands each batch of window features to its calibrator instead (``on_features``).
"""

from __future__ import annotations

from typing import Callable, Optional

import numpy as np

from ..calibration.trust import CountStep
from ..core.blocks import Block
from ..features import WindowFeatures
from ..operators.nonmovement import NonmovementOperator
from ..operators.windows import WindowFeaturesOperator
from ..settings import RunSettings


class FeatureStage:
    """Block -> window features -> nonmovement windows (and, online, the calibrator)."""

    def __init__(self, s: RunSettings, rate_hz: float,
                 on_features: Optional[Callable[[WindowFeatures], None]] = None):
        self.windows = WindowFeaturesOperator(rate_hz, s.window_s, s.min_fill)
        # batch: the fit reads the nonmovement windows and every window's start time (8 bytes a
        # window), not the whole window table (11 values a window)
        self.keep = on_features is None
        self.nonmovement = NonmovementOperator(s.sd_threshold_g, s.max_abs_mean_g, keep=self.keep)
        self.on_features = on_features
        self._starts: list[np.ndarray] = []
        self.last_block_ns: Optional[int] = None
        self.count_step = CountStep()  # quantisation step of the counts (calibration)

    @property
    def all_starts(self) -> np.ndarray:
        """Start times of every window seen (batch), in stream order."""
        if len(self._starts) != 1:
            self._starts = [np.concatenate(self._starts) if self._starts else np.zeros(0, np.int64)]
        return self._starts[0]

    def _take(self, f: WindowFeatures) -> None:
        if self.keep and len(f):
            self._starts.append(np.array(f.start_ns, np.int64))
        self.nonmovement.push(f)
        if self.on_features is not None:
            self.on_features(f)

    def push(self, block: Block) -> None:
        """Take one block's samples."""
        self.last_block_ns = int(block.time_at(0))
        self.count_step.push(block)
        self._take(self.windows.push(block))

    def flush(self) -> None:
        """Close the last window at the end of the stream."""
        self._take(self.windows.flush())
