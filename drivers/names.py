"""Names and table cells made from recording metadata, which is never trusted.

A recording's header is free text written by a device, a vendor program or anyone: a GENEActiv
``Device Unique Serial Code`` of ``../x`` or ``/tmp/x``, a study field holding a newline, a
serial of ``=HYPERLINK(...)``. Two rules keep such text where it belongs:

- ``safe_name_part(text)``: the only way a metadata value becomes part of a file name. The result
  is one path component: only ``A-Z a-z 0-9 . _ -``, no ``..``, no leading ``.`` or ``-``, never
  empty, at most ``MAX_NAME_PART`` characters. Text that had to change gets a short hash of the
  original appended, so two different values never share a name (``a/b`` and ``a_b`` differ).
  Clean text (``10001``, ``AX3-39434``) is returned unchanged.
- ``safe_child(folder, part)``: ``folder / part`` after checking that it is a direct child of
  ``folder`` (a second guard at the place a path is built).
- ``csv_cell(value)``: the only way a value reaches a CSV cell of a table we write. Text that a
  spreadsheet would read as a formula (first character ``= + - @``, tab or carriage return) is
  prefixed with ``'``; numbers, and text that is a plain number (``-12.5``) or a UTC offset
  (``+01:00``), are left alone.
"""

from __future__ import annotations

import hashlib
import math
import re
from pathlib import Path

MAX_NAME_PART = 64  # characters; a name part is one piece of a longer file name
_HASH_CHARS = 8
_UNSAFE = re.compile(r"[^A-Za-z0-9._-]+")
_DOTS = re.compile(r"\.{2,}")
_FORMULA_START = ("=", "+", "-", "@", "\t", "\r")
# text that starts like a formula but is a plain number (-12.5, +3e-2) or a UTC offset (+01:00)
_PLAIN_VALUE = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?|[+-]\d{2}:?\d{2}")


def _digest(text: str) -> str:
    return hashlib.sha1(text.encode("utf-8", "surrogatepass")).hexdigest()[:_HASH_CHARS]


def safe_name_part(text, *, fallback: str = "unknown", max_len: int = MAX_NAME_PART) -> str:
    """One file-name component made from ``text`` (any value; ``None`` and empty text give
    ``fallback``). See the module docstring for the rules."""
    raw = "" if text is None else str(text)
    s = _UNSAFE.sub("_", raw)
    s = _DOTS.sub(".", s).strip("._-")
    if s == raw and s and len(s) <= max_len:
        return s
    if not raw:
        return fallback
    tag = "-" + _digest(raw)
    return ((s or fallback)[: max_len - len(tag)].rstrip("._-") or fallback) + tag


def safe_child(folder, part: str) -> Path:
    """``folder / part`` when ``part`` is a plain file name (one component, not ``.``/``..``);
    ``ValueError`` otherwise."""
    if not part or part in (".", "..") or "/" in part or "\\" in part or "\0" in part:
        raise ValueError(f"{part!r} is not a plain file name")
    folder = Path(folder)
    child = folder / part
    if child.parent != folder:
        raise ValueError(f"{part!r} is not a plain file name")
    return child


def csv_cell(value):
    """A value ready for ``csv.writer``: formula-like text neutralised, everything else as is."""
    if isinstance(value, str) and value.startswith(_FORMULA_START) \
            and not _PLAIN_VALUE.fullmatch(value):
        return "'" + value
    return value


def cell_text(v, decimals: int = 4) -> str:
    """A table cell's text: empty for None and non-finite floats, floats to ``decimals``
    decimals without trailing zeros, anything else as ``str``."""
    if v is None:
        return ""
    if isinstance(v, float):
        return "" if not math.isfinite(v) else f"{v:.{decimals}f}".rstrip("0").rstrip(".")
    return str(v)


# the file-name endings of the inputs we read (a trailing .gz first): ``recording_stem``
RECORDING_SUFFIXES = (".cwa", ".bin", ".gt3x", ".mcap")


def recording_stem(path) -> str:
    """A recording's file name without its format's ending, the default participant id:
    ``P04_tiny.cwa.gz`` -> ``P04_tiny``, ``week.bin`` -> ``week``, ``a.b.cwa`` -> ``a.b``; a
    name with another ending is kept whole (``notes.txt``, with only its ``.gz`` dropped)."""
    name = Path(path).name
    low = name.lower()
    if low.endswith(".gz") and len(name) > 3:
        name, low = name[:-3], low[:-3]
    for suffix in RECORDING_SUFFIXES:
        if low.endswith(suffix) and len(name) > len(suffix):
            return name[:-len(suffix)]
    return name
