"""Window features of every 10 s window of a recording (.cwa/.bin) or a stillpoint MCAP log, streamed
through the engine's window-features operator (bounded memory: only the ~60k-row/week feature
table is kept, never the samples).

The MCAP path replays the log's lossless raw stream (``drivers.mcap_replay``), so the features are
those of the original recording.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

from stillpoint.drivers import open_recording
from stillpoint.drivers.errors import RecordingError

from ..features import WindowFeatures
from ..operators.windows import WindowFeaturesOperator


@dataclass
class StreamedFeatures:
    features: WindowFeatures
    rate_hz: float
    device: str
    device_key: Optional[str]
    segments: int


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
        for block in src:
            f = op.push(block)
            segs.add(int(block.segment))
            if len(f):
                parts.append(f)
            if len(parts) > 256:
                parts = [WindowFeatures.concat(parts)]
        f = op.flush()
        if len(f):
            parts.append(f)
        return StreamedFeatures(WindowFeatures.concat(parts), rate, src.info.device_type,
                                src.info.device_key, len(segs))
    finally:
        src.close()


def features_from_recording(path) -> WindowFeatures:
    return stream_features(path).features


def features_from_mcap(path) -> WindowFeatures:
    return stream_features(path).features
