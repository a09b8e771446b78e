"""Numeric command-line options checked at parse time: finite and within a plausible range, so
``--epoch-s 1e12`` or ``--days nan`` is refused with a clear message before any work (argparse
exit code 2), never handed to the engine."""

from __future__ import annotations

import argparse
import math


def number(lo: float, hi: float, *, integer: bool = False, lo_open: bool = False, unit: str = ""):
    """An argparse ``type``: a finite number in [lo, hi] (or (lo, hi] with ``lo_open``)."""
    u = f" {unit}" if unit else ""
    span = f"{'(' if lo_open else '['}{lo:g}, {hi:g}]{u}"

    def parse(text: str):
        try:
            v = int(text) if integer else float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"{text!r} is not {'an integer' if integer else 'a number'}") from None
        if not math.isfinite(v):
            raise argparse.ArgumentTypeError(f"{text!r} is not a finite number")
        if v < lo or v > hi or (lo_open and v == lo):
            raise argparse.ArgumentTypeError(f"{text} is outside {span}")
        return v

    parse.__name__ = "integer" if integer else "number"
    return parse


HOURS = number(0, 8760, lo_open=True, unit="h")  # up to a year of data
MG = number(0, 1000, lo_open=True, unit="mg")
SECONDS_DAY = number(0, 86_400, lo_open=True, unit="s")
EPOCH_S = number(0.01, 86_400, unit="s")
RATE_HZ = number(1, 5000, unit="Hz")
SEED = number(0, 2**32 - 1, integer=True)
