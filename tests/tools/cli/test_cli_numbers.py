"""Every number on the command line is checked when it is parsed, before any work: finite, in
range, one line on stderr (``stillpoint CMD: error: argument --opt: ...``), exit code 2.

The options are found by walking the parser itself, so an option added later is covered (and an
option parsed with a bare ``int``/``float``, or a number left as text, fails the first test)."""

from __future__ import annotations

import argparse
import math
import subprocess
import sys
from pathlib import Path

import pytest

from stillpoint.tools.cli import build_parser, main

ALWAYS_BAD = ["nan", "NaN", "-nan", "inf", "-inf", "Infinity", "1e308", "-1e308", "1e999", "",
              "x", "0x10", "1,5"]


def _walk(parser, path=()):
    """(command words, action) for every action of every (sub)command parser."""
    for a in parser._actions:
        if isinstance(a, argparse._SubParsersAction):
            for name, sub in a.choices.items():
                yield from _walk(sub, path + (name,))
        elif not isinstance(a, argparse._HelpAction):
            yield path, a


ACTIONS = list(_walk(build_parser()))
NUMERIC = [(path, a) for path, a in ACTIONS if hasattr(a.type, "lo")]


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def test_every_number_option_uses_a_checked_type():
    unchecked = []
    for path, a in ACTIONS:
        takes_value = a.nargs != 0
        if not takes_value:
            continue
        if a.type in (int, float) or (a.type is None and _is_number(a.default)) or \
                (_is_number(a.default) and not hasattr(a.type, "lo")):
            unchecked.append(f"{' '.join(path)} {a.option_strings or a.dest}")
    assert not unchecked, "number options without a checked type (tools/cli/commands/_numbers.py): " \
                          + ", ".join(unchecked)
    assert len(NUMERIC) >= 50  # the walk found the options (every command's numbers)


def _outside(t) -> list[str]:
    """Values just outside a type's range, and the wrong kind of number."""
    lo, hi = t.lo, t.hi
    vals = [repr(hi * 2 + 1), repr(-(abs(lo) + 1) * 1000)]
    if t.lo_open:
        vals.append(repr(lo))
    elif t.integer:
        vals.append(repr(lo - 1))
    else:
        vals.append(repr(lo / 2 if lo > 0 else lo - max(abs(lo), 1) * 1e-3))
    if lo > 0:
        vals.append("1e-300")  # a tiny positive number where the range starts above 0
    if t.integer:
        vals += ["1.5", "1e3"]
    return vals


def _bad_values(t) -> list[str]:
    vals = ALWAYS_BAD + _outside(t)
    sep = getattr(t, "separator", None)
    if sep:  # lists and pairs: a bad item among good ones
        good = str(t.hi)
        vals = [v for v in vals if sep not in v] + [f"{good}{sep}nan", f"nan{sep}{good}",
                                                    f"{good}{sep}{good}{sep}inf", sep]
    return vals


def _name(a) -> str:
    return max(a.option_strings, key=len) if a.option_strings else a.dest


CASES = [pytest.param(path, _name(a), bad, id=f"{'-'.join(path)}{_name(a)}={bad}")
         for path, a in NUMERIC for bad in _bad_values(a.type)]


@pytest.mark.parametrize("path, option, bad", CASES)
def test_a_bad_number_is_one_line_and_exit_2_before_any_work(path, option, bad, capsys, monkeypatch):
    ran = []
    monkeypatch.setattr("stillpoint.tools.cli._input_files", lambda args: ran.append(args) or [])
    assert option.startswith("-"), "a numeric positional argument needs its own case here"
    rc = main([*path, f"{option}={bad}"])
    out, err = capsys.readouterr()
    lines = err.strip().splitlines()
    assert rc == 2 and not ran, (rc, err)
    assert len(lines) == 1 and out == "", err
    assert lines[0].startswith(f"stillpoint {' '.join(path)}: error: argument "), err
    assert option in lines[0].split(":")[2], err
    assert "Traceback" not in err and "usage:" not in err


