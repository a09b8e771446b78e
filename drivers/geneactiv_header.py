"""GENEActiv ``.bin`` text header: parsing by section heading and key, time strings, time zones.

Pure functions over text; no file I/O here (the reader in ``geneactiv.py`` feeds the bytes).
See ../shared/specs/geneactiv-format.md §1, §2, §4.
"""

from __future__ import annotations

import datetime as _dt
import re
from dataclasses import dataclass, field
from typing import Optional, Union

import numpy as np

from stillpoint.engine.core.times import offset_text, parse_offset

from .constants import GNA_PAGE_MARKER, gna_rate_hz

# Section headings of the standard header [GNA] §2 (a free-text line that is none of these and has no
# colon is taken as a continuation of the previous value, e.g. multi-line notes).
SECTIONS = ("Device Identity", "Device Capabilities", "Configuration Info", "Trial Info",
            "Subject Info", "Calibration Data", "Memory Status")
TRIAL_KEYS = ("Study Centre", "Study Code", "Investigator ID", "Exercise Type", "Config Operator ID",
              "Config Time", "Config Notes", "Extract Operator ID", "Extract Time", "Extract Notes")
SUBJECT_KEYS = ("Device Location Code", "Subject Code", "Date of Birth", "Sex", "Height", "Weight",
                "Handedness Code", "Subject Notes")
CALIBRATION_KEYS = ("x gain", "x offset", "y gain", "y offset", "z gain", "z offset")

_STRIP = " \t\r\x00"
_TIME_RE = re.compile(r"^\s*(\d{1,4})-(\d{1,2})-(\d{1,2})[ T](\d{1,2}):(\d{1,2}):(\d{1,2})"
                      r"(?:([:.])(\d{1,3}))?\s*$")

_EPOCH_DAYS_0000 = 719468  # days from 0000-03-01 to 1970-01-01 (civil-calendar algorithm)


def clean(value: str) -> str:
    """Strip the spaces, tabs, CR and NUL padding the device leaves around values. [GNA] §1"""
    return value.strip(_STRIP)


def parse_number(text: str) -> float:
    """A header/page number that may use a comma decimal separator ("21,5"). [GNA] §1"""
    return float(clean(text).replace(",", ".").split()[0])


@dataclass
class GeneactivHeader:
    """The parsed header: sections of key -> value (cleaned strings) plus what the reader needs."""

    sections: dict[str, dict[str, str]] = field(default_factory=dict)
    lines: int = 0  # header lines before the first "Recorded Data"
    warnings: list[str] = field(default_factory=list)

    def get(self, key: str, section: Optional[str] = None, default: Optional[str] = None):
        if section is not None:
            return self.sections.get(section, {}).get(key, default)
        for sec in self.sections.values():
            if key in sec:
                return sec[key]
        return default

    def flat(self) -> dict[str, str]:
        """key -> value over all sections (a key repeated in two sections is "Section/key")."""
        out: dict[str, str] = {}
        for sec, kv in self.sections.items():
            for k, v in kv.items():
                out[f"{sec}/{k}" if k in out else k] = v
        return out


def split_header_lines(text: str) -> list[str]:
    """Lines of the header, accepting CR LF, LF or lone CR endings."""
    return text.replace("\r\n", "\n").replace("\r", "\n").split("\n")


def parse_header_text(text: str) -> GeneactivHeader:
    """Parse the header text (everything before the first "Recorded Data" line) by section and key.

    Keys are split at the first colon; values are stripped of spaces and NUL padding. A line
    that is neither a known heading nor ``key:value`` continues the previous value.
    """
    hdr = GeneactivHeader()
    section = ""
    last_key: Optional[str] = None
    lines = split_header_lines(text)
    hdr.lines = len(lines)
    for raw in lines:
        line = clean(raw)
        if not line:
            last_key = None
            continue
        if line in SECTIONS or line == GNA_PAGE_MARKER:
            section = line
            hdr.sections.setdefault(section, {})
            last_key = None
            continue
        key, sep, value = line.partition(":")
        if sep:
            key = clean(key)
            hdr.sections.setdefault(section, {})[key] = clean(value)
            last_key = key
        elif last_key is not None:
            sec = hdr.sections[section]
            sec[last_key] = (sec[last_key] + "\n" + line).strip()
        else:
            # an unknown heading: keep it as a section of its own
            section = line
            hdr.sections.setdefault(section, {})
    return hdr


