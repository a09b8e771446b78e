"""Streaming reads of an MCAP log in flat memory: messages of chosen topics in file order, and
the metadata records.

``iter_topic_messages`` walks the data section record by record, one chunk in memory at a
time: it reads each Chunk, then the Message Index records that follow it and, for the wanted
channels, decompresses the chunk (CRC32 checked) and slices exactly the indexed messages (a
chunk with no wanted message is not decompressed). Chunks without message indexes are walked
record by record. Nothing proportional to the file's length is kept (the ``mcap`` package's
seeking reader holds every Chunk Index of the summary as Python objects: ~80 MB for 14 days of
10 s chunks). ``read_metadata`` seeks to the summary's Metadata Index records and reads only
the Metadata records they point at.

Errors are ``McapFormatError`` (a ``ValueError``) naming what was wrong and where.
"""

from __future__ import annotations

import os
import struct
import threading
from typing import BinaryIO, Iterable, Iterator, NamedTuple, Optional

from . import records as rec

_REC = struct.Struct("<BQ")
_MSG = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time
_CHUNK_HEAD = struct.Struct("<QQQI")  # start, end, uncompressed size, uncompressed crc


class McapFormatError(ValueError):
    pass


_DECOMPRESSORS = threading.local()  # one per thread: a zstd decompressor is not thread-safe


def _decompressor(name: str):
    cache = _DECOMPRESSORS.__dict__
    d = cache.get(name)
    if d is None:
        d = cache[name] = _make_decompressor(name)
    return d


def _make_decompressor(name: str):
    if name == "":
        return lambda b, n: b
    if name == "zstd":
        import zstandard
        d = zstandard.ZstdDecompressor()
        return lambda b, n: d.decompress(b, max_output_size=n)
    if name == "lz4":
        import lz4.frame
        return lambda b, n: lz4.frame.decompress(b)
    raise McapFormatError(f"unsupported chunk compression {name!r}")


def _str(buf, p: int) -> tuple[str, int]:
    n, = struct.unpack_from("<I", buf, p)
    return bytes(buf[p + 4:p + 4 + n]).decode("utf-8"), p + 4 + n


# The largest uncompressed chunk accepted for a given compressed size: any chunk up to
# MAX_CHUNK_FLOOR, beyond that at most MAX_EXPANSION times its compressed size. A declared size
# above both is damage, not data, and must not decide how much memory is allocated.
MAX_EXPANSION = 1024
MAX_CHUNK_FLOOR = 256 << 20


def _read_exact(f: BinaryIO, n: int, what: str) -> bytes:
    """Read ``n`` bytes; a length that runs past the end of the file is refused before any
    allocation (a damaged length field must not allocate gigabytes)."""
    try:
        left = os.fstat(f.fileno()).st_size - f.tell()
    except (OSError, AttributeError, ValueError):
        left = None
    if n < 0 or (left is not None and n > left):
        raise McapFormatError(f"file ends inside {what} (its length field says {n} bytes)")
    b = f.read(n)
    if len(b) != n:
        raise McapFormatError(f"file ends inside {what}")
    return b


class StreamedMessage(NamedTuple):
    log_time: int
    data: memoryview


def iter_messages(path, topics: Optional[Iterable[str]] = None, *,
                  start_ns: Optional[int] = None) -> Iterator[tuple]:
    """(topic, index within its topic, message with ``log_time`` and ``data``) in file order,
    chunk CRCs checked, in flat memory; every reader of a stillpoint MCAP goes through here (a
    damaged container is an ``McapReadError`` naming the file and where reading stopped).
    ``start_ns``: see ``iter_topic_messages`` (indexes then count from the first chunk read)."""
    from .reading import RECOVER_HINT, McapReadError, locate_damage
    counts: dict[str, int] = {}
    last: Optional[str] = None
    try:
        f = open(path, "rb")
    except OSError as e:
        from stillpoint.engine.core.errors import CorruptRecordingError
        raise CorruptRecordingError(path, f"cannot open: {e.strerror or e}") from None
    with f:
        try:
            for topic, log_time, data in iter_topic_messages(f, topics, start_ns=start_ns):
                i = counts.get(topic, 0)
                counts[topic] = i + 1
                last = topic
                yield topic, i, StreamedMessage(log_time, data)
        except (ValueError, struct.error, EOFError, OSError, OverflowError) as e:  # McapFormatError too
            after = (f"after message {counts[last] - 1} of {last}" if last
                     else "before the first message")
            where = locate_damage(path)
            raise McapReadError(path, f"unreadable MCAP data ({where or e}); {RECOVER_HINT}",
                                record=after) from None


