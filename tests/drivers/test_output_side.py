"""Output side of every command: a destination that cannot be written is one line and exit 2
before the work starts; a failed run leaves nothing that looks complete and never destroys a
previous complete output; multi-file commands report a bad file and go on."""

from __future__ import annotations

import errno
import json
import subprocess
import sys
from pathlib import Path

import pytest

from stillpoint.engine.core.outputs import OutputError

FUZZ = Path(__file__).parents[1] / "data" / "fuzz"
GOOD = FUZZ / "ax3_unpacked_40_sectors.cwa"


def cli(*args):
    r = subprocess.run([sys.executable, "-m", "tools", *map(str, args)], capture_output=True,
                       text=True, timeout=300)
    return r.returncode, r.stdout, r.stderr


def one_line(rc, err, *needles):
    assert rc == 2, err
    assert "Traceback" not in err
    lines = [ln for ln in err.strip().splitlines() if ln]
    assert len(lines) == 1, err
    for n in needles:
        assert n in lines[0], err


@pytest.fixture(scope="module")
def mcap(tmp_path_factory):
    out = tmp_path_factory.mktemp("m") / "r.mcap"
    rc, _, err = cli("process", GOOD, "-o", out, "-q")
    assert rc == 0, err
    return out


@pytest.mark.parametrize("make", ["missing", "file_in_way"])
@pytest.mark.parametrize("cmd", ["export", "export_mcap", "summary", "process", "discrepancy",
                                 "recover", "calibrate_plot", "align_json", "simulate",
                                 "calibration_export"])
def test_unwritable_destination_is_one_line_before_work(tmp_path, mcap, make, cmd):
    base = tmp_path / "nope" if make == "missing" else tmp_path / "afile"
    if make == "file_in_way":
        base.write_text("x")
    dest = base / "out"
    args = {
        "export": ["export", GOOD, "-o", f"{dest}.csv"],
        "export_mcap": ["export", mcap, "-o", f"{dest}.csv", "--topic", "/metrics/epoch"],
        "summary": ["process", GOOD, "-o", tmp_path / "ok.mcap", "--summary", f"{dest}.json", "-q"],
        "process": ["process", GOOD, "-o", f"{dest}.mcap", "-q"],
        "discrepancy": ["discrepancy", GOOD, "-o", dest],
        "recover": ["recover", mcap, "-o", f"{dest}.mcap"],
        "calibrate_plot": ["calibrate", GOOD, "--plot", f"{dest}.png"],
        "align_json": ["align", GOOD, GOOD, "--json-out", f"{dest}.json"],
        "simulate": ["simulate", "-o", f"{dest}.cwa", "--days", "0.01"],
        "calibration_export": ["calibration", "--store-dir", tmp_path / "st", "export", "-o", f"{dest}.json"],
    }[cmd]
    rc, out, err = cli(*args)
    one_line(rc, err)
    if cmd == "discrepancy" and make == "missing":  # a missing report folder is created
        assert base.is_dir()
        return
    assert str(base) in err
    if cmd == "summary":  # checked before the work: the MCAP was never started
        assert not (tmp_path / "ok.mcap").exists()


def test_simulate_full_disk_leaves_nothing_that_looks_complete(tmp_path, monkeypatch):
    from stillpoint.drivers import cwa_writer
    from stillpoint.engine.sim.record import simulate_recording
    real = cwa_writer.CwaWriter.write
    calls = {"n": 0}

    def full(self, *a, **k):
        calls["n"] += 1
        if calls["n"] > 1:
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(self, *a, **k)

    monkeypatch.setattr(cwa_writer.CwaWriter, "write", full)
    out = tmp_path / "rec.cwa"
    with pytest.raises(OutputError, match="no space left"):
        simulate_recording(out, days=0.1, hz=25)
    names = sorted(p.name for p in tmp_path.iterdir())
    assert not any(n.endswith((".cwa", ".json", ".csv")) for n in names), names
    assert any(n.endswith(".part") for n in names)


def test_simulate_outputs_complete_together(tmp_path):
    from stillpoint.engine.sim.record import simulate_recording
    t = simulate_recording(tmp_path / "r.cwa", days=0.01, hz=25)
    assert (tmp_path / "r.cwa").exists() and Path(t.truth_path).exists() and Path(t.labels_path).exists()
    assert not list(tmp_path.glob("*.part"))


def test_export_never_destroys_previous_output_on_failure(tmp_path):
    out = tmp_path / "e.csv"
    out.write_text("previous complete export\n")
    rc, _, err = cli("export", FUZZ / "ax3_corrupt_deflate.cwa.gz", "-o", out)
    one_line(rc, err)
    assert out.read_text() == "previous complete export\n"


