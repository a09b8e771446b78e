"""Numeric command-line options checked at parse time: finite and within a plausible range, so
``--epoch-s 1e12`` or ``--days nan`` is refused with one line (``stillpoint CMD: error:
argument --days: ...``, exit code 2) before any work, never handed to the engine.

Every number a command line takes is parsed by a type made here (``number``, ``number_or``,
``number_list``, ``number_pair``); ``tests/tools/cli/test_cli_numbers.py`` walks the whole parser and
fails for an option parsed with a bare ``int``/``float``/no type, and tries every bad value
against every option. Each type carries its bounds (``lo``, ``hi``, ``integer``, ``lo_open``)
so that test can compute the values just outside them."""

from __future__ import annotations

import argparse
import math


def number(lo: float, hi: float, *, integer: bool = False, lo_open: bool = False, unit: str = "",
           or_zero: bool = False):
    """An argparse ``type``: a finite number in [lo, hi] (or (lo, hi] with ``lo_open``), or
    exactly 0 with ``or_zero`` (an option whose 0 means "off")."""
    u = f" {unit}" if unit else ""
    shown = (lambda v: f"{v:d}") if integer else (lambda v: f"{v:g}")
    span = f"{'(' if lo_open else '['}{shown(lo)}, {shown(hi)}]{u}"

    def parse(text: str):
        try:
            v = int(text) if integer else float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"{text!r} is not {'an integer' if integer else 'a number'}") from None
        if not math.isfinite(v):
            raise argparse.ArgumentTypeError(f"{text!r} is not a finite number")
        if or_zero and v == 0:
            return v
        if v < lo or v > hi or (lo_open and v == lo):
            raise argparse.ArgumentTypeError(f"{text} is outside {span}{' (or 0)' if or_zero else ''}")
        return v

    parse.__name__ = "integer" if integer else "number"
    parse.lo, parse.hi, parse.integer, parse.lo_open, parse.unit = lo, hi, integer, lo_open, unit
    parse.or_zero = or_zero
    return parse


def number_or(word: str, num):
    """An argparse ``type``: the word ``word`` (any case; returned as given in lower case) or a
    number checked by ``num`` (a ``number(...)`` type)."""

    def parse(text: str):
        if text.strip().lower() == word:
            return word
        try:
            return num(text)
        except argparse.ArgumentTypeError as e:
            raise argparse.ArgumentTypeError(f"{e} (or '{word}')") from None

    parse.__name__ = num.__name__
    parse.lo, parse.hi, parse.integer, parse.lo_open = num.lo, num.hi, num.integer, num.lo_open
    parse.unit, parse.word = num.unit, word
    return parse


def number_list(num, *, increasing: bool = False, what: str = "numbers"):
    """An argparse ``type``: comma-separated numbers, each checked by ``num``; a tuple."""

    def parse(text: str):
        items = [x.strip() for x in str(text).split(",") if x.strip()]
        if not items:
            raise argparse.ArgumentTypeError(f"{text!r}: give {what}, e.g. 40,100,400")
        vals = tuple(num(x) for x in items)
        if increasing and any(b <= a for a, b in zip(vals, vals[1:])):
            raise argparse.ArgumentTypeError(f"{text!r}: the values must increase")
        return vals

    parse.__name__ = "list"
    parse.lo, parse.hi, parse.integer, parse.lo_open, parse.unit = (
        num.lo, num.hi, num.integer, num.lo_open, num.unit)
    parse.separator = ","
    return parse


def number_pair(num, *, separator: str = ":", form: str = "A:B"):
    """An argparse ``type``: two numbers ``A<separator>B``, each checked by ``num``; a tuple."""

    def parse(text: str):
        parts = str(text).split(separator)
        if len(parts) != 2:
            raise argparse.ArgumentTypeError(f"{text!r}: expected {form}")
        return num(parts[0]), num(parts[1])

    parse.__name__ = "pair"
    parse.lo, parse.hi, parse.integer, parse.lo_open, parse.unit = (
        num.lo, num.hi, num.integer, num.lo_open, num.unit)
    parse.separator = separator
    return parse