def iter_topic_messages(f: BinaryIO, topics: Optional[Iterable[str]], *,
                        validate_crcs: bool = True,
                        start_ns: Optional[int] = None) -> Iterator[tuple[str, int, memoryview]]:
    """(topic, log_time, payload) of every message on ``topics`` (None: every topic), in file
    order. ``f``: a binary file positioned anywhere (it is rewound). Stops at Data End (or the
    end of file). ``start_ns``: a chunk whose messages all end before it is skipped unread (a
    seek); messages before it in the chunks that are read are still yielded."""
    want = None if topics is None else set(topics)
    f.seek(0)
    if f.read(8) != rec.MAGIC:
        raise McapFormatError("not an MCAP file (bad magic)")
    groups = _summary_groups(f)
    f.seek(8)
    channels: dict[int, str] = {}  # wanted channel id -> topic
    known: set[int] = set()  # every channel id whose Channel record was read
    pending = None  # (compressed records, compression, usize, crc) of the chunk just read
    pending_idx: list[tuple[int, bytes]] = []  # its Message Index records (channel, entries)
    summary_channels = groups.get(rec.OP_CHANNEL) if groups else None
    skipping = False  # inside the message indexes of a chunk a seek skipped

    def channel_record(buf, p):
        cid, _sid = struct.unpack_from("<HH", buf, p)
        known.add(cid)
        topic, _ = _str(buf, p + 4)
        if want is None or topic in want:
            channels[cid] = topic

    def walk(data: bytes):
        """Every record of a decompressed chunk (when no usable message index guides us)."""
        p, n = 0, len(data)
        mv = memoryview(data)
        while p < n:
            op, ln = _REC.unpack_from(data, p)
            body = p + 9
            if body + ln > n:
                raise McapFormatError("a record runs past the end of its chunk")
            if op == rec.OP_CHANNEL:
                channel_record(data, body)
            elif op == rec.OP_MESSAGE:
                cid, _seq, lt, _pt = _MSG.unpack_from(data, body)
                t = channels.get(cid)
                if t is not None:
                    yield t, lt, mv[body + 22:body + ln]
            p = body + ln

    if summary_channels is not None:  # a finished log: every channel known before any chunk
        cs = _group(f, summary_channels, "the summary channels")
        p = 0
        while p + 9 <= len(cs):
            op, ln = _REC.unpack_from(cs, p)
            if op == rec.OP_CHANNEL:
                channel_record(cs, p + 9)
            p += 9 + ln
        f.seek(8)

    def finish_chunk():
        nonlocal pending, pending_idx
        if pending is None:
            return
        (cdata, comp, usize, crc), idx = pending, pending_idx
        pending, pending_idx = None, []
        # with every channel known from the summary, the message indexes say which chunks hold
        # wanted messages and where; otherwise every chunk is read record by record
        guided = summary_channels is not None and bool(idx) and all(cid in known for cid, _e in idx)
        wanted = [(cid, e) for cid, e in idx if cid in channels]
        if guided and not wanted:
            return  # nothing of ours in it: not even decompressed
        try:
            data = _decompressor(comp)(cdata, usize)
        except McapFormatError:
            raise
        except Exception as e:  # zstd/lz4 errors are not ValueErrors
            raise McapFormatError(f"a chunk does not decompress ({type(e).__name__}: {e})") from None
        if len(data) != usize:
            raise McapFormatError("a chunk decompresses to the wrong size")
        if validate_crcs and crc and rec.crc32(data) != crc:
            raise McapFormatError("a chunk's CRC does not match its records")
        if not guided:  # unindexed, or it registers channels: read every record
            yield from walk(data)
            return
        offs = []
        for _cid, e in wanted:
            offs.extend(struct.unpack_from(f"<{len(e) // 8}Q", e)[1::2])
        offs.sort()
        mv = memoryview(data)
        for off in offs:
            if off + 9 > usize:
                raise McapFormatError("a message index points past the end of its chunk")
            op, ln = _REC.unpack_from(data, off)
            if op != rec.OP_MESSAGE or off + 9 + ln > usize:
                raise McapFormatError("a message index points at no message")
            mcid, _seq, lt, _pt = _MSG.unpack_from(data, off + 9)
            t = channels.get(mcid)
            if t is None:
                raise McapFormatError("a message index points at another channel's message")
            yield t, lt, mv[off + 9 + 22:off + 9 + ln]

    while True:
        head = f.read(9)
        if len(head) < 9:
            if head:
                raise McapFormatError("file ends inside a record header")
            break
        op, ln = _REC.unpack(head)
        if op == rec.OP_MESSAGE_INDEX:
            if skipping:
                f.seek(ln, 1)
                continue
            body = _read_exact(f, ln, "a message index")
            cid, n = struct.unpack_from("<HI", body, 0)
            pending_idx.append((cid, body[6:6 + n]))
            continue
        yield from finish_chunk()
        skipping = False
        if op == rec.OP_CHUNK and start_ns is not None and ln >= 16:
            _cstart, cend = struct.unpack("<QQ", _read_exact(f, 16, "a chunk"))
            f.seek(-16, 1)
            if cend < start_ns:  # a seek: the whole chunk precedes it, read neither it nor its indexes
                f.seek(ln, 1)
                skipping = True
                continue
        if op == rec.OP_CHUNK:
            body = _read_exact(f, ln, "a chunk")
            start, end, usize, crc = _CHUNK_HEAD.unpack_from(body, 0)
            comp, p = _str(body, 28)
            clen, = struct.unpack_from("<Q", body, p)
            if usize > max(MAX_EXPANSION * clen, MAX_CHUNK_FLOOR):
                raise McapFormatError(f"a chunk declares {usize} uncompressed bytes for {clen} "
                                      "compressed: not a real chunk")
            pending = (body[p + 8:p + 8 + clen], comp, usize, crc)
        elif op == rec.OP_CHANNEL:
            channel_record(_read_exact(f, ln, "a channel"), 0)
        elif op in (rec.OP_DATA_END, rec.OP_FOOTER):
            break
        else:
            f.seek(ln, 1)
    yield from finish_chunk()


