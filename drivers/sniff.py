"""What a file is, from its first bytes (not its name): ``sniff_format(path)``."""

from __future__ import annotations

from pathlib import Path

from .byteio import check_recording_path, open_bytes, read_exact, stream_damage
from stillpoint.engine.core.errors import CorruptRecordingError, TruncatedRecordingError, UnsupportedFormatError

MCAP_MAGIC = b"\x89MCAP0\r\n"
ZIP_MAGIC = b"PK\x03\x04"  # a zip: ActiGraph .gt3x (drivers/gt3x.py checks its members)
ZIP_EMPTY_MAGIC = b"PK\x05\x06"


def sniff_format(path) -> str:
    """Return "cwa", "geneactiv", "gt3x" or "mcap" from the first bytes of the (possibly gzipped) file."""
    p = Path(path)
    check_recording_path(p)
    try:
        with open_bytes(p) as f:
            head = read_exact(f, 512)
            damage = stream_damage(f)
    except (OSError, EOFError) as e:
        raise CorruptRecordingError(p, f"cannot read the file: {e}") from None
    if not head:
        if damage:
            raise CorruptRecordingError(p, f"nothing readable: {damage}")
        raise TruncatedRecordingError(p, "file is empty after decompression")
    if head.startswith(MCAP_MAGIC):
        return "mcap"
    if head[:2] == b"MD":
        return "cwa"
    if head[:4] in (ZIP_MAGIC, ZIP_EMPTY_MAGIC):
        return "gt3x"
    text = head.lstrip(b"\xef\xbb\xbf")
    if text.startswith(b"Device Identity"):
        return "geneactiv"
    if text.startswith(b"GENEA"):
        raise UnsupportedFormatError(
            p, "this is an original GENEA (2010) file, not GENEActiv .bin; it is not supported")
    raise UnsupportedFormatError(
        p, "not a recognised recording: expected an AX3/AX6 .cwa header ('MD'), a GENEActiv .bin "
           f"header ('Device Identity'), an ActiGraph .gt3x (a zip) or an MCAP file; first bytes are {head[:16]!r}")
