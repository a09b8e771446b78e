"""Study profiles (TOML): how devices are configured for the next wearer, and the station's
defaults. Read with ``tomllib`` (Python 3.11+; on 3.10 the ``tomli`` package if installed).

    [device]
    type = "AX6"             # optional: "AX3" or "AX6" (default: the profile fits both)
    rate_hz = 100            # 3200 / 2^k Hz that the device type records (see below)
    range_g = 8              # 2, 4, 8, 16
    gyro_dps = 0             # AX6 only: 0 (off), 125, 250, 500, 1000, 2000
    start = "+1h"            # "0" (as soon as unplugged), "+<n>[mhd]" from now, or local ISO time
    stop = "+8d"             # "-1" (never), "+<n>[mhd]" after start, or local ISO time
    session = "increment"    # "increment" (previous + 1), "keep", or a number 0 .. 2147483647
    min_battery_pct = 80     # 0 .. 100
    led_flash = false        # DEBUG 3 (flash while recording) or 0

    [metadata]               # written to the 14 x 32-character annotation slots (URL-encoded)
    study = "ABC"
    site = "wrist"

    [station]
    clear_after_verify = true
    configure_after = true
    erase = "quick"          # "quick" (FORMAT QC) or "wipe" (FORMAT WC)
    file_name = "{study}_{subject}_{device}_{session}"  # optional: download names (study.py)
    timezone = "Europe/London"  # optional: the participants' zone (IANA name or +01:00); default:
                                # the zone of this computer, which sets the device clocks

Every value is checked when the profile loads, before any device is touched, against what the
device types it may meet can record (``constants.AX_DEVICE_RULES``: one row per rule, each citing
the firmware or vendor source): an AX3 (packed) records 12.5-3200 Hz, an AX6 6.25-1600 Hz
and with the gyro on at least 25 Hz; only an AX6 has a gyro. A profile without ``type`` must fit
both types, unless it turns the gyro on (then it is for AX6s). Unknown keys are refused (a
misspelt key would otherwise be ignored in silence).
"""

from __future__ import annotations

import datetime as _dt
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

from stillpoint.drivers import constants as C
from stillpoint.engine.core.errors import StillpointError


class ProfileError(StillpointError):
    """The study profile cannot be read or holds an invalid value."""


# The example study profile (``station --write-profile FILE`` writes it; the station guide shows
# it): every device type, a recording from an hour after unplugging for eight days.
EXAMPLE_PROFILE = """\
[device]
rate_hz = 100            # 3200 / 2^k Hz the device records: AX3 12.5-3200, AX6 6.25-1600
range_g = 8              # 2, 4, 8, 16
gyro_dps = 0             # AX6 only: 0 (off), 125 ... 2000; with the gyro on, at least 25 Hz
start = "+1h"            # "0" (when unplugged), "+<n>m|h|d" from now, or an ISO local time
stop = "+8d"             # "-1" (never), "+<n>m|h|d" after the start, or an ISO local time
session = "increment"    # "increment", "keep" or a number 0 .. 2147483647
min_battery_pct = 80
[metadata]               # URL-encoded into the 14 x 32-character annotation slots
study = "ABC"
[station]
clear_after_verify = true
configure_after = true
erase = "quick"          # the clear's erase: "quick" (FORMAT QC) or "wipe" (FORMAT WC)
"""


def write_example_profile(path) -> Path:
    """Write ``EXAMPLE_PROFILE`` to ``path``, a new file (an existing one is never replaced)."""
    p = Path(path)
    try:
        with open(p, "x", encoding="utf-8") as f:
            f.write(EXAMPLE_PROFILE)
    except FileExistsError:
        raise ProfileError(f"{p}: already exists; it is never replaced (remove it, or write the "
                           "example profile to another name)") from None
    except OSError as e:
        raise ProfileError(f"{p}: cannot write the example profile: {e.strerror or e}") from None
    return p


_DEVICE_KEYS = ("type", "rate_hz", "range_g", "gyro_dps", "start", "stop", "session",
                "min_battery_pct", "led_flash")
