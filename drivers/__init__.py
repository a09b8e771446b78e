"""Sources and writers: .cwa (AX3/AX6), .bin (GENEActiv), .gt3x (ActiGraph), USB devices.

``open_recording(path)`` sniffs the content (not the file name) and returns a device recording's
Source. A stillpoint MCAP log's raw stream is read by the engine (``engine/mcap/replay.py``);
``stillpoint.engine.recordings.open_recording`` opens either.
"""

from __future__ import annotations

from stillpoint.engine.core.errors import (CorruptRecordingError, RecordingError, StillpointError,
                     TruncatedRecordingError, UnsupportedFormatError)
from .sniff import MCAP_MAGIC, ZIP_EMPTY_MAGIC, ZIP_MAGIC, sniff_format  # noqa: F401

__all__ = [
    "open_recording", "open_format", "read_header", "sniff_format", "RecordingError", "StillpointError",
    "UnsupportedFormatError", "CorruptRecordingError", "TruncatedRecordingError",
]


def open_recording(path, **options):
    """Open a device recording (.cwa, GENEActiv .bin, .gt3x; plain or gzipped) as a Source
    (options go to the format's reader). An MCAP file is refused with a pointer to
    ``stillpoint.engine.recordings.open_recording``, which also replays a stillpoint log."""
    return open_format(path, sniff_format(path), **options)


def open_format(path, fmt: str, **options):
    """``open_recording`` for a format already sniffed (``sniff_format(path)``): the format's
    reader over ``path``, without reading the file's first bytes again."""
    if fmt == "cwa":
        from .cwa import CwaReader
        return CwaReader(path, **options)
    if fmt == "geneactiv":
        from .geneactiv import GeneactivReader
        return GeneactivReader(path, **options)
    if fmt == "gt3x":
        from .gt3x import Gt3xReader
        return Gt3xReader(path, **options)
    raise UnsupportedFormatError(
        path, "is an MCAP file, not a device recording: a stillpoint log's raw stream is opened by "
              "stillpoint.engine.recordings.open_recording")


def read_header(path, fmt: str, **options):
    """The header of a device recording of a format already sniffed (``"cwa"``, ``"geneactiv"``,
    ``"gt3x"``) as its reader gives it (``DeviceInfo``), without decoding the samples (options go
    to the format's ``read_header``)."""
    if fmt == "cwa":
        from .cwa import read_header as header
    elif fmt == "geneactiv":
        from .geneactiv import read_header as header
    elif fmt == "gt3x":
        from .gt3x import read_header as header
    else:
        raise UnsupportedFormatError(path, f"is not a device recording ({fmt}): it has no header")
    return header(path, **options)
