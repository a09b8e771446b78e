"""Salvage an MCAP that was never finished (process killed, disk full, power loss).

Before ``finish()`` an MCAP has no summary, footer or trailing magic, and seeking readers refuse
it. The records of every *complete* chunk are intact, though: ``recover`` reads the file linearly
(``engine.mcap.reading.walk_records``), keeps every Schema, Channel, Message, Metadata and
Attachment record up to a torn tail, skipping (and reporting) any complete record that is
unreadable, e.g. a chunk whose CRC is wrong, and writes them into a new, finished
and indexed MCAP (ids re-mapped; records a finished file repeats in its summary are not
duplicated). The input is never modified (it may be the ``<name>.part`` file an interrupted run
left); the output goes through the one writer path (engine/mcap/log.py: ``<out>.part``,
renamed when complete). A file that is already finished is copied record by record all the same.
"""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass, field
from pathlib import Path

from mcap.exceptions import McapError
from mcap.records import (Attachment, Channel, DataEnd, Footer, Message, Metadata, Schema)

from stillpoint.engine.mcap.log import McapLog
from stillpoint.engine.mcap.reading import BadRecord, TornTail, walk_records

MAGIC = b"\x89MCAP0\r\n"


@dataclass
class RecoveryReport:
    input: str
    output: str
    finished: bool  # the input already had a footer
    messages: int = 0
    channels: int = 0
    metadata: int = 0
    attachments: int = 0
    last_log_time_ns: int = 0
    stopped_at: str = ""  # why reading stopped ("" when the file ended cleanly)
    bad_records: list = field(default_factory=list)  # unreadable records skipped (e.g. a bad chunk)
    per_topic: dict = field(default_factory=dict)

    def as_dict(self) -> dict:
        return dict(self.__dict__)


def is_finished(path) -> bool:
    with open(path, "rb") as f:
        f.seek(0, os.SEEK_END)
        if f.tell() < 2 * len(MAGIC):
            return False
        f.seek(-len(MAGIC), os.SEEK_END)
        return f.read() == MAGIC


def recover(path, out, *, compression: str = "zstd") -> RecoveryReport:
    path, out = Path(path), Path(out)
    from stillpoint.engine.mcap.replay import check_is_log
    check_is_log(path)  # a recording, or no MCAP at all: one line saying which
    rep = RecoveryReport(str(path), str(out), is_finished(path))
    schema_map: dict[int, str] = {}
    channel_map: dict[int, int] = {}
    topics: dict[int, str] = {}
    pending_channels: dict[int, Channel] = {}
    with open(path, "rb") as fin, McapLog(out, compression=compression) as w:
        try:
            for rec in walk_records(fin):
                if isinstance(rec, BadRecord):
                    rep.bad_records.append(rec.describe())
                    continue
                if isinstance(rec, TornTail):
                    rep.stopped_at = rec.describe()
                    break
                if isinstance(rec, Schema):
                    if rec.id not in schema_map:
                        w.define_schema(rec.name, rec.encoding, bytes(rec.data))
                        schema_map[rec.id] = rec.name
                elif isinstance(rec, Channel):
                    if rec.id not in channel_map:
                        pending_channels[rec.id] = rec
                        schema = schema_map.get(rec.schema_id) if rec.schema_id else None
                        channel_map[rec.id] = w.channel(rec.topic, rec.message_encoding, schema)
                        topics[rec.id] = rec.topic
                elif isinstance(rec, Message):
                    cid = channel_map.get(rec.channel_id)
                    if cid is None:
                        continue  # a message whose channel record was lost: cannot be placed
                    w.add(cid, rec.log_time, rec.data, sequence=rec.sequence,
                          publish_time=rec.publish_time)
                    rep.messages += 1
                    t = topics[rec.channel_id]
                    rep.per_topic[t] = rep.per_topic.get(t, 0) + 1
                    rep.last_log_time_ns = max(rep.last_log_time_ns, rec.log_time)
                elif isinstance(rec, Metadata):
                    w.write_metadata(rec.name, dict(rec.metadata))
                    rep.metadata += 1
                elif isinstance(rec, Attachment):
                    rep.attachments += 1  # stillpoint writes none; counted, not copied
                elif isinstance(rec, (DataEnd, Footer)):
                    break  # the summary repeats schemas/channels already copied
        except (McapError, struct.error, ValueError, EOFError) as e:
            rep.stopped_at = f"{type(e).__name__}: {e}" if str(e) else type(e).__name__
        rep.channels = len(channel_map)
    return rep