_STATION_KEYS = ("clear_after_verify", "configure_after", "erase", "file_name", "timezone")
_TABLES = ("device", "metadata", "station")
_SESSION_RE = re.compile(r"^[0-9]+$")
# the years every device type can hold (start/stop times are checked before the type is known)
_YEARS = (max(r["years"][0] for r in C.AX_RULES.values()), min(r["years"][1] for r in C.AX_RULES.values()))


# a study profile is a page of settings; anything larger is not one (and is not parsed)
MAX_PROFILE_BYTES = 1 << 20


def _toml_load(path: Path) -> dict:
    try:
        import tomllib  # Python 3.11+
    except ImportError:  # pragma: no cover - Python 3.10
        try:
            import tomli as tomllib  # type: ignore[no-redef]
        except ImportError:
            raise ProfileError(f"{path}: reading a study profile needs Python 3.11 (tomllib) or the "
                               "'tomli' package on Python 3.10") from None
    try:
        with open(path, "rb") as f:
            data = f.read(MAX_PROFILE_BYTES + 1)
        if len(data) > MAX_PROFILE_BYTES:
            raise ProfileError(f"{path}: over {MAX_PROFILE_BYTES // 1024} KiB, not a study profile")
        return tomllib.loads(data.decode("utf-8"))
    except RecursionError:  # tables or arrays nested thousands deep
        raise ProfileError(f"{path}: not a study profile (tables nested too deeply)") from None
    except OSError as e:
        raise ProfileError(f"{path}: cannot read: {e.strerror}") from None
    except tomllib.TOMLDecodeError as e:
        raise ProfileError(f"{path}: not valid TOML: {e}") from None
    except UnicodeDecodeError as e:
        raise ProfileError(f"{path}: not a TOML text file (byte {e.start} is not UTF-8)") from None
    except ValueError as e:  # e.g. an integer of thousands of digits (Python's conversion limit)
        raise ProfileError(f"{path}: not a study profile ({str(e)[:100]})") from None


