"""A run's input, opened once: ``open_input(path, settings, options) -> OpenedInput``.

The format is sniffed once and the zone of the times resolved once (``ClockZone``); the header
is read for the zone only where the zone cannot come from the opened reader (a given IANA zone
for a .cwa, .gt3x or GENEActiv file: the device's offset at the recording's start). Later passes
(a batch run's output pass, an online run's tables) open the same input again with
``RunInput.open`` without sniffing or resolving anything again.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Optional

from stillpoint.engine.recordings import open_format

from ..core.prefetch import Prefetched
from ..timezones import Zone, clock_record, fixed_zone, given_zone_offset, parse_zone, zone_of_log
from . import tuning


@dataclass(frozen=True)
class ClockZone:
    """The zone of a run's times, resolved once per run: the zone local times are read in
    (unknown for a .cwa given none) and the device clock's offset the reader applied to make the
    logged times (``DeviceInfo.timezone_offset_s``). The log's ``clock`` record, the summary's
    ``timezone`` and the tables' zone all come from it."""

    zone: Zone
    device_offset_s: int = 0

    def record(self) -> dict:
        """The MCAP ``clock`` metadata record (``engine.timezones.clock_record``)."""
        return clock_record(self.zone, self.device_offset_s)


@dataclass(frozen=True)
class RunInput:
    """The input of a run: its path, sniffed format and the reader options every pass uses."""

    path: Path
    format: str  # "cwa", "geneactiv", "gt3x" or "mcap" (drivers.sniff_format)
    options: dict = field(default_factory=dict)  # reader options (the caller's, and the zone's)
    prefetch: bool = False  # read and decode ahead on a thread (engine/core/prefetch.py)

    def open(self, *, features_only: bool = False, follow: bool = True, tables: bool = False):
        """Open the input for one pass (``reader_options``); ``follow=False`` drops the options
        that follow a growing file (a pass after the file is complete); ``tables``: the tables'
        own pass (an online run's, after it), which reads larger batches."""
        opts = self.options if follow else {k: v for k, v in self.options.items()
                                            if not k.startswith("follow")}
        src = open_format(self.path, self.format,
                          **reader_options(self.format, opts, features_only=features_only,
                                           tables=tables))
        return Prefetched(src) if self.prefetch else src


@dataclass
class OpenedInput:
    """``open_input``'s result: the input, its clock zone and the first pass's open source."""

    input: RunInput
    clock: ClockZone
    source: object


def reader_options(fmt: str, opts: dict, *, features_only: bool = False,
                   tables: bool = False) -> dict:
    """Reader options of a run's passes: a ``.cwa`` is decoded column-major (each axis
    contiguous, the layout the window features, the correction and the raw messages' x/y/z
    sequences read; the same values); a pass that only needs window features (``features_only``)
    also reads it without per-sample times (a sample clock cuts the windows at the same samples);
    the other passes read ``tuning.OUTPUT_BATCH_SECTORS`` at a time, the tables' own pass
    (``tables``) ``tuning.TABLES_PASS_SECTORS``. The logs and tables are the same, byte for
    byte, as with the per-sample, row-major read. Options the caller gives win."""
    if fmt != "cwa":
        return opts
    sectors = tuning.TABLES_PASS_SECTORS if tables else tuning.OUTPUT_BATCH_SECTORS
    extra = ({"column_major": True, "sample_times": False} if features_only
             else {"column_major": True, "batch_sectors": sectors})
    return dict(extra, **opts)


def _opened_zone(fmt: str, zone: Zone, src) -> Zone:
    """The zone of the times when the user gave none, from the opened reader: a GENEActiv
    header's, a .gt3x's stored one, a log's ``clock`` record; unknown for a .cwa."""
    if zone.known:
        return zone
    info = src.info
    if fmt == "geneactiv":
        return fixed_zone(info.timezone_offset_s)
    if fmt == "gt3x":
        stored = (info.header or {}).get("timezone_stored_s")
        return fixed_zone(stored) if stored is not None else zone
    if fmt == "mcap":
        return zone_of_log(getattr(src, "metadata", {}), info.timezone_offset_s)
    return zone


def open_input(path, settings, options: Optional[dict] = None, *, features_only: bool = False,
               prefetch: bool = False) -> OpenedInput:
    """Sniff ``path`` once, resolve the zone of its times once (``settings.timezone``,
    ``settings.timezone_override``; a ``ZoneError`` when a header's zone contradicts the given
    one) and open it for the first pass. Raises a ``StillpointError`` (exit 2) on an unreadable
    input."""
    from stillpoint.drivers import sniff_format
    path = Path(path)
    fmt = sniff_format(path)
    zone = parse_zone(settings.timezone)
    opts = dict(options or {})
    if zone.known and fmt != "mcap":
        tz = given_zone_offset(path, fmt, zone, settings.timezone_override)
        if tz is not None and "timezone" not in opts:
            opts["timezone"] = tz
    elif fmt == "cwa" and "timezone" not in opts:
        opts["timezone"] = 0  # a .cwa given no zone: the device clock, read as UTC
    run_input = RunInput(path, fmt, opts, prefetch)
    src = run_input.open(features_only=features_only)
    try:
        clock = ClockZone(_opened_zone(fmt, zone, src), int(src.info.timezone_offset_s))
    except BaseException:
        src.close()
        raise
    return OpenedInput(run_input, clock, src)


def with_zone(tables, clock: ClockZone):
    """The table settings with the run's zone when they name none (a copy: the caller's are not
    changed)."""
    if tables is None or tables.zone.known:
        return tables
    return replace(tables, zone=clock.zone)