_BYTE_UNITS = {"": 1, "b": 1, "kb": 10**3, "mb": 10**6, "gb": 10**9, "tb": 10**12,
               "kib": 2**10, "mib": 2**20, "gib": 2**30, "tib": 2**40}


def memory_size(text: str):
    """An argparse ``type`` for a memory limit: ``auto``, a fraction of the machine's memory
    (a number in (0, 1]), or a size (``4GB``, ``500 MiB``, ``4e9`` bytes) up to 1 PB. Returns
    ``"auto"``, the fraction (float) or the number of bytes (int)."""
    import re
    t = str(text).strip().lower()
    if t == "auto":
        return "auto"
    m = re.fullmatch(r"([0-9.eE+-]+)\s*([a-z]*)", t)
    try:
        v = float(m.group(1)) if m else float("nan")
    except ValueError:
        v = float("nan")
    unit = m.group(2) if m else ""
    if not math.isfinite(v) or unit not in _BYTE_UNITS:
        raise argparse.ArgumentTypeError(f"{text!r} is not a memory size (auto, 0.5, 4GB, 500MiB)")
    if not unit and 0 < v <= 1:
        return v
    n = v * _BYTE_UNITS[unit]
    if not 1 < n <= 10**15:
        raise argparse.ArgumentTypeError(f"{text!r} is outside (1 byte, 1 PB] (or a fraction in "
                                         "(0, 1] of the memory)")
    return int(n)


MAX_SHARDS = 1_000_000


def shard(text: str) -> str:
    """An argparse ``type`` for ``--shard K/N``: whole numbers, 0 <= K < N <= MAX_SHARDS.
    Returns the text (the cohort parses it again)."""
    parts = str(text).split("/")
    ok = len(parts) == 2 and all(p.strip().isascii() and p.strip().isdigit() and len(p.strip()) <= 7
                                 for p in parts)
    if not ok:
        raise argparse.ArgumentTypeError(f"{text!r}: expected K/N with whole numbers, e.g. 0/4")
    k, n = (int(p) for p in parts)
    if not (1 <= n <= MAX_SHARDS and 0 <= k < n):
        raise argparse.ArgumentTypeError(f"{text}: need 0 <= K < N <= {MAX_SHARDS}")
    return text


def setting(key: str):
    """An argparse ``type`` for the run setting ``key``, with its bounds from
    ``engine.settings.BOUNDS`` (the one place they are kept; a logged settings record is checked
    against the same)."""
    from stillpoint.engine.settings import BOUNDS
    lo, hi, unit = BOUNDS[key]
    return number(lo, hi, integer=key == "chunk_size", unit=unit, or_zero=key == "view_hz")


HOURS = number(0, 8760, lo_open=True, unit="h")  # up to a year of data
MG = number(0, 1000, lo_open=True, unit="mg")
SECONDS_DAY = number(0, 86_400, lo_open=True, unit="s")
EPOCH_S = number(0.01, 86_400, unit="s")
RATE_HZ = number(1, 5000, unit="Hz")
SEED = number(0, 2**32 - 1, integer=True)
DAYS = number(0, 366, lo_open=True, unit="days")  # a simulated or emulated recording's length
DEVICE_ID = number(0, 2**32 - 1, integer=True)  # the .cwa header holds a 32-bit id (cwa_layout)
# an emulated device's id: its drive label holds at most 7 digits (drivers/ax/emulator.py
# volume_label: AX317_<5 digits>, or AX3_<7 digits> for longer ids)
EMULATED_ID = number(1, 9_999_999, integer=True)
WORKERS = number(1, 1024, integer=True)
MB_PER_S = number(0.01, 10_000, unit="MB/s")  # 0.01: a 4 MB download in under 7 minutes
SECONDS_YEAR = number(0, 366 * 86_400, lo_open=True, unit="s")
PORT = number(0, 65_535, integer=True)  # a TCP port; 0: any free port
PLAYBACK_SPEED = number(0, 1e6, lo_open=True, unit="x")  # times real time