@pytest.mark.parametrize("path, a", [pytest.param(p, a, id=f"{'-'.join(p)}{a.option_strings}")
                                     for p, a in NUMERIC])
def test_the_range_ends_are_accepted(path, a):
    t = a.type
    ends = [t.hi] + ([] if t.lo_open else [t.lo]) + ([0] if getattr(t, "or_zero", False) else [])
    for v in ends:
        text = str(int(v)) if t.integer else repr(float(v))
        if getattr(t, "separator", None) == ",":
            text = str(v)
            assert t(text) == (v,)
        elif getattr(t, "separator", None):
            assert t(f"{text}{t.separator}{text}") == (v, v)
        else:
            got = t(text)
            assert got == v and math.isfinite(got)


def test_the_reported_hangs_end_at_once(tmp_path):
    """The commands that hung (align --rate -1, cohort run --max-in-flight -1, device emulate
    --days inf) through the installed entry point: exit 2 within seconds, one line."""
    rec = tmp_path / "r.cwa"
    rec.write_bytes(b"MD")  # never read: the command line is refused first
    for argv in (["align", str(rec), str(rec), "--rate", "-1"],
                 ["cohort", "run", str(rec), "-o", str(tmp_path / "co"), "--max-in-flight", "-1",
                  "--scheduler", "serial"],
                 ["device", "emulate", "--days", "inf", "--dir", str(tmp_path / "emu")]):
        r = subprocess.run([sys.executable, "-m", "stillpoint", *argv], capture_output=True,
                           text=True, timeout=60)
        assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
        assert "Traceback" not in r.stderr
    assert not (tmp_path / "co").exists() and not (tmp_path / "emu").exists()


