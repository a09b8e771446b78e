"""``open_recording(path)``: any input the engine reads, as a Source: a device recording (.cwa,
GENEActiv .bin, .gt3x; ``stillpoint.drivers.open_recording``) or the raw stream of a stillpoint
MCAP log (``engine/mcap/replay.McapRawSource``), told apart by content, not file name."""

from __future__ import annotations

from stillpoint import drivers
from stillpoint.drivers.sniff import sniff_format


def open_recording(path, **options):
    """Open a recording or a stillpoint log as a Source (options go to the format's reader;
    a log's replay ignores them). A file that is neither is a typed error naming it."""
    return open_format(path, sniff_format(path), **options)


def open_format(path, fmt: str, **options):
    """``open_recording`` for a format already sniffed (``sniff_format(path)``)."""
    if fmt == "mcap":
        from .mcap.replay import McapRawSource
        return McapRawSource(path, **options)
    return drivers.open_format(path, fmt, **options)
