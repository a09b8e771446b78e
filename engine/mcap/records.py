"""MCAP record encoders (pure functions: fields in, record bytes out).

The MCAP format is a sequence of records ``opcode u8, length u64, body`` (specs/mcap-python.md
§2; field order as in the MCAP specification). Only what stillpoint writes is here: Header,
Schema, Channel, Message (header part), Chunk, MessageIndex, ChunkIndex, Metadata,
MetadataIndex, Statistics, DataEnd (with the data-section CRC), SummaryOffset, Footer. Strings are ``u32 length +
UTF-8``, maps ``u32 byte length + entries``, all integers little-endian.

No dependency but the standard library (and ISA-L's CRC-32 when installed), so the writer
process stays small.
"""

from __future__ import annotations

import struct

try:  # ISA-L's CRC-32: zlib's polynomial and values, faster (docs/performance.md#code-figures)
    from isal.isal_zlib import crc32  # noqa: F401 - the module's crc32 (imported from here)
except ImportError:  # pragma: no cover - the standard library's
    from zlib import crc32  # noqa: F401

MAGIC = b"\x89MCAP0\r\n"

OP_HEADER, OP_FOOTER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK = 0x01, 0x02, 0x03, 0x04, 0x05, 0x06
OP_MESSAGE_INDEX, OP_CHUNK_INDEX, OP_STATISTICS, OP_METADATA, OP_METADATA_INDEX = 0x07, 0x08, 0x0B, 0x0C, 0x0D
OP_SUMMARY_OFFSET, OP_DATA_END = 0x0E, 0x0F

_REC = struct.Struct("<BQ")
# a Message record's framing: opcode, length, channel id, sequence, log time, publish time
MESSAGE_HEADER = struct.Struct("<BQHIQQ")
MESSAGE_OVERHEAD = MESSAGE_HEADER.size - _REC.size  # body bytes before the payload (22)


def record(op: int, body: bytes) -> bytes:
    return _REC.pack(op, len(body)) + body


def _str(s: str) -> bytes:
    b = s.encode("utf-8")
    return struct.pack("<I", len(b)) + b


def _map_str(d: dict) -> bytes:
    body = b"".join(_str(str(k)) + _str(str(v)) for k, v in d.items())
    return struct.pack("<I", len(body)) + body


def header(profile: str, library: str) -> bytes:
    return record(OP_HEADER, _str(profile) + _str(library))


def schema(sid: int, name: str, encoding: str, data: bytes) -> bytes:
    return record(OP_SCHEMA, struct.pack("<H", sid) + _str(name) + _str(encoding)
                  + struct.pack("<I", len(data)) + data)


def channel(cid: int, schema_id: int, topic: str, message_encoding: str,
            metadata: dict | None = None) -> bytes:
    return record(OP_CHANNEL, struct.pack("<HH", cid, schema_id) + _str(topic)
                  + _str(message_encoding) + _map_str(metadata or {}))


def message(cid: int, sequence: int, log_time: int, publish_time: int, data: bytes) -> bytes:
    return MESSAGE_HEADER.pack(OP_MESSAGE, MESSAGE_OVERHEAD + len(data), cid, sequence,
                               log_time, publish_time) + data


_CHUNK_HEAD = struct.Struct("<QQQI")


def chunk_head(start: int, end: int, uncompressed_size: int, crc: int, compression: str,
               compressed_size: int) -> bytes:
    """A Chunk record up to its records (write the compressed records right after it)."""
    c = compression.encode()
    return _CHUNK_HEAD.pack(OP_CHUNK, 8 + 8 + 8 + 4 + 4 + len(c) + 8 + compressed_size, start, end,
                            uncompressed_size, crc, len(c)) + c + struct.pack("<Q", compressed_size)


_CHUNK_HEAD = struct.Struct("<BQQQQII")


MESSAGE_INDEX_ENTRY = 16  # log_time u64, offset u64


def message_index(cid: int, entries: bytes) -> bytes:
    """A Message Index record: ``entries`` are packed (log_time u64, offset u64) pairs, the
    offset counted from the start of the chunk's uncompressed records."""
    return _REC.pack(OP_MESSAGE_INDEX, 6 + len(entries)) + struct.pack("<HI", cid, len(entries)) \
        + entries


def chunk_index(start: int, end: int, offset: int, length: int, index_offsets: dict,
                index_length: int, compression: str, compressed_size: int,
                uncompressed_size: int) -> bytes:
    """A Chunk Index record; ``index_offsets``: channel id -> file offset of that channel's
    Message Index record after the chunk; ``index_length``: bytes of all of them."""
    offs = b"".join(struct.pack("<HQ", c, o) for c, o in index_offsets.items())
    return record(OP_CHUNK_INDEX, struct.pack("<QQQQI", start, end, offset, length, len(offs))
                  + offs + struct.pack("<Q", index_length) + _str(compression)
                  + struct.pack("<QQ", compressed_size, uncompressed_size))


def metadata(name: str, values: dict) -> bytes:
    return record(OP_METADATA, _str(name) + _map_str(values))


def metadata_index(offset: int, length: int, name: str) -> bytes:
    return record(OP_METADATA_INDEX, struct.pack("<QQ", offset, length) + _str(name))


def statistics(message_count: int, schema_count: int, channel_count: int, metadata_count: int,
               chunk_count: int, start: int, end: int, channel_counts: dict) -> bytes:
    counts = b"".join(struct.pack("<HQ", c, n) for c, n in sorted(channel_counts.items()))
    return record(OP_STATISTICS, struct.pack("<QHIIIIQQ", message_count, schema_count,
                                             channel_count, 0, metadata_count, chunk_count,
                                             start, end)
                  + struct.pack("<I", len(counts)) + counts)


def data_end(crc: int = 0) -> bytes:
    return record(OP_DATA_END, struct.pack("<I", crc))


def summary_offset(group_opcode: int, start: int, length: int) -> bytes:
    return record(OP_SUMMARY_OFFSET, struct.pack("<BQQ", group_opcode, start, length))


def footer_body_prefix(summary_start: int, summary_offset_start: int) -> bytes:
    """Footer bytes covered by the summary CRC (opcode, length and the two offsets)."""
    return _REC.pack(OP_FOOTER, 20) + struct.pack("<QQ", summary_start, summary_offset_start)
