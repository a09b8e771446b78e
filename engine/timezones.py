"""Time zones: one mechanism for the device clock's zone and for local (calendar) time.

``parse_zone(spec)`` accepts an IANA name (``Europe/London``, through the standard ``zoneinfo``;
systems without a zone database need ``pip install tzdata``), a fixed offset (``+01:00``,
``-0530``, ``GMT +01:00``, ``UTC``) or ``None`` (zone unknown).

How recordings use it:

* **.cwa** stores no zone: its clock is the wall-clock time of the computer that configured it.
  With a zone, the clock's offset from UTC is the zone's offset in force at the recording's first
  sample (DST-aware: a device set up in British summer time runs at +01:00). The device does not
  change its clock at a DST change, so that one offset converts every sample to UTC. Without a
  zone the times are **device local time, zone unknown**: the readers then treat the clock as if
  it were UTC (offset 0) and every output says so instead of claiming UTC.
* **ActiGraph .gt3x** stores its zone in info.txt ``TimeZone`` (a fixed offset; NHANES-era files
  have none: zone unknown, as a .cwa) and keeps it unless a zone is given, as GENEActiv.
* **GENEActiv .bin** stores its zone (``Time Zone``, a fixed offset) and keeps it unless a zone is
  given, which then replaces it the same way.
* **local time** (epoch table, calendar days) is UTC + the zone's offset at each instant, so with
  an IANA zone local days have 23 or 25 hours at DST changes; with a fixed offset they never do.

``Zone.offsets_s(utc_ns)`` is vectorised: offsets are looked up once per hour of data (and the
change instant found to the second by bisection), never per sample.

**How outputs label times** (one rule, applied by ``inspect``, ``export``, the MCAP log, the
tables, the cohort summary and the report through the helpers below): a time is called UTC
(``...Z``, a ``*_utc`` column, ``timezone_offset_s``) only when the zone is known. Otherwise it
is the device clock's local time, written without ``Z`` or offset in columns named ``*_local``
(``time_local``, ``start_local``); a ``*_utc`` column is then empty and the zone is stated as
``UNKNOWN_LABEL``. ``utc_text``/``local_text`` format one instant; ``time_column`` names a
per-sample time column; ``clock_record``/``zone_of_log`` write and read the ``clock`` metadata
record of an MCAP log (a log written before that record existed has none: its times are read
as before, as UTC shifted by the device record's ``timezone_offset_s``).
"""

from __future__ import annotations

import datetime as _dt
import re
from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from stillpoint.engine.core.errors import StillpointError
from stillpoint.engine.core.times import iso_local, iso_text, iso_utc, offset_text, parse_offset

UNKNOWN_LABEL = "device local time, zone unknown"
_HOUR_NS = 3600 * 10**9


class ZoneError(StillpointError):
    """A time zone that cannot be used (unknown name, bad offset, no zone database)."""


def _fixed_offset(spec: str) -> Optional[int]:
    try:
        return parse_offset(spec)
    except ValueError:
        return None


