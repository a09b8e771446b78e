"""Follow an MCAP while it is written (the station's ``<stem>.unverified.mcap.part``): each
``poll()`` returns the messages of the records completed since the last one.

The writer only appends (engine/mcap/writer.py), so a record is read once its header and body
are all in the file; a record still being written is left for the next poll. Chunks are opened
into their Schema, Channel and Message records (CRC checked); one chunk is in memory at a time,
and nothing else grows with the file but the channel table.
"""

from __future__ import annotations

import os
import struct
from typing import NamedTuple, Optional

from stillpoint.engine.mcap import records as rec
from stillpoint.engine.mcap.stream import (_CHUNK_HEAD, _MSG, _REC, MAX_CHUNK_FLOOR, MAX_EXPANSION,
                                           ChannelInfo, McapFormatError, _decompressor, _str)

MAX_RECORDS_PER_POLL = 64  # chunks read per poll: a listener catching up never blocks long


class FollowedMessage(NamedTuple):
    channel: ChannelInfo
    log_time: int
    data: bytes


class McapFollower:
    """Reads a growing MCAP from where the last poll stopped. ``paths``: the file's name, or its
    names in the order it takes them (``x.mcap.part`` renamed ``x.mcap`` when finished: the
    same bytes, so reading goes on where it was); each poll reads the first that exists.
    ``skip_topics``: topics whose messages are never returned (their chunks are still read for
    the other topics). ``finishing``: set by the caller once the writer is done."""

    def __init__(self, paths, skip_topics=()):
        self.paths = [str(p) for p in (paths if isinstance(paths, (list, tuple)) else [paths])]
        self.path = self.paths[0]
        self.finishing = False
        self.skip = set(skip_topics)
        self.pos = 0
        self.schemas: dict[int, tuple[str, str, bytes]] = {}
        self.channels: dict[int, ChannelInfo] = {}
        self.error: Optional[str] = None

    def _schema(self, buf, p: int) -> None:
        sid, = struct.unpack_from("<H", buf, p)
        name, q = _str(buf, p + 2)
        enc, q = _str(buf, q)
        n, = struct.unpack_from("<I", buf, q)
        self.schemas[sid] = (name, enc, bytes(buf[q + 4:q + 4 + n]))

    def _channel(self, buf, p: int) -> None:
        cid, sid = struct.unpack_from("<HH", buf, p)
        topic, q = _str(buf, p + 4)
        enc, _ = _str(buf, q)
        name, senc, data = self.schemas.get(sid, ("", "", b""))
        self.channels[cid] = ChannelInfo(topic, enc, name, senc, data)

    def _message(self, buf, p: int, end: int, out: list) -> None:
        cid, _seq, lt, _pt = _MSG.unpack_from(buf, p)
        ch = self.channels.get(cid)
        if ch is not None and ch.topic not in self.skip:
            out.append(FollowedMessage(ch, lt, bytes(buf[p + 22:end])))

    def _records(self, buf, out: list) -> None:
        p, n = 0, len(buf)
        while p + 9 <= n:
            op, ln = _REC.unpack_from(buf, p)
            body = p + 9
            if body + ln > n:
                raise McapFormatError("a record runs past the end of its chunk")
            self._record(op, buf, body, body + ln, out)
            p = body + ln

    def _record(self, op: int, buf, p: int, end: int, out: list) -> None:
        if op == rec.OP_SCHEMA:
            self._schema(buf, p)
        elif op == rec.OP_CHANNEL:
            self._channel(buf, p)
        elif op == rec.OP_MESSAGE:
            self._message(buf, p, end, out)
        elif op == rec.OP_CHUNK:
            _start, _end, usize, crc = _CHUNK_HEAD.unpack_from(buf, p)
            comp, q = _str(buf, p + 28)
            clen, = struct.unpack_from("<Q", buf, q)
            if usize > max(MAX_EXPANSION * clen, MAX_CHUNK_FLOOR):
                raise McapFormatError("a chunk declares an impossible uncompressed size")
            data = _decompressor(comp)(bytes(buf[q + 8:q + 8 + clen]), usize)
            if crc and rec.crc32(data) != crc:
                raise McapFormatError("a chunk's CRC does not match its records")
            self._records(data, out)

    def poll(self) -> list[FollowedMessage]:
        """The messages completed since the last poll (empty: nothing new, the file is gone, or
        it cannot be read; ``error`` then says why and later polls return nothing)."""
        out: list[FollowedMessage] = []
        if self.error is not None:
            return out
        f = None
        for p in self.paths:
            try:
                f = open(p, "rb")
                self.path = p
                break
            except OSError:
                continue  # not there yet, or renamed when finished
        if f is None:
            return out
        with f:
            try:
                size = os.fstat(f.fileno()).st_size
                if size < self.pos:  # written again from the start (a rebuilt log)
                    self.pos = 0
                    self.schemas.clear()
                    self.channels.clear()
                if self.pos == 0:
                    if size < len(rec.MAGIC):
                        return out
                    if f.read(len(rec.MAGIC)) != rec.MAGIC:
                        raise McapFormatError("not an MCAP file (bad magic)")
                    self.pos = len(rec.MAGIC)
                for _ in range(MAX_RECORDS_PER_POLL):
                    if self.pos + 9 > size:
                        break
                    f.seek(self.pos)
                    op, ln = _REC.unpack(f.read(9))
                    if self.pos + 9 + ln > size:
                        break  # being written
                    if op in (rec.OP_DATA_END, rec.OP_FOOTER):
                        break
                    if op in (rec.OP_SCHEMA, rec.OP_CHANNEL, rec.OP_MESSAGE, rec.OP_CHUNK):
                        body = f.read(ln)
                        self._record(op, body, 0, ln, out)
                    self.pos += 9 + ln
            except Exception as e:  # noqa: BLE001 - zstd's errors too; a view never raises into the station
                self.error = f"{self.path}: {type(e).__name__}: {e}"
        return out