@dataclass
class StudyProfile:
    rate_hz: float = 100.0
    range_g: int = 8
    gyro_dps: int = 0
    start: str = "0"
    stop: str = "-1"
    session: str = "increment"
    min_battery_pct: int = 0
    led_flash: bool = False
    metadata: dict = field(default_factory=dict)
    clear_after_verify: bool = False
    configure_after: bool = False
    erase: str = "quick"
    file_name: Optional[str] = None  # the download's file-name template (study.file_stem)
    timezone: Optional[str] = None  # the zone of the logs and products (None: the host's zone)
    device_type: Optional[str] = None  # "AX3" | "AX6" | None (both)
    path: Optional[str] = None

    def _err(self, msg: str) -> ProfileError:
        return ProfileError(f"{self.path or 'profile'}: {msg}")

    @property
    def rate_code(self) -> int:
        if not math.isfinite(self.rate_hz):
            raise self._err(f"rate_hz must be a number of Hz, not {self.rate_hz}")
        try:
            return C.cwa_rate_code(self.rate_hz, self.range_g)
        except (ValueError, OverflowError) as e:
            raise self._err(str(e)) from None

    @property
    def device_types(self) -> tuple[str, ...]:
        """The device types this profile can configure."""
        if self.device_type:
            return (self.device_type,)
        if self.gyro_dps:
            return C.AX_GYRO_DEVICE_TYPES
        return tuple(C.AX_RULES)

    def check_device(self, device_type: str) -> None:
        """Refuse (``ProfileError``) settings a device of ``device_type`` cannot record."""
        if device_type not in self.device_types:
            why = (f"gyro_dps = {self.gyro_dps} needs an AX6" if self.gyro_dps and device_type not in
                   C.AX_GYRO_DEVICE_TYPES else f"it is for {' and '.join(self.device_types)} devices")
            raise self._err(f"cannot configure an {device_type}: {why}")
        rules = C.AX_RULES[device_type]
        lo, hi = rules["rate_hz"]
        if not lo <= self.rate_hz <= hi:
            others = [k for k, r in C.AX_RULES.items() if k != device_type
                      and r["rate_hz"][0] <= self.rate_hz <= r["rate_hz"][1]]
            hint = (f'; a profile for {others[0]}s only says type = "{others[0]}"'
                    if others and self.device_type is None else "")
            raise self._err(f"rate_hz = {self.rate_hz:g} is not recordable by an {device_type} "
                            f"({lo:g}-{hi:g} Hz" + (", packed" if device_type == "AX3" else "") + ")"
                            + hint)
        if self.gyro_dps:
            if not rules["gyro_dps"]:
                raise self._err(f"gyro_dps = {self.gyro_dps}: an {device_type} has no gyroscope")
            if self.gyro_dps not in rules["gyro_dps"]:
                raise self._err(f"gyro_dps must be 0 or one of {rules['gyro_dps']}, not {self.gyro_dps}")
            if self.rate_hz < rules["gyro_min_rate_hz"]:
                raise self._err(f"rate_hz = {self.rate_hz:g} with gyro_dps = {self.gyro_dps}: the "
                                f"gyroscope needs at least {rules['gyro_min_rate_hz']:g} Hz")

    def check(self) -> None:
        """Every value, against every device type the profile may meet."""
        self.rate_code  # noqa: B018 - validates rate and range
        for kind in self.device_types:
            self.check_device(kind)
        if self.session not in ("increment", "keep"):
            if not _SESSION_RE.match(self.session):
                raise self._err(f"session must be 'increment', 'keep' or a whole number 0.."
                                f"{C.AX_SESSION_MAX}, not {self.session[:40]!r}")
            if len(self.session) > 12 or int(self.session) > C.AX_SESSION_MAX:
                raise self._err(f"session {self.session[:40]} is above {C.AX_SESSION_MAX}, the "
                                "largest session id the vendor's software sets")
        if not 0 <= self.min_battery_pct <= 100:
            raise self._err(f"min_battery_pct must be 0..100, not {self.min_battery_pct}")
        if self.erase not in C.AX_ERASE_COMMANDS:
            raise self._err(f"erase must be one of {', '.join(map(repr, C.AX_ERASE_COMMANDS))}, "
                            f"not {self.erase!r}")
        self.annotation_slots()
        self.times(_dt.datetime.now())
        if self.timezone is not None:
            from stillpoint.engine.timezones import ZoneError, parse_zone
            try:
                parse_zone(self.timezone)
            except ZoneError as e:
                raise self._err(f"[station] timezone: {e}") from None
        if self.file_name is not None:
            from .study import StudyRecordError, check_template
            try:
                check_template(self.file_name, "[station] file_name")
            except StudyRecordError as e:
                raise self._err(str(e)) from None

    def session_for(self, previous: int) -> int:
        if self.session == "increment":
            return (previous + 1) % (C.AX_SESSION_MAX + 1)
        if self.session == "keep":
            return previous
        return int(self.session)

    def times(self, now: _dt.datetime) -> tuple[str, str, Optional[_dt.datetime]]:
        """(HIBERNATE value, STOP value, start as local time or None) for the device."""
        start_dt = None
        if self.start == "0":
            start = "0"
        else:
            start_dt = _when(self.start, now, self.path, "start")
            start = start_dt.strftime("%Y/%m/%d,%H:%M:%S")
        if self.stop in ("-1", "never"):
            stop = "-1"
        else:
            base = start_dt or now
            stop = _when(self.stop, base, self.path, "stop").strftime("%Y/%m/%d,%H:%M:%S")
        return start, stop, start_dt

    def annotation_slots(self) -> list[str]:
        """The metadata as a URL-encoded ``key=value&...`` string cut into 14 slots of 32."""
        from urllib.parse import urlencode
        n, w = min(C.AX_RULES[k]["annotation"] for k in self.device_types)
        text = urlencode({str(k): str(v) for k, v in self.metadata.items()})
        if len(text) > n * w:
            raise self._err(f"metadata is {len(text)} characters URL-encoded; the device holds "
                            f"{n * w} ({n} slots of {w})")
        return [text[i * w:(i + 1) * w] for i in range(n)]

    def to_dict(self) -> dict:
        from dataclasses import asdict
        return asdict(self)


_REL = re.compile(r"^\+(\d{1,9}(?:\.\d{1,6})?)\s*([mhd])$")


