"""Window features of every 10 s window of a recording (.cwa/.bin) or a stillpoint MCAP log, streamed
through the engine's window-features operator (bounded memory: only the ~60k-row/week feature
table is kept, never the samples).

The MCAP path replays the log's lossless raw stream (``engine/mcap/replay.py``), so the features are
those of the original recording.

The quantisation step of the stored values is measured on the way (greatest common divisor of
the counts per axis over the first rows of every block; e.g. 4 counts = 15.6 mg for an AX3 in
packed +-8 g mode): window means of still windows whose noise does not dither that step are biased.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from stillpoint.engine.recordings import open_recording
from stillpoint.engine.core.errors import RecordingError

from ..features import WindowFeatures
from ..operators.windows import WindowFeaturesOperator


@dataclass
class StreamedFeatures:
    features: WindowFeatures
    rate_hz: float
    device: str
    device_key: Optional[str]
    segments: int
    count_step_g: Optional[np.ndarray] = None  # (3,) quantisation step seen in the counts, g


STEP_ROWS = 512  # rows of each block used for the step (the greatest common divisor of the counts)


def stream_features(path, progress=None) -> StreamedFeatures:
    """Every window's features (moving and still), in time order, with the device's rate."""
    src = open_recording(path)
    try:
        rate = float(src.info.sample_rate_nominal or 0.0)
        if rate <= 0:
            raise RecordingError(path, "the header gives no sample rate")
        op = WindowFeaturesOperator(rate)
        parts = []
        segs = set()
        step = np.zeros(3, np.int64)  # gcd of the counts so far (0: none seen)
        cpg = None
        for block in src:
            f = op.push(block)
            segs.add(int(block.segment))
            if np.any(step != 1) and block.accel.shape[0]:
                c = np.abs(np.asarray(block.accel[:STEP_ROWS], np.int64))
                step = np.gcd(step, np.gcd.reduce(c, axis=0))
                cpg = np.asarray(block.accel_counts_per_g, np.float64)
            if len(f):
                parts.append(f)
            if len(parts) > 256:
                parts = [WindowFeatures.concat(parts)]
        f = op.flush()
        if len(f):
            parts.append(f)
        step_g = step / cpg if cpg is not None and np.all(step > 0) else None
        return StreamedFeatures(WindowFeatures.concat(parts), rate, src.info.device_type,
                                src.info.device_key, len(segs), step_g)
    finally:
        src.close()