def _summary_groups(f: BinaryIO) -> Optional[dict[int, tuple[int, int]]]:
    """{group opcode: (start, length)} from the Summary Offset records; None if the file has
    no footer (an unfinished log) or no summary offsets."""
    f.seek(0, 2)
    size = f.tell()
    if size < 8 + 29 + 8:
        return None
    f.seek(size - 8 - 29)
    foot = f.read(29 + 8)
    if foot[29:] != rec.MAGIC or foot[0] != rec.OP_FOOTER:
        return None
    summary_start, offsets_start = struct.unpack_from("<QQ", foot, 9)
    if not summary_start or not offsets_start or offsets_start > size - 8 - 29:
        return None
    f.seek(offsets_start)
    so = _read_exact(f, size - 8 - 29 - offsets_start, "the summary offsets")
    groups = {}
    p = 0
    while p + 9 <= len(so):
        op, ln = _REC.unpack_from(so, p)
        if op == rec.OP_SUMMARY_OFFSET and ln >= 17:
            gop, gstart, glen = struct.unpack_from("<BQQ", so, p + 9)
            if gstart + glen > size:
                raise McapFormatError("a summary offset points past the end of the file")
            groups[gop] = (gstart, glen)
        p += 9 + ln
    return groups


def _group(f: BinaryIO, where: tuple[int, int], what: str) -> bytes:
    f.seek(where[0])
    return _read_exact(f, where[1], what)