@dataclass(frozen=True)
class Zone:
    """A participant's time zone: IANA (``name``), a fixed offset, or unknown."""

    name: str  # IANA name, "+01:00"-style text for a fixed offset, "" when unknown
    fixed_s: Optional[int] = None  # fixed offset in seconds (None for IANA or unknown)
    _cache: dict = field(default_factory=dict, compare=False, repr=False)

    @property
    def known(self) -> bool:
        return bool(self.name)

    @property
    def iana(self) -> bool:
        return self.known and self.fixed_s is None

    @property
    def label(self) -> str:
        return self.name if self.known else UNKNOWN_LABEL

    def _tz(self):
        import zoneinfo
        return zoneinfo.ZoneInfo(self.name)

    def offset_at_s(self, utc_s: int) -> int:
        """UTC offset (seconds) in force at one instant (UTC seconds)."""
        if not self.iana:
            return int(self.fixed_s or 0)
        d = _dt.datetime.fromtimestamp(int(utc_s), tz=_dt.timezone.utc).astimezone(self._tz())
        return int(d.utcoffset().total_seconds())

    def _hour(self, h: int) -> tuple:
        """(offset at the hour's start, change second or None, offset after the change)."""
        r = self._cache.get(h)
        if r is None:
            s0 = h * 3600
            a, b = self.offset_at_s(s0), self.offset_at_s(s0 + 3600)
            if a == b:
                r = (a, None, a)
            else:  # bisect to the second where the offset changes
                lo, hi = s0, s0 + 3600
                while hi - lo > 1:
                    mid = (lo + hi) // 2
                    if self.offset_at_s(mid) == a:
                        lo = mid
                    else:
                        hi = mid
                r = (a, hi, b)
            if len(self._cache) > 100_000:
                self._cache.clear()
            self._cache[h] = r
        return r

    def offsets_s(self, utc_ns) -> np.ndarray:
        """(n,) int64 UTC offsets in seconds at each instant (UTC ns)."""
        t = np.asarray(utc_ns, np.int64)
        if not self.iana:
            return np.full(t.shape, int(self.fixed_s or 0), np.int64)
        hours = np.floor_divide(t, _HOUR_NS)
        out = np.empty(t.shape, np.int64)
        for h in np.unique(hours):
            sel = hours == h
            a, change, b = self._hour(int(h))
            if change is None:
                out[sel] = a
            else:
                out[sel] = np.where(t[sel] >= change * 10**9, b, a)
        return out

    def local_ns(self, utc_ns) -> np.ndarray:
        t = np.asarray(utc_ns, np.int64)
        return t + self.offsets_s(t) * 10**9

    def utc_of_local_midnight_ns(self, day: int) -> int:
        """UTC ns of local midnight starting ``day`` (days since 1970-01-01, local calendar)."""
        if not self.iana:
            return (day * 86400 - int(self.fixed_s or 0)) * 10**9
        d = _dt.date(1970, 1, 1) + _dt.timedelta(days=int(day))
        local = _dt.datetime(d.year, d.month, d.day, tzinfo=self._tz())
        return int(local.timestamp()) * 10**9

    def device_offset_s(self, device_clock_s: float) -> int:
        """The offset of a device clock set to this zone's wall-clock time, judged at a device
        clock reading (e.g. the first sample): the zone's offset at that local time."""
        if not self.iana:
            return int(self.fixed_s or 0)
        guess = int(device_clock_s) - self.offset_at_s(int(device_clock_s))
        return self.offset_at_s(guess)

    def to_dict(self) -> dict:
        return {"zone": self.label, "known": self.known, "iana": self.iana,
                "fixed_offset_s": self.fixed_s}


# "GMT+1", "UTC-5": opposite signs in the IANA database (Etc/GMT+1 = UTC-01:00, POSIX TZ) and in
# everyday use, so refused (a GENEActiv header's "GMT +01:00", with a space and minutes, is read
# as the vendor writes it, by drivers/geneactiv_header.parse_timezone)
_AMBIGUOUS_GMT = re.compile(r"(?i)(GMT|UTC)[+-]\d{1,2}")


def parse_zone(spec) -> Zone:
    """IANA name, fixed offset text/seconds, or None (unknown)."""
    if spec is None or (isinstance(spec, str) and not spec.strip()):
        return Zone("")
    if isinstance(spec, Zone):
        return spec
    if isinstance(spec, (int, float, np.integer)) and not isinstance(spec, bool):
        return fixed_zone(int(spec))
    text = str(spec).strip()
    if _AMBIGUOUS_GMT.fullmatch(text):
        raise ZoneError(f"--timezone {text!r} is ambiguous: in the IANA database Etc/GMT+1 is one "
                        "hour behind UTC, in everyday use GMT+1 is one hour ahead; give the "
                        "offset (+01:00 or -01:00) or an IANA name (e.g. Europe/London)")
    off = _fixed_offset(text)
    if off is not None and not ("/" in text):
        return fixed_zone(off)
    try:
        import zoneinfo
        zoneinfo.ZoneInfo(text)
    except ModuleNotFoundError:  # pragma: no cover - Python < 3.9
        raise ZoneError(f"time zone {text!r}: this Python has no zoneinfo") from None
    except (zoneinfo.ZoneInfoNotFoundError, ValueError, OSError):  # OSError: a name too long
        import zoneinfo as _zi
        hint = "" if _zi.available_timezones() else (
            "; this system has no time zone database: pip install tzdata")
        raise ZoneError(f"--timezone {text[:80]!r} is neither an IANA name (e.g. Europe/London) nor an "
                        f"offset like +01:00{hint}") from None
    return Zone(text)


def fixed_zone(offset_s: int) -> Zone:
    return Zone(offset_text(offset_s), int(offset_s))


