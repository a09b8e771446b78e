"""The one time module (engine/core/times.py): ISO instants, UTC offsets as text and back, and the
one declaration of --timezone/--timezone-override for every command."""

from __future__ import annotations

import argparse
import datetime as dt

import numpy as np
import pytest

from stillpoint.engine.core.times import (iso_local, iso_text, iso_texts, iso_utc, offset_text,
                                          offset_texts, parse_offset)

SPRING = 1743296400 * 10**9  # 2025-03-30T01:00:00Z, Europe/London moves to +01:00


def test_iso_instants_truncate_to_the_unit():
    t = SPRING - 1  # one nanosecond before the change
    assert iso_utc(t) == "2025-03-30T00:59:59Z"
    assert iso_utc(t, "ms") == "2025-03-30T00:59:59.999Z"
    assert iso_utc(t, "ns") == "2025-03-30T00:59:59.999999999Z"
    assert iso_text(SPRING, "us") == "2025-03-30T01:00:00.000000"
    assert iso_local(SPRING, 3600) == "2025-03-30T02:00:00+01:00"
    assert iso_local(SPRING, -16200, "ms") == "2025-03-29T20:30:00.000-04:30"


def test_iso_matches_the_standard_library():
    rng = np.random.default_rng(5)
    for t in rng.integers(0, 4_000_000_000, 200).tolist():
        ref = dt.datetime.fromtimestamp(t, tz=dt.timezone.utc).isoformat().replace("+00:00", "Z")
        assert iso_utc(t * 10**9) == ref


def test_array_forms_equal_the_scalar_forms():
    t = np.array([SPRING - 10**9, SPRING, SPRING + 1234567], np.int64)
    assert iso_texts(t, "ms").tolist() == [iso_text(int(x), "ms") for x in t]
    off = np.array([0, 3600, -16200, 3600])
    assert offset_texts(off).tolist() == ["+00:00", "+01:00", "-04:30", "+01:00"]


@pytest.mark.parametrize("seconds,text", [(0, "+00:00"), (3600, "+01:00"), (-16200, "-04:30"),
                                          (19800, "+05:30"), (50400, "+14:00"), (-43200, "-12:00")])
def test_offset_text_round_trips(seconds, text):
    assert offset_text(seconds) == text
    assert parse_offset(text) == seconds


@pytest.mark.parametrize("text,seconds", [("GMT +01:00", 3600), ("-0530", -19800), ("+1", 3600),
                                          ("UTC", 0), ("z", 0), ("GMT", 0), ("utc+02:00", 7200),
                                          ("  +01:00 ", 3600)])
def test_offset_parser_reads_what_devices_write(text, seconds):
    assert parse_offset(text) == seconds


@pytest.mark.parametrize("text", ["", "+15:00", "+01:60", "Europe/London", "1h", "+01:00:00"])
def test_offset_parser_refuses(text):
    with pytest.raises(ValueError):
        parse_offset(text)


def test_every_command_declares_the_zone_options_once_with_one_help():
    from stillpoint.tools.cli import build_parser

    parser = build_parser()
    helps, commands = {}, set()
    subs = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    for name, sub in subs.choices.items():
        for action in sub._actions:
            if isinstance(action, argparse._SubParsersAction):  # cohort run, ...
                for inner in action.choices.values():
                    for a in inner._actions:
                        if a.option_strings and a.option_strings[0].startswith("--timezone"):
                            helps.setdefault(a.option_strings[0], set()).add(a.help)
                            commands.add(name)
            elif action.option_strings and action.option_strings[0].startswith("--timezone"):
                helps.setdefault(action.option_strings[0], set()).add(action.help)
                commands.add(name)
    assert {"process", "export", "inspect", "cohort"} <= commands, commands
    assert set(helps) == {"--timezone", "--timezone-override"}
    assert all(len(h) == 1 for h in helps.values()), helps