def test_align_summary_with_a_sampling_gap():
    from stillpoint.tools.cli.commands.align import _summary
    d = {"aligned": True, "model": "linear", "method": "xcorr", "initial_offset_s": 0.1,
         "drift_s_per_day": 0.2, "drift_day7_s": 1.4, "blocks_used": 3, "blocks_valid": 3,
         "blocks_total": 3, "blocks_excluded": 0, "rmse_samples": 0.5, "rate_hz": 25,
         "steps": [{"kind": "gap", "device": "other", "time_s": 3600.0, "time_ns": 1,
                    "window_s": [3600.0, 3720.0], "duration_s": 120.0},
                   {"kind": "lag_step", "size_s": 0.5, "time_s": 7200.0, "window_s": [7000.0, 7300.0]}]}
    text = _summary(d)
    assert "sampling gap     120.000 s on the other device at 1.00 h" in text
    assert "step             +0.500 s" in text


def test_inspect_many_files_one_bad(tmp_path):
    rc, out, err = cli("inspect", GOOD, FUZZ / "geneactiv_gain_inf.bin", FUZZ / "ax3_truncated.cwa.gz")
    assert rc == 2 and "Traceback" not in err
    assert "geneactiv_gain_inf.bin" in err
    assert out.count("samples") >= 2  # the two good files were still inspected


@pytest.mark.parametrize("jobs", ["1", "2"])
def test_calibrate_many_files_one_bad(tmp_path, jobs):
    rc, out, err = cli("calibrate", "-j", jobs, "--json", GOOD, FUZZ / "geneactiv_rate_inf.bin",
                       FUZZ / "ax3_truncated.cwa.gz")
    assert rc == 2 and "Traceback" not in err
    rows = [json.loads(ln) for ln in out.strip().splitlines()]
    assert [r["status"] == "error" for r in rows] == [False, True, False]


@pytest.mark.parametrize("opt", [["--epoch-s", "1e12"], ["--epoch-s", "nan"], ["--first-hours", "inf"],
                                 ["--sd-threshold-mg", "-1"], ["--flush-every-s", "1e308"]])
def test_absurd_options_refused_at_parse_time(tmp_path, opt):
    rc, out, err = cli("process", GOOD, "-o", tmp_path / "o.mcap", *opt)
    assert rc == 2 and "Traceback" not in err and opt[0] in err
    assert not (tmp_path / "o.mcap").exists()


def test_interrupt_message_names_the_partial_log_and_recover(tmp_path):
    from argparse import Namespace

    from stillpoint.tools.cli import _interrupt_note
    out = tmp_path / "r.mcap"
    args = Namespace(command="process", output=out, file=GOOD)
    assert "no partial log" in _interrupt_note(args) and "pass" in _interrupt_note(args)
    part = tmp_path / "r.mcap.part"
    part.write_bytes(b"\x89MCAP0\r\n" + b"\x00" * 100)  # an unfinished log
    note = _interrupt_note(args)
    assert str(part) in note and "stillpoint recover" in note


def test_non_utf8_file_names(tmp_path):
    """Names the file system allows but UTF-8 cannot spell (bytes 0xFF, 0xFE): every command
    works on them; the MCAP log shows U+FFFD in their place."""
    import os
    import shutil
    if sys.platform == "win32" or os.fsencode("x\udcff") != b"x\xff":
        pytest.skip("needs a POSIX file system with bytes file names (surrogateescape)")
    src = tmp_path / "in\udcff.cwa"
    shutil.copy(GOOD, src)
    out = tmp_path / "o\udcfe.mcap"
    for args in (["process", src, "-o", out, "--summary", tmp_path / "s\udcff.json", "-q"],
                 ["export", src, "-o", tmp_path / "e\udcff.csv"],
                 ["export", out, "-o", tmp_path / "e\udcff.npz", "--topic", "/corrected/accel"],
                 ["replay", out, "--check", "-o", tmp_path / "r\udcff.mcap", "-q"],
                 ["simulate", "-o", tmp_path / "sim\udcff.cwa", "--days", "0.005"]):
        r = subprocess.run([sys.executable, "-m", "tools", *map(str, args)], capture_output=True,
                           timeout=300)
        assert r.returncode == 0, r.stderr.decode("utf-8", "replace")
    assert (tmp_path / "s\udcff.json").exists() and (tmp_path / "sim\udcff.truth.json").exists()