def test_other_argument_errors_are_one_line_too(capsys):
    assert main(["align", "only-one.cwa"]) == 2
    err = capsys.readouterr().err
    assert err.strip() == "stillpoint align: error: the following arguments are required: other"
    assert main(["inspect", "x.cwa", "--no-such-option"]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1
    assert main(["align", "--help"]) == 0 and "usage:" in capsys.readouterr().out


def test_align_rate_native_and_numbers(capsys):
    from stillpoint.tools.cli.commands import align
    p = argparse.ArgumentParser()
    align.add_arguments(p)
    assert p.parse_args(["a", "b"]).rate == 30.0
    assert p.parse_args(["a", "b", "--rate", "Native"]).rate == "native"
    assert p.parse_args(["a", "b", "--rate", "20.5"]).rate == 20.5


def _small_cwa(tmp_path) -> Path:
    from stillpoint.engine.sim.record import simulate_recording
    rec = tmp_path / "small.cwa"
    simulate_recording(rec, device="ax3", days=0.002, truth_path=False)
    return rec


def test_export_topic_is_refused_for_a_recording(tmp_path, capsys):
    rec = _small_cwa(tmp_path)
    out = tmp_path / "x.csv"
    assert main(["export", str(rec), "-o", str(out), "--topic", "/raw/accel"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--topic" in err[0] and str(rec) in err[0]
    assert not out.exists() and not (tmp_path / "x.csv.part").exists()
    assert main(["export", str(rec), "-o", str(out)]) == 0 and out.stat().st_size > 0


@pytest.mark.parametrize("effect", ["corrupt_sectors:indices=x", "corrupt_sectors:indices=1;nan",
                                    "corrupt_sectors:count=nan", "corrupt_sectors:count=1e300",
                                    "corrupt_sectors:count=-1", "halts:count=2.5",
                                    "offset:x=nan", "offset:x=1e400"])
def test_numbers_inside_effect_options_are_one_line(effect, tmp_path, capsys):
    out = tmp_path / "x.cwa"
    assert main(["simulate", "-o", str(out), "--days", "0.01", "--effect", effect]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("stillpoint simulate: error: ") and "effect" in err[0]
    assert not out.exists()


@pytest.mark.parametrize("action", [("cohort", "run", "r.cwa", "-o", "co"), ("cohort", "retry", "co",
                                                                            "--class", "all")])
@pytest.mark.parametrize("bad", ["nan", "inf", "-1", "0", "1e300", "4XB", ""])
def test_memory_limit_is_checked_when_parsed(action, bad, capsys):
    assert main([*action, f"--memory-limit={bad}"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "argument --memory-limit" in err[0], err


@pytest.mark.parametrize("bad", ["1e308/2", "2/2", "-1/2", "1/0", "0/9999999", "a/b", "1", "1/2/3",
                                 "99999999999999999999999/999999999999999999999999", "²/3"])
def test_shard_is_checked_when_parsed(bad, capsys):
    assert main(["cohort", "run", "r.cwa", "-o", "co", f"--shard={bad}"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "argument --shard" in err[0], err


def test_memory_limit_values():
    from stillpoint.tools.cli.commands._numbers import memory_size
    assert memory_size("auto") == "auto" and memory_size("0.5") == 0.5
    assert memory_size("4GB") == 4 * 10**9 and memory_size("500 MiB") == 500 * 2**20


@pytest.mark.parametrize("extra", [["--order", "+x,-x"], ["--hold-s", "5"], ["--minutes", "3"],
                                   ["--sleep", "1:1"], ["--controls"], ["--skew-ppm", "5"],
                                   ["--device-id", "7"], ["--cross-axis", "0.01"],
                                   ["--sensor-errors", "none"], ["--pair-hz", "50"],
                                   ["--pair-effect", "noise"], ["--pair-output", "b.cwa"],
                                   ["--pair-device", "ax6"]])
def test_simulate_refuses_an_option_the_run_would_ignore(extra, tmp_path, capsys):
    out = tmp_path / "x.cwa"
    assert main(["simulate", "-o", str(out), "--days", "0.01", *extra]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and extra[0] in err[0] and "ignored" in err[0], err
    assert not out.exists()


def test_calibrate_store_dir_without_store_is_refused(tmp_path, capsys):
    assert main(["calibrate", str(tmp_path / "r.cwa"), "--store-dir", str(tmp_path / "st")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--store-dir" in err[0] and "--store" in err[0]
    assert not (tmp_path / "st").exists()


def test_align_rate_must_be_above_twice_the_band_edge(tmp_path, capsys):
    """The activity band-pass ends at 7 Hz: a common rate of 14 Hz or less (a number, or the
    native rate of a 12.5 Hz reference) is one line, not scipy's ValueError traceback."""
    from stillpoint.engine.alignment.signal import BAND_HZ
    from stillpoint.engine.sim.record import simulate_recording
    from stillpoint.tools.cli.commands.align import MIN_COMMON_RATE_HZ
    assert MIN_COMMON_RATE_HZ == 2 * BAND_HZ[1]
    rec = tmp_path / "slow.cwa"
    simulate_recording(rec, device="ax3", hz=12.5, days=0.002, truth_path=False)
    for rate in ("native", "14", "1"):
        assert main(["align", str(rec), str(rec), "--rate", rate]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "Traceback" not in err[0] and "14" in err[0], err


@pytest.mark.parametrize("scenario", ["sixface", "infant"])
def test_a_scenario_rate_the_writer_refuses_is_one_line(scenario, tmp_path, capsys):
    out = tmp_path / "s.cwa"
    assert main(["simulate", "-o", str(out), "--device", "ax6", "--scenario", scenario,
                 "--hz", "5000", "--minutes" if scenario == "infant" else "--hold-s", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "3200/2^k" in err[0] and str(out) in err[0], err
    assert not out.exists()


def test_emulated_ids_fit_the_drive_label(capsys, tmp_path):
    """--first-id plus --count stays within what an emulated drive label can hold (checked
    before any device is made)."""
    assert main(["device", "emulate", "--count", "2", "--first-id", "9999999",
                 "--dir", str(tmp_path / "emu")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "9999999" in err[0]
    assert not (tmp_path / "emu").exists()
