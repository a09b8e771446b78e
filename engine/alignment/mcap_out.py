"""MCAP log of an alignment run: estimates, per-block lags and the aligned second stream.

==================== ============================ ==========================================
topic                encoding / schema            one message per
==================== ============================ ==========================================
/alignment/block_lag json + jsonschema            1 h block (lag, correlation, validity)
/alignment/estimate  json + jsonschema            estimate (online: after every valid block;
                                                  the final one has ``"final": true``)
/aligned/accel       cdr stillpoint/msg/AccelBatch up to ``MESSAGE_SAMPLES`` aligned samples
==================== ============================ ==========================================

The aligned stream uses the engine's AccelBatch layout (engine/mcap/schemas.py): times are on the
*reference* clock; points with no data (gaps, step windows) are left out rather than NaN-filled.
Metadata records: ``reference`` and ``other`` (device info) and ``alignment`` (final result, JSON
under ``json``). Written through the one MCAP writer path (engine/mcap/log.py: spec-complete
indexes, ``<name>.part`` renamed when finished).
"""

from __future__ import annotations

import json
import numpy as np

from stillpoint.engine.core.jsonsafe import jsonable
from stillpoint.engine.mcap.jsonschemas import ALIGNMENT_BLOCK_LAG, ALIGNMENT_ESTIMATE
from stillpoint.engine.mcap.log import McapLog
from stillpoint.engine.mcap.schemas import ACCEL_BATCH, max_step_ok, time_deltas

TOPIC_BLOCK_LAG = "/alignment/block_lag"
TOPIC_ESTIMATE = "/alignment/estimate"
TOPIC_ALIGNED = "/aligned/accel"
MESSAGE_SAMPLES = 1000
_SCHEMAS = {TOPIC_BLOCK_LAG: ALIGNMENT_BLOCK_LAG, TOPIC_ESTIMATE: ALIGNMENT_ESTIMATE}


class AlignmentMcap:
    """Writer for the topics above. Use as a context manager (an exception leaves the partial
    file, recoverable, instead of finishing it)."""

    def __init__(self, path, compression: str = "zstd"):
        self.path = str(path)
        self._log = McapLog(path, compression=compression)
        self.samples_written = 0
        self._closed = False

    @property
    def messages(self) -> int:
        return self._log.messages

    def write_json(self, topic: str, t_ns: int, obj: dict) -> None:
        self._log.write_json(topic, t_ns, jsonable(obj), schema=_SCHEMAS.get(topic))

    def write_metadata(self, name: str, obj: dict) -> None:
        self._log.write_metadata(name, {"json": json.dumps(jsonable(obj), sort_keys=True,
                                                           allow_nan=False)})

    def write_aligned(self, time_ns: np.ndarray, accel_g: np.ndarray, segment: int = 0) -> None:
        ok = np.isfinite(accel_g).all(axis=1)
        if not ok.all():
            time_ns, accel_g = time_ns[ok], accel_g[ok]
        for a in range(0, time_ns.size, MESSAGE_SAMPLES):
            t = time_ns[a:a + MESSAGE_SAMPLES]
            x = accel_g[a:a + MESSAGE_SAMPLES].astype(np.float32)
            if not max_step_ok(t):  # a gap longer than int32 ns: split there
                cut = int(np.argmax(np.diff(t) > 2**31 - 1)) + 1
                self.write_aligned(t[:cut], x[:cut].astype(np.float64), segment)
                self.write_aligned(t[cut:], x[cut:].astype(np.float64), segment)
                continue
            self._log.write(TOPIC_ALIGNED, "cdr", ACCEL_BATCH, int(t[0]), ACCEL_BATCH.encode({
                "stamp": int(t[0]), "t0_ns": int(t[0]), "segment": segment,
                "dt_ns": time_deltas(t), "x": x[:, 0], "y": x[:, 1], "z": x[:, 2]}))
            self.samples_written += t.size

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self._log.close()

    def abort(self):
        """Stop without finishing; return the partial file kept."""
        if not self._closed:
            self._closed = True
            return self._log.abort()
        return None

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            self.close()
        else:
            self.abort()


def read_topic_json(path, topic: str) -> list[dict]:
    """All JSON messages of a topic (for tests and tools); CRC-checked, typed errors."""
    from stillpoint.engine.mcap.reading import loads_json
    from stillpoint.engine.mcap.stream import iter_messages
    return [loads_json(path, topic, i, m.data) for _, i, m in iter_messages(path, [topic])]


def read_aligned(path) -> tuple[np.ndarray, np.ndarray]:
    """(time_ns, accel_g (n, 3)) of the aligned stream."""
    from stillpoint.engine.mcap.reading import decode
    from stillpoint.engine.mcap.stream import iter_messages
    from stillpoint.engine.mcap.schemas import times_from_deltas
    ts, xs = [], []
    for _, i, m in iter_messages(path, [TOPIC_ALIGNED]):
        d = decode(ACCEL_BATCH, path, TOPIC_ALIGNED, i, m.data)
        ts.append(times_from_deltas(d["t0_ns"], d["dt_ns"]))
        xs.append(np.column_stack([d["x"], d["y"], d["z"]]))
    if not ts:
        return np.zeros(0, np.int64), np.zeros((0, 3))
    return np.concatenate(ts), np.concatenate(xs).astype(np.float64)
