"""Time text: the one ISO 8601 instant formatter, the one UTC-offset formatter and parser.

Instants are int nanoseconds since 1970-01-01 (UTC, or the device clock when its zone is
unknown); text is truncated to ``unit`` ("s", "ms", "us" or "ns"), never rounded up, so a time
never reads as later than it was. Offsets are int seconds east of UTC, written ``+HH:MM``.

- ``iso_text(t_ns, unit)``: ``2025-03-30T00:59:59`` (no zone suffix: a device clock, or the caller's);
  ``iso_utc(t_ns, unit)`` adds ``Z``; ``iso_local(t_ns, offset_s, unit)`` gives the wall-clock time
  at that offset with it (``2025-03-30T02:00:00+01:00``); ``iso_texts`` is ``iso_text`` over an array.
- ``offset_text(offset_s)``: ``+01:00`` / ``-04:30``; ``offset_texts`` over an array.
- ``parse_offset(text)``: seconds from ``+01:00``, ``-0530``, ``+1``, ``GMT +01:00``, ``UTC``, ``Z``.
"""

from __future__ import annotations

import re

import numpy as np

UNITS = ("s", "ms", "us", "ns")
MAX_OFFSET_H = 14  # UTC+14 (Kiribati) is the largest offset in use; -12 the smallest

_OFFSET_RE = re.compile(r"^(?:GMT|UTC|Z)?\s*(?:([+-])\s*)?(\d{1,2})?(?::?(\d{2}))?$", re.IGNORECASE)


def iso_text(t_ns: int, unit: str = "s") -> str:
    """ISO 8601 text of an instant without a zone suffix, truncated to ``unit``."""
    return str(np.datetime64(int(t_ns), "ns").astype(f"datetime64[{unit}]"))


def iso_texts(t_ns: np.ndarray, unit: str = "s") -> np.ndarray:
    """``iso_text`` of every instant of an int64 array (an array of str)."""
    t = np.asarray(t_ns).astype("datetime64[ns]").astype(f"datetime64[{unit}]")
    return np.datetime_as_string(t, unit=unit)  # type: ignore[call-overload]  # unit: a str


def iso_utc(t_ns: int, unit: str = "s") -> str:
    """ISO 8601 UTC text of an instant: ``2025-03-30T00:59:59Z``."""
    return iso_text(t_ns, unit) + "Z"


def iso_local(t_ns: int, offset_s: int, unit: str = "s") -> str:
    """The wall-clock time of an instant at a UTC offset, with the offset:
    ``2025-03-30T02:00:00+01:00``."""
    return iso_text(int(t_ns) + int(offset_s) * 10**9, unit) + offset_text(offset_s)


def offset_text(offset_s: int) -> str:
    """``+HH:MM`` of an offset in seconds east of UTC (``-04:30``; zero is ``+00:00``)."""
    a = abs(int(offset_s)) // 60
    return f"{'-' if offset_s < 0 else '+'}{a // 60:02d}:{a % 60:02d}"


def offset_texts(offset_s: np.ndarray) -> np.ndarray:
    """``offset_text`` of every offset of an int array (an array of str)."""
    off = np.asarray(offset_s)
    out = np.empty(off.shape, object)
    for o in np.unique(off):
        out[off == o] = offset_text(int(o))
    return out.astype(str)


def parse_offset(text: str) -> int:
    """Seconds east of UTC from ``+01:00``, ``-0530``, ``+1``, ``01:00``, ``GMT +01:00``, ``UTC``,
    ``GMT`` or ``Z`` (case and spaces as written by devices); ValueError for anything else or an
    offset beyond +-14 h."""
    text = str(text).strip()
    m = _OFFSET_RE.match(text)
    if not m or (m.group(2) is None and m.group(3) is None
                 and text.upper() not in ("GMT", "UTC", "Z")):
        raise ValueError(f"cannot read time zone {text!r} (expected e.g. 'GMT +01:00' or '-04:00')")
    sign = -1 if m.group(1) == "-" else 1
    hours, minutes = int(m.group(2) or 0), int(m.group(3) or 0)
    if hours > MAX_OFFSET_H or minutes >= 60:
        raise ValueError(f"time zone {text!r} is out of range")
    return sign * (hours * 3600 + minutes * 60)
