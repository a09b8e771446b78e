"""The streaming MCAP reader never lets a damaged length field decide an allocation."""

import struct

import pytest

from stillpoint.engine.mcap import records as rec
from stillpoint.engine.mcap.stream import McapFormatError, iter_topic_messages


def _file(tmp_path, body: bytes):
    p = tmp_path / "damaged.mcap"
    p.write_bytes(rec.MAGIC + body)
    return p


def test_record_length_past_the_end_is_refused_before_reading(tmp_path):
    p = _file(tmp_path, struct.pack("<BQ", rec.OP_CHUNK, 1 << 62) + b"\0" * 64)
    with open(p, "rb") as f, pytest.raises(McapFormatError, match="length field"):
        list(iter_topic_messages(f, None))


def test_chunk_declaring_an_absurd_uncompressed_size_is_refused(tmp_path):
    comp = b"zstd"
    chunk = (struct.pack("<QQQI", 0, 0, 1 << 50, 0) + struct.pack("<I", len(comp)) + comp
             + struct.pack("<Q", 8) + b"\0" * 8)
    p = _file(tmp_path, struct.pack("<BQ", rec.OP_CHUNK, len(chunk)) + chunk)
    with open(p, "rb") as f, pytest.raises(McapFormatError, match="not a real chunk"):
        list(iter_topic_messages(f, None))


def test_message_index_pointing_past_its_chunk_is_a_typed_error(tmp_path):
    """A fuzzed log whose message index holds an offset beyond any chunk: every read path ends
    in one typed line, never an OverflowError."""
    from pathlib import Path

    from stillpoint.engine.mcap.reading import McapReadError
    from stillpoint.engine.mcap.stream import iter_messages
    path = Path(__file__).parents[2] / "data" / "fuzz" / "message_index_offset_huge.mcap"
    with pytest.raises(McapReadError):
        for _ in iter_messages(path):
            pass