def parse_timezone(value: Union[str, int, float, _dt.timedelta, None]) -> int:
    """Offset of the device clock from UTC in seconds, from "GMT +01:00", "-04:00", "+0530", "UTC",
    a number of seconds or a timedelta. Sign, hours and minutes are all used. [GNA] §2
    """
    if value is None:
        raise ValueError("no time zone")
    if isinstance(value, _dt.timedelta):
        return int(value.total_seconds())
    if isinstance(value, (int, float, np.integer, np.floating)):
        return int(value)
    return parse_offset(clean(str(value)))


def format_timezone(offset_s: int) -> str:
    """"GMT +01:00" form of an offset in seconds (the header's own format)."""
    return f"GMT {offset_text(offset_s)}"


def days_from_civil(y, m, d):
    """Days since 1970-01-01 of a proleptic Gregorian date (vectorised; H. Hinnant's algorithm)."""
    y = np.asarray(y, np.int64) - (np.asarray(m) <= 2)
    era = np.floor_divide(y, 400)
    yoe = y - era * 400
    m = np.asarray(m, np.int64)
    doy = (153 * (m + np.where(m > 2, -3, 9)) + 2) // 5 + np.asarray(d, np.int64) - 1
    doe = yoe * 365 + yoe // 4 - yoe // 100 + doy
    return era * 146097 + doe - _EPOCH_DAYS_0000


def parse_time_ms(text: str) -> Optional[int]:
    """"YYYY-MM-DD HH:MM:SS:mmm" (4th field = 3-digit milliseconds; date fields may lack zero padding)
    -> milliseconds since 1970 on the device clock, or None when it is not a valid time (e.g. the
    "0000-00-00 00:00:00:000" an unset Start Time holds). [GNA] §4
    """
    m = _TIME_RE.match(clean(text))
    if not m:
        return None
    y, mo, d, hh, mi, ss = (int(g) for g in m.groups()[:6])
    if m.group(7) == ":" and len(m.group(8)) != 3:
        # ":mmm" is milliseconds, always 3 digits: "22:5" would be 5 ms to one reader and 500 ms
        # to another (decimal seconds), and a last digit damaged into a space must not pass as
        # a shorter value ("22:50 " -> "22:50")
        return None
    frac = m.group(8) or "0"
    ms = int(frac.ljust(3, "0")) if m.group(7) == "." else int(frac)  # ":mmm" is milliseconds
    if not (1 <= mo <= 12 and 1 <= d <= 31 and hh < 24 and mi < 60 and ss < 61 and y >= 1):
        return None
    try:
        _dt.date(y, mo, d)
    except ValueError:
        return None
    days = int(days_from_civil(y, mo, d))
    return ((days * 24 + hh) * 60 + mi) * 60_000 + ss * 1000 + ms


def parse_times_ms(values: list[bytes]) -> tuple[np.ndarray, np.ndarray]:
    """Many Page Time values -> (ms since 1970 on the device clock, valid mask).

    The zero-padded "YYYY-MM-DD HH:MM:SS:mmm" form (23 bytes) is parsed vectorised; every value
    that form does not accept (another width, a 'T' separator, '.mmm', ...) is parsed on its own
    by ``parse_time_ms``. A value's result never depends on the other values in the list (so a
    page's time does not depend on which pages share its read batch)."""
    n = len(values)
    t = np.zeros(n, np.int64)
    ok = np.zeros(n, bool)
    fixed = [i for i, v in enumerate(values) if len(v) == 23]
    if fixed:
        rows = np.asarray(fixed, np.int64)
        tf, okf = _parse_fixed(b"".join(values[i] for i in fixed))
        t[rows] = tf
        ok[rows] = okf
    for i in np.flatnonzero(~ok).tolist():
        v = parse_time_ms(values[i].decode("latin-1"))
        if v is not None:
            t[i], ok[i] = v, True
    return t, ok