def reader_timezone(path, fmt: str, spec, override: bool = False) -> tuple[Optional[int], Zone]:
    """What to pass as ``timezone=`` to the reader of ``path`` (None: the reader's default) and
    the Zone of local time, for a user's zone ``spec`` (None: not given). A GENEActiv header's
    zone that the given one contradicts is a ``ZoneError`` unless ``override``. An MCAP log's
    zone is the one its ``clock`` record names (``zone_of_log``) unless a zone is given."""
    zone = parse_zone(spec)
    if fmt == "mcap":
        if zone.known:
            return None, zone
        from stillpoint.engine.recordings import open_recording
        src = open_recording(path)
        try:
            return None, zone_of_log(getattr(src, "metadata", {}), src.info.timezone_offset_s)
        finally:
            src.close()
    if zone.known:
        return given_zone_offset(path, fmt, zone, override), zone
    from stillpoint.drivers import read_header
    if fmt == "geneactiv":
        return None, fixed_zone(read_header(path, fmt).timezone_offset_s)
    if fmt == "gt3x":
        stored = read_header(path, fmt, timezone=0).header.get("timezone_stored_s")
        return (None, fixed_zone(stored)) if stored is not None else (0, zone)
    # .cwa (and anything else with a local clock and no stored zone)
    return 0, zone


def given_zone_offset(path, fmt: str, zone: Zone, override: bool = False) -> Optional[int]:
    """The reader's ``timezone=`` (seconds) for a zone the user gave, from at most one read of
    the header: its start time places an IANA zone (the device's offset at the recording's
    start); a GENEActiv or .gt3x header's own zone must agree with the given one unless
    ``override`` (``check_header_zone``). A .cwa needs no read for a fixed offset."""
    if fmt == "cwa" and zone.fixed_s is not None:
        return zone.fixed_s
    from stillpoint.drivers import read_header
    # a .cwa (and anything else with a local clock and no stored zone) is read as a .cwa
    info = read_header(path, fmt if fmt in ("geneactiv", "gt3x") else "cwa", timezone=0)
    start = _header_start_s(info)
    if fmt == "geneactiv":
        header_offset = _geneactiv_header_offset(info.header)
        if header_offset is not None:
            check_header_zone(path, header_offset, zone, start, override)
    elif fmt == "gt3x":
        stored = info.header.get("timezone_stored_s")
        if stored is not None:
            check_header_zone(path, stored, zone, start, override)
    elif start is None:
        raise ZoneError(f"{path}: no readable sector time to place the recording in {zone.name}")
    if zone.fixed_s is not None:
        return zone.fixed_s
    return zone.device_offset_s(start) if start is not None else zone.offset_at_s(0)


def _geneactiv_header_offset(header: dict) -> Optional[int]:
    """A GENEActiv header's own zone (Configuration Info ``Time Zone``), seconds, from the header
    fields a read gives; None when it is unreadable (the given zone then stands in for it)."""
    from stillpoint.drivers.geneactiv_header import parse_timezone
    text = header.get("Configuration Info/Time Zone", header.get("Time Zone"))
    try:
        return parse_timezone(text)
    except ValueError:
        return None


def _header_start_s(info) -> Optional[float]:
    """First sample time (device clock read as UTC, seconds) from a reader's header dict."""
    h = info.header or {}
    for key in ("first_sector_time", "start_time_ns", "Config Time"):
        v = h.get(key)
        if v is None:
            continue
        if key == "Config Time":  # GENEActiv: "2012-05-23 16:47:31:901", the device clock
            v = str(v)[:19].replace(" ", "T")
        if isinstance(v, (int, float)):
            return float(v) / (1e9 if v > 1e12 else 1.0)
        try:
            text = str(v).replace("Z", "+00:00")
            d = _dt.datetime.fromisoformat(text)
            if d.tzinfo is None:
                d = d.replace(tzinfo=_dt.timezone.utc)
            return d.timestamp()
        except ValueError:
            continue
    return None


# ---------------------------------------------------------------------------- labels
CLOCK_RECORD = "clock"  # MCAP metadata record naming the zone of the log's times


def zone_from_label(label) -> Zone:
    """The Zone an output's ``timezone`` text names (``UNKNOWN_LABEL`` or empty: unknown)."""
    if label is None or str(label).strip() in ("", UNKNOWN_LABEL, "unknown"):
        return Zone("")
    return parse_zone(str(label))


