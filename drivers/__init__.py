"""Sources and writers: .cwa (AX3/AX6), .bin (GENEActiv), .gt3x (ActiGraph), MCAP replay, USB devices.

``open_recording(path)`` sniffs the content (not the file name) and returns a Source.
"""

from __future__ import annotations

from .errors import (CorruptRecordingError, RecordingError, StillpointError,
                     TruncatedRecordingError, UnsupportedFormatError)
from .sniff import MCAP_MAGIC, ZIP_EMPTY_MAGIC, ZIP_MAGIC, sniff_format  # noqa: F401

__all__ = [
    "open_recording", "sniff_format", "RecordingError", "StillpointError",
    "UnsupportedFormatError", "CorruptRecordingError", "TruncatedRecordingError",
]

def open_recording(path, **options):
    """Open a recording as a Source (options go to the format's reader)."""
    fmt = sniff_format(path)
    if fmt == "cwa":
        from .cwa import CwaReader
        return CwaReader(path, **options)
    if fmt == "geneactiv":
        from .geneactiv import GeneactivReader
        return GeneactivReader(path, **options)
    if fmt == "gt3x":
        from .gt3x import Gt3xReader
        return Gt3xReader(path, **options)
    from .mcap_replay import McapRawSource
    return McapRawSource(path, **options)
