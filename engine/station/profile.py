"""Study profiles (TOML): how devices are configured for the next wearer, and the station's
defaults. Read with ``tomllib`` (Python 3.11+; on 3.10 the ``tomli`` package if installed).

    [device]
    rate_hz = 100            # 6.25 ... 3200 (3200 / 2^k)
    range_g = 8              # 2, 4, 8, 16
    gyro_dps = 0             # AX6 only: 0 (off), 125, 250, 500, 1000, 2000
    start = "+1h"            # "0" (as soon as unplugged), "+<n>[mhd]" from now, or local ISO time
    stop = "+8d"             # "-1" (never), "+<n>[mhd]" after start, or local ISO time
    session = "increment"    # "increment" (previous + 1), "keep", or a number
    min_battery_pct = 80
    led_flash = false        # DEBUG 3 (flash while recording) or 0

    [metadata]               # written to the 14 x 32-character annotation slots (URL-encoded)
    study = "ABC"
    site = "wrist"

    [station]
    clear_after_verify = true
    configure_after = true
"""

from __future__ import annotations

import datetime as _dt
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

from stillpoint.drivers import constants as C
from stillpoint.drivers.errors import StillpointError


class ProfileError(StillpointError):
    """The study profile cannot be read or holds an invalid value."""


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
            return tomllib.load(f)
    except OSError as e:
        raise ProfileError(f"{path}: cannot read: {e.strerror}") from None
    except tomllib.TOMLDecodeError as e:
        raise ProfileError(f"{path}: not valid TOML: {e}") from None
    except UnicodeDecodeError as e:
        raise ProfileError(f"{path}: not a TOML text file (byte {e.start} is not UTF-8)") from None


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
    path: Optional[str] = None

    @property
    def rate_code(self) -> int:
        try:
            return C.cwa_rate_code(self.rate_hz, self.range_g)
        except ValueError as e:
            raise ProfileError(f"{self.path or 'profile'}: {e}") from None

    def session_for(self, previous: int) -> int:
        if self.session == "increment":
            return (previous + 1) % (1 << 31)
        if self.session == "keep":
            return previous
        return int(self.session)

    def times(self, now: _dt.datetime) -> tuple[str, str, Optional[_dt.datetime]]:
        """(HIBERNATE value, STOP value, start as local time or None) for the device."""
        start_dt = None
        if self.start == "0":
            start = "0"
        else:
            start_dt = _when(self.start, now, self.path)
            start = start_dt.strftime("%Y/%m/%d,%H:%M:%S")
        if self.stop in ("-1", "never"):
            stop = "-1"
        else:
            base = start_dt or now
            stop = _when(self.stop, base, self.path).strftime("%Y/%m/%d,%H:%M:%S")
        return start, stop, start_dt

    def annotation_slots(self) -> list[str]:
        """The metadata as a URL-encoded ``key=value&...`` string cut into 14 slots of 32."""
        from urllib.parse import urlencode
        text = urlencode({str(k): str(v) for k, v in self.metadata.items()})
        if len(text) > 14 * 32:
            raise ProfileError(f"{self.path or 'profile'}: metadata is {len(text)} characters "
                               "URL-encoded; the device holds 448")
        return [text[i * 32:(i + 1) * 32] for i in range(14)]

    def to_dict(self) -> dict:
        from dataclasses import asdict
        return asdict(self)


_REL = re.compile(r"^\+(\d+(?:\.\d+)?)\s*([mhd])$")


def _when(text: str, base: _dt.datetime, path) -> _dt.datetime:
    m = _REL.match(text.strip())
    if m:
        mult = {"m": 60, "h": 3600, "d": 86400}[m.group(2)]
        return (base + _dt.timedelta(seconds=float(m.group(1)) * mult)).replace(microsecond=0)
    try:
        return _dt.datetime.fromisoformat(text.strip()).replace(tzinfo=None, microsecond=0)
    except ValueError:
        raise ProfileError(f"{path or 'profile'}: time {text!r} is neither '+<n>m/h/d' nor an ISO "
                           "date-time") from None


def load_profile(path) -> StudyProfile:
    p = Path(path)
    d = _toml_load(p)
    dev, st = d.get("device", {}), d.get("station", {})
    try:
        prof = StudyProfile(
            rate_hz=float(dev.get("rate_hz", 100)), range_g=int(dev.get("range_g", 8)),
            gyro_dps=int(dev.get("gyro_dps", 0)), start=str(dev.get("start", "0")),
            stop=str(dev.get("stop", "-1")), session=str(dev.get("session", "increment")),
            min_battery_pct=int(dev.get("min_battery_pct", 0)),
            led_flash=bool(dev.get("led_flash", False)), metadata=dict(d.get("metadata", {})),
            clear_after_verify=bool(st.get("clear_after_verify", False)),
            configure_after=bool(st.get("configure_after", False)), path=str(p))
    except (TypeError, ValueError) as e:
        raise ProfileError(f"{p}: {e}") from None
    prof.rate_code  # validates rate and range
    if prof.gyro_dps and prof.gyro_dps not in C.AX_GYRO_RANGES_DPS:
        raise ProfileError(f"{p}: gyro_dps must be 0 or one of {C.AX_GYRO_RANGES_DPS}")
    if prof.session not in ("increment", "keep") and not prof.session.isdigit():
        raise ProfileError(f"{p}: session must be 'increment', 'keep' or a number")
    prof.annotation_slots()
    now = _dt.datetime.now()
    prof.times(now)
    return prof