def utc_text(t_ns, zone: Zone, unit: str = "s") -> str:
    """ISO 8601 UTC (``...Z``) of an instant when the zone is known; "" when it is not (the
    instant is then the device clock, not UTC)."""
    if t_ns is None or not zone.known:
        return ""
    return iso_utc(t_ns, unit)


def local_text(t_ns, zone: Zone, unit: str = "s") -> str:
    """Local time of an instant: with the zone's offset in force (``2026-03-29T02:00:00+01:00``)
    when the zone is known, else the device clock without any offset."""
    if t_ns is None:
        return ""
    if not zone.known:
        return iso_text(t_ns, unit)
    return iso_local(t_ns, int(zone.offsets_s(np.array([int(t_ns)], np.int64))[0]), unit)


def time_column(zone: Zone) -> str:
    """Name of a per-sample time column: ``time`` (UTC) when the zone is known, else
    ``time_local`` (the device clock)."""
    return "time" if zone.known else "time_local"


def clock_record(zone: Zone, device_offset_s: int) -> dict:
    """The ``clock`` metadata record of an MCAP log: the zone of its times (``zone``: the IANA
    name or offset, "" when unknown), ``known`` (``true``/``false``), the label the outputs
    print and the device clock's offset applied to make the logged times (seconds)."""
    return {"zone": zone.name, "known": "true" if zone.known else "false", "label": zone.label,
            "device_offset_s": str(int(device_offset_s))}


def zone_of_log(metadata: dict, device_offset_s: int = 0) -> Zone:
    """The zone of an MCAP log's times from its metadata records (``{name: {key: text}}``).
    Without a ``clock`` record (a log written before it existed) the times are read as before:
    UTC shifted by the device record's offset, i.e. a fixed zone of that offset."""
    rec = (metadata or {}).get(CLOCK_RECORD)
    if not rec:
        return fixed_zone(int(device_offset_s or 0))
    if str(rec.get("known", "")).lower() != "true":
        return Zone("")
    try:
        return parse_zone(rec.get("zone") or None)
    except ZoneError:
        return fixed_zone(int(device_offset_s or 0))


def log_zone(path) -> Optional[Zone]:
    """The Zone of an MCAP log's times from its metadata alone (``zone_of_log`` with the device
    record's offset); None when the metadata cannot be read (an unfinished or damaged log)."""
    import json

    from stillpoint.engine.mcap.stream import read_metadata
    try:
        with open(path, "rb") as f:
            meta = read_metadata(f)
    except Exception:  # noqa: BLE001 - the caller's own read reports the damage
        return None
    try:
        offset = int(json.loads(meta["device"]["json"]).get("timezone_offset_s") or 0)
    except (KeyError, TypeError, ValueError, AttributeError):
        offset = 0
    return zone_of_log(meta, offset)


def check_header_zone(path, header_offset_s: int, zone: Zone, start_s, override: bool) -> None:
    """A GENEActiv header states its zone; a given zone that puts the recording at another
    offset is refused unless ``override`` (the run then records that it replaced the header's)."""
    if override or not zone.known:
        return
    offset = zone.device_offset_s(start_s) if start_s is not None else zone.offset_at_s(0)
    if offset != int(header_offset_s):
        raise ZoneError(
            f"{path}: the header's time zone is {fixed_zone(int(header_offset_s)).name} but "
            f"--timezone {zone.name} puts this recording at {fixed_zone(offset).name}; leave "
            "--timezone out to keep the header's, or add --timezone-override to replace it")


def host_zone() -> Zone:
    """This computer's zone, the one whose wall-clock time a station sets the device clocks from
    (the ledger's ``host_time_zone`` labels it): ``TZ`` when it names a zone, else the IANA name
    ``/etc/localtime`` links to (or ``/etc/timezone`` holds), else the fixed offset in force now."""
    import os
    import time as _time
    candidates = []
    tz = os.environ.get("TZ", "").lstrip(":").strip()
    if tz:
        candidates.append(tz)
    try:
        target = os.path.realpath("/etc/localtime")
        if "zoneinfo/" in target:
            candidates.append(target.split("zoneinfo/", 1)[1])
    except OSError:
        pass
    try:
        with open("/etc/timezone") as f:
            candidates.append(f.read().strip())
    except OSError:
        pass
    for name in candidates:
        try:
            z = parse_zone(name)
        except ZoneError:
            continue
        if z.known:
            return z
    return fixed_zone(_time.localtime().tm_gmtoff)