def _when(text: str, base: _dt.datetime, path, what: str = "time") -> _dt.datetime:
    where = path or "profile"
    m = _REL.match(text.strip())
    try:
        if m:
            mult = {"m": 60, "h": 3600, "d": 86400}[m.group(2)]
            t = (base + _dt.timedelta(seconds=float(m.group(1)) * mult)).replace(microsecond=0)
        else:
            t = _dt.datetime.fromisoformat(text.strip()).replace(tzinfo=None, microsecond=0)
    except (OverflowError, ValueError):
        if m:
            raise ProfileError(f"{where}: {what} {text!r} is beyond the year "
                               f"{_YEARS[1]} a device can hold") from None
        raise ProfileError(f"{where}: {what} {text[:60]!r} is neither '+<n>m/h/d' nor an ISO "
                           "date-time") from None
    lo, hi = _YEARS
    if not lo <= t.year <= hi:
        raise ProfileError(f"{where}: {what} {t:%Y-%m-%d %H:%M} is outside the years {lo}-{hi} a "
                           "device can hold")
    return t


def _table(d: dict, name: str, path: Path, keys: Optional[tuple] = None) -> dict:
    t = d.get(name, {})
    if not isinstance(t, dict):
        raise ProfileError(f"{path}: [{name}] must be a table of key = value lines, not a "
                           f"{type(t).__name__}")
    if keys is not None:
        unknown = sorted(set(t) - set(keys))
        if unknown:
            raise ProfileError(f"{path}: unknown key {unknown[0]!r} in [{name}]; known: "
                               f"{', '.join(keys)}")
    return t


def _typed(t: dict, key: str, default, kinds: tuple, what: str, path: Path, table: str):
    v = t.get(key, default)
    if isinstance(v, bool) and bool not in kinds or not isinstance(v, kinds):
        raise ProfileError(f"{path}: [{table}] {key} must be {what}, not {v!r}"[:200])
    return v


def load_profile(path) -> StudyProfile:
    p = Path(path)
    d = _toml_load(p)
    unknown = sorted(set(d) - set(_TABLES))
    if unknown:
        raise ProfileError(f"{p}: unknown table or key {unknown[0]!r}; a profile has "
                           f"{', '.join('[' + t + ']' for t in _TABLES)}")
    dev = _table(d, "device", p, _DEVICE_KEYS)
    st = _table(d, "station", p, _STATION_KEYS)
    meta = _table(d, "metadata", p)
    for k, v in meta.items():
        if isinstance(v, (dict, list)):
            raise ProfileError(f"{p}: [metadata] {k} must be a single value, not a "
                               f"{type(v).__name__}")
    num, whole, text, flag = (int, float), (int,), (str,), (bool,)
    kind = _typed(dev, "type", None, text + (type(None),), '"AX3" or "AX6"', p, "device")
    if kind is not None and kind.upper() not in C.AX_RULES:
        raise ProfileError(f'{p}: [device] type must be "AX3" or "AX6", not {kind[:40]!r}')
    session = _typed(dev, "session", "increment", text + whole, "'increment', 'keep' or a number",
                     p, "device")
    prof = StudyProfile(
        rate_hz=float(_typed(dev, "rate_hz", 100, num, "a number of Hz", p, "device")),
        range_g=_typed(dev, "range_g", 8, whole, "a whole number of g", p, "device"),
        gyro_dps=_typed(dev, "gyro_dps", 0, whole, "a whole number of dps", p, "device"),
        start=str(_typed(dev, "start", "0", text + whole, "a time", p, "device")),
        stop=str(_typed(dev, "stop", "-1", text + whole, "a time", p, "device")),
        session=str(session),
        min_battery_pct=_typed(dev, "min_battery_pct", 0, whole, "a whole percentage", p, "device"),
        led_flash=_typed(dev, "led_flash", False, flag, "true or false", p, "device"),
        metadata=dict(meta),
        clear_after_verify=_typed(st, "clear_after_verify", False, flag, "true or false", p,
                                  "station"),
        configure_after=_typed(st, "configure_after", False, flag, "true or false", p, "station"),
        erase=_typed(st, "erase", "quick", text, '"quick" or "wipe"', p, "station"),
        file_name=_typed(st, "file_name", None, text + (type(None),), "a file-name template", p,
                         "station"),
        timezone=_typed(st, "timezone", None, text + (type(None),),
                        'a zone ("Europe/London" or "+01:00")', p, "station"),
        device_type=kind.upper() if kind else None, path=str(p))
    prof.check()
    return prof