def _parse_fixed(joined: bytes) -> tuple[np.ndarray, np.ndarray]:
    """The vectorised part of parse_times_ms: 23-byte values joined, -> (ms, valid mask)."""
    a = np.frombuffer(joined, np.uint8).reshape(-1, 23).astype(np.int64) - 48
    sep_ok = ((a[:, 4] == ord("-") - 48) & (a[:, 7] == ord("-") - 48) & (a[:, 10] == ord(" ") - 48)
              & (a[:, 13] == ord(":") - 48) & (a[:, 16] == ord(":") - 48) & (a[:, 19] == ord(":") - 48))
    digit_cols = [0, 1, 2, 3, 5, 6, 8, 9, 11, 12, 14, 15, 17, 18, 20, 21, 22]
    dig = a[:, digit_cols]
    dig_ok = ((dig >= 0) & (dig <= 9)).all(axis=1)
    y = a[:, 0] * 1000 + a[:, 1] * 100 + a[:, 2] * 10 + a[:, 3]
    mo = a[:, 5] * 10 + a[:, 6]
    d = a[:, 8] * 10 + a[:, 9]
    hh = a[:, 11] * 10 + a[:, 12]
    mi = a[:, 14] * 10 + a[:, 15]
    ss = a[:, 17] * 10 + a[:, 18]
    ms = a[:, 20] * 100 + a[:, 21] * 10 + a[:, 22]
    dim = np.array([31, 29, 31, 30, 31, 30, 31, 31, 30, 31, 30, 31])[np.clip(mo - 1, 0, 11)]
    leap = ((y % 4 == 0) & (y % 100 != 0)) | (y % 400 == 0)
    dim = np.where((mo == 2) & ~leap, 28, dim)
    ok = (sep_ok & dig_ok & (y >= 1) & (mo >= 1) & (mo <= 12) & (d >= 1) & (d <= dim) & (hh < 24)
          & (mi < 60) & (ss < 61))
    days = days_from_civil(np.where(ok, y, 1970), np.where(ok, mo, 1), np.where(ok, d, 1))
    t = ((days * 24 + hh) * 60 + mi) * 60_000 + ss * 1000 + ms
    return t, ok


def format_time_ms(ms: int) -> str:
    """Milliseconds since 1970 (device clock) -> "YYYY-MM-DD HH:MM:SS:mmm". [GNA] §4"""
    sec, milli = divmod(int(ms), 1000)
    t = _dt.datetime(1970, 1, 1) + _dt.timedelta(seconds=sec)
    return f"{t:%Y-%m-%d %H:%M:%S}:{milli:03d}"


def header_rate_hz(hdr: GeneactivHeader) -> Optional[float]:
    v = hdr.get("Measurement Frequency", "Configuration Info")
    if not v:
        return None
    try:
        return gna_rate_hz(v)
    except (ValueError, IndexError):
        return None


def header_range_g(hdr: GeneactivHeader) -> float:
    """±g from "Accelerometer Range:-8 to 8" (8.0 when absent or unreadable)."""
    v = hdr.get("Accelerometer Range", "Device Capabilities", "")
    nums = re.findall(r"[-+]?\d+(?:[.,]\d+)?", v or "")
    try:
        return max(abs(float(n.replace(",", "."))) for n in nums) if nums else 8.0
    except ValueError:
        return 8.0

