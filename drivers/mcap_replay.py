"""``McapRawSource``: the raw channel of a stillpoint MCAP log as a Source.

Replays ``/raw/accel`` (and ``/raw/gyro`` for AX6) message by message and returns exactly the
Blocks that were logged (same samples, times, counts, scales, per-unit arrays, segments). The
``DeviceInfo`` comes from the ``device`` metadata record and ``settings`` (the original run's
settings) is exposed so replay can compare or reuse them. Reader QC events logged on ``/qc``
(``source == "reader"``) are restored into ``qc``. Reads linearly (file order) with
engine/mcap/stream.py, one chunk at a time, guided by the message indexes, so memory stays flat
however long the log; a recovered file replays too. Consecutive raw messages of one segment are
joined into larger Blocks (fewer, larger blocks make replay about as fast as processing the
recording) -- but never two messages of the same data-time cell, so the sink cuts the joined
Blocks into exactly the logged raw messages again.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Iterator, Optional

import numpy as np

from stillpoint.engine.blocks import (Block, DeviceInfo, PER_SAMPLE_BUTTON, PER_SAMPLE_LIGHT_RAW,
                                      QCEvent, QCReport)
from stillpoint.engine.mcap.schemas import ACCEL_BATCH_RAW, GYRO_BATCH_RAW, times_from_deltas
from stillpoint.engine.mcap.stream import McapFormatError, iter_topic_messages, read_metadata

from .errors import CorruptRecordingError, RecordingError, UnsupportedFormatError

TOPIC_RAW = "/raw/accel"
TOPIC_GYRO = "/raw/gyro"
TOPIC_QC = "/qc"
JOIN_FRACTION = 0.5  # a joined Block holds at most this fraction of the pipeline's block bound


def block_from_message(raw: dict, gyro: Optional[dict] = None) -> Block:
    t = times_from_deltas(raw["t0_ns"], raw["dt_ns"])
    accel = np.stack([raw["x"], raw["y"], raw["z"]], axis=1).astype(np.int16)
    per = {}
    if len(raw["light_raw"]):
        per[PER_SAMPLE_LIGHT_RAW] = raw["light_raw"].copy()
    if len(raw["button"]):
        per[PER_SAMPLE_BUTTON] = raw["button"].copy()
    return Block(
        time_ns=t, accel=accel,
        accel_counts_per_g=raw["counts_per_g"].astype(np.float64),
        accel_zero=raw["zero_counts"].astype(np.float64),
        gyro=(None if gyro is None else np.stack([gyro["x"], gyro["y"], gyro["z"]], axis=1).astype(np.int16)),
        gyro_dps_per_count=(None if gyro is None else float(gyro["dps_per_count"])),
        unit_index=raw["unit_index"].astype(np.int64), unit_sequence=raw["unit_sequence"].astype(np.int64),
        unit_start=raw["unit_start"].astype(np.int64), temperature_c=raw["temperature_c"].astype(np.float64),
        temperature_raw=raw["temperature_raw"].astype(np.int32), light=raw["light"].astype(np.int32),
        battery_v=raw["battery_v"].astype(np.float64), events=raw["events"].astype(np.uint8),
        per_sample=per, segment=int(raw["segment"]), first_sample=int(raw["first_sample"]))


def _device_info(meta: dict, path: Path) -> DeviceInfo:
    d = json.loads(meta["json"])
    known = DeviceInfo.__dataclass_fields__
    d = {k: v for k, v in d.items() if k in known}
    d["channels"] = tuple(d.get("channels", ()))
    d["path"] = str(path)
    return DeviceInfo(**d)


def _cell(b: Block, cell_ns: int) -> int:
    return int(b.time_ns[b.unit_start[0] if b.m else 0]) // cell_ns


def _joinable(a: Block, b: Block, cell_ns: int) -> bool:
    """``b`` continues ``a`` in another cell: same segment, scales and per-sample channels,
    next sample (two messages of one cell were cut apart by the logged run: keep them apart)."""
    return (a.segment == b.segment and b.first_sample == a.first_sample + a.n
            and _cell(a, cell_ns) != _cell(b, cell_ns)
            and (a.gyro is None) == (b.gyro is None) and set(a.per_sample) == set(b.per_sample)
            and a.gyro_dps_per_count == b.gyro_dps_per_count
            and np.array_equal(a.accel_counts_per_g, b.accel_counts_per_g)
            and np.array_equal(a.accel_zero, b.accel_zero))


class McapRawSource:
    """Source over a stillpoint MCAP's raw topics (single pass; open again for another)."""

    def __init__(self, path, **_options):
        self.path = Path(path)
        if not self.path.is_file():
            raise RecordingError(self.path, "no such file")
        self._f = open(self.path, "rb")
        self.settings: Optional[dict] = None
        self.metadata: dict[str, dict] = {}
        try:
            self.metadata = read_metadata(self._f)
        except (ValueError, OSError) as e:
            self._f.close()
            raise CorruptRecordingError(
                self.path, f"cannot read the MCAP index ({type(e).__name__}); if the run was "
                           f"interrupted, run `stillpoint recover` on it first") from None
        if "device" not in self.metadata:
            self._f.close()
            raise UnsupportedFormatError(self.path, "MCAP has no 'device' metadata record: not a "
                                                    "stillpoint log")
        self.info = _device_info(self.metadata["device"], self.path)
        if "settings" in self.metadata:
            self.settings = json.loads(self.metadata["settings"]["json"])
        self.qc = QCReport(unit="sector" if self.info.device_type.startswith("AX") else "page")

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self) -> None:
        self._f.close()

    def __iter__(self) -> Iterator[Block]:
        try:
            yield from self._blocks()
        except McapFormatError as e:
            raise CorruptRecordingError(self.path, f"damaged MCAP: {e}") from None

    def _blocks(self) -> Iterator[Block]:
        pending_raw: list[dict] = []
        pending_gyro: list[dict] = []
        has_gyro = self.info.gyro_range_dps is not None
        group: list[Block] = []
        st = self.settings or {}
        # the logged run's raw-message cells (engine/mcap/sink.py) and pipeline block bound
        cell_ns = int(float(st.get("flush_every_s") or 60.0) * 1e9)
        rate = float(self.info.sample_rate_nominal or 0.0)
        max_join = int(JOIN_FRACTION * float(st.get("max_block_s") or 0.0) * rate)
        n_group = 0

        def joined():
            nonlocal n_group
            b = group[0] if len(group) == 1 else Block.concat(group)
            group.clear()
            n_group = 0
            return b

        for topic, _log_time, data in iter_topic_messages(self._f, [TOPIC_RAW, TOPIC_GYRO, TOPIC_QC]):
            if topic == TOPIC_RAW:
                pending_raw.append(ACCEL_BATCH_RAW.decode(data))
            elif topic == TOPIC_GYRO:
                pending_gyro.append(GYRO_BATCH_RAW.decode(data))
            else:
                ev = json.loads(bytes(data))
                if ev.get("source") == "reader":
                    self.qc.add(QCEvent(int(ev.get("index", -1)), ev.get("reason", ""),
                                        ev.get("detail", ""), ev.get("time_ns"), int(ev.get("samples", 0))))
            while pending_raw and (not has_gyro or pending_gyro):
                raw = pending_raw.pop(0)
                gyro = pending_gyro.pop(0) if has_gyro else None
                b = block_from_message(raw, gyro)
                self.qc.total += b.m
                self.qc.valid += b.m
                if group and (not _joinable(group[-1], b, cell_ns) or n_group + b.n > max_join):
                    yield joined()
                group.append(b)
                n_group += b.n
        if group:
            yield joined()
        # a gyro-less tail (should not happen in a complete log): yield accel only
        for raw in pending_raw:
            yield block_from_message(raw, None)
        qc_meta = self.metadata.get("summary")
        if qc_meta and "qc" in qc_meta:
            q = json.loads(qc_meta["qc"])
            self.qc.total, self.qc.valid = q.get("total", self.qc.total), q.get("valid", self.qc.valid)
            self.qc.skipped, self.qc.segments = q.get("skipped", 0), q.get("segments", 0)