def read_metadata(f: BinaryIO) -> dict[str, dict[str, str]]:
    """{name: values} of every Metadata record, through the summary's Metadata Index records
    (a later record of the same name wins). Raises ``McapFormatError`` for a file without a
    footer (an unfinished log) or with a damaged summary."""
    groups = _summary_groups(f)
    if groups is None:
        raise McapFormatError("no footer or summary: the log was not finished")
    group = groups.get(rec.OP_METADATA_INDEX)
    out: dict[str, dict[str, str]] = {}
    if group is None:
        return out
    mi = _group(f, group, "the metadata indexes")
    p = 0
    while p < len(mi):
        op, ln = _REC.unpack_from(mi, p)
        if op == rec.OP_METADATA_INDEX:
            off, length = struct.unpack_from("<QQ", mi, p + 9)
            f.seek(off)
            r = _read_exact(f, length, "a metadata record")
            if r[0] != rec.OP_METADATA:
                raise McapFormatError("a metadata index points at no metadata record")
            name, q = _str(r, 9)
            n, = struct.unpack_from("<I", r, q)
            q += 4
            end = q + n
            values = {}
            while q < end:
                k, q = _str(r, q)
                v, q = _str(r, q)
                values[k] = v
            out[name] = values
        p += 9 + ln
    return out



class ChannelInfo(NamedTuple):
    """A channel of a finished log with its schema (``schema_name`` "" when it has none)."""
    topic: str
    message_encoding: str
    schema_name: str
    schema_encoding: str
    schema_data: bytes


def _record_starts(buf, opcode: int) -> Iterator[int]:
    """Offsets of the records with ``opcode`` in a run of records (a summary group)."""
    p = 0
    while p + 9 <= len(buf):
        op, ln = _REC.unpack_from(buf, p)
        if op == opcode:
            yield p
        p += 9 + ln


def read_channels(f: BinaryIO) -> list[ChannelInfo]:
    """Every channel of a finished log with its schema, in channel-id order, from the summary's
    Schema and Channel records only. Raises ``McapFormatError`` for a file without a footer."""
    groups = _summary_groups(f)
    if groups is None:
        raise McapFormatError("no footer or summary: the log was not finished")
    schemas: dict[int, tuple[str, str, bytes]] = {}
    if rec.OP_SCHEMA in groups:
        buf = _group(f, groups[rec.OP_SCHEMA], "the summary schemas")
        for p in _record_starts(buf, rec.OP_SCHEMA):
            sid, = struct.unpack_from("<H", buf, p + 9)
            name, q = _str(buf, p + 11)
            enc, q = _str(buf, q)
            n, = struct.unpack_from("<I", buf, q)
            schemas[sid] = (name, enc, bytes(buf[q + 4:q + 4 + n]))
    out: list[tuple[int, ChannelInfo]] = []
    if rec.OP_CHANNEL in groups:
        buf = _group(f, groups[rec.OP_CHANNEL], "the summary channels")
        for p in _record_starts(buf, rec.OP_CHANNEL):
            cid, sid = struct.unpack_from("<HH", buf, p + 9)
            topic, q = _str(buf, p + 13)
            enc, q = _str(buf, q)
            name, senc, data = schemas.get(sid, ("", "", b""))
            out.append((cid, ChannelInfo(topic, enc, name, senc, data)))
    return [c for _cid, c in sorted(out, key=lambda x: x[0])]


def read_time_range(f: BinaryIO) -> Optional[tuple[int, int]]:
    """(first, last) message log time of a finished log from its Statistics record (None: no
    statistics or no message)."""
    groups = _summary_groups(f)
    if not groups or rec.OP_STATISTICS not in groups:
        return None
    buf = _group(f, groups[rec.OP_STATISTICS], "the statistics")
    if len(buf) < 9 + 8 + 2 + 4 * 4 + 16:
        return None
    count, = struct.unpack_from("<Q", buf, 9)
    start, end = struct.unpack_from("<QQ", buf, 9 + 8 + 2 + 4 * 4)  # count, schemas, channels, attachments, metadata, chunks
    return (start, end) if count else None
