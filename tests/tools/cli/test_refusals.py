"""Refusals instead of surprises: an existing output is replaced only with --overwrite, a folder
given where a recording is expected is one line (exit 2), and an MCAP export names what it
wants (tests/engine/tables/test_tables.py covers --table/--topic)."""

from __future__ import annotations

from pathlib import Path

import pytest

from stillpoint.tools.cli import main

FUZZ = Path(__file__).parents[2] / "data" / "fuzz"
GOOD = FUZZ / "ax3_unpacked_40_sectors.cwa"


def _one_line(capsys, *needles) -> str:
    err = capsys.readouterr().err
    lines = [ln for ln in err.strip().splitlines() if ln]
    assert len(lines) == 1 and "Traceback" not in err, err
    for n in needles:
        assert n in lines[0], err
    return lines[0]


def test_simulate_does_not_replace_an_existing_recording(tmp_path, capsys):
    rec = tmp_path / "real.cwa"
    rec.write_bytes(GOOD.read_bytes())
    before = rec.read_bytes()
    assert main(["simulate", "-o", str(rec), "--days", "0.01", "--hz", "25"]) == 2
    _one_line(capsys, str(tmp_path), "already exists", "--overwrite")
    assert rec.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["real.cwa"]  # nothing else written
    assert main(["simulate", "-o", str(rec), "--days", "0.01", "--hz", "25", "--overwrite"]) == 0
    assert rec.read_bytes() != before


def test_process_export_report_recover_keep_existing_outputs(tmp_path, capsys):
    out = tmp_path / "a.mcap"
    assert main(["process", str(GOOD), "-o", str(out), "-q"]) == 0
    capsys.readouterr()
    stamp = {p.name: p.stat().st_mtime_ns for p in tmp_path.iterdir()}
    assert main(["process", str(GOOD), "-o", str(out), "-q"]) == 2
    _one_line(capsys, str(out), "already exists")
    csv = tmp_path / "e.csv"
    csv.write_text("mine\n")
    assert main(["export", str(GOOD), "-o", str(csv)]) == 2
    _one_line(capsys, str(csv), "already exists")
    assert csv.read_text() == "mine\n"
    assert main(["recover", str(out), "-o", str(csv)]) == 2
    _one_line(capsys, str(csv), "already exists")
    assert {p.name: p.stat().st_mtime_ns for p in tmp_path.iterdir() if p.name != "e.csv"} == stamp
    assert main(["process", str(GOOD), "-o", str(out), "-q", "--overwrite"]) == 0
    assert main(["export", str(GOOD), "-o", str(csv), "--overwrite"]) == 0
    assert csv.read_text().startswith("time_local,x,y,z")  # replaced


@pytest.mark.parametrize("command", ["process", "report", "recover", "inspect", "export"])
def test_a_folder_as_the_input_is_one_line(tmp_path, capsys, command):
    folder = tmp_path / "looks_like.cwa"
    folder.mkdir()
    args = [command, str(folder)] + (["-o", str(tmp_path / "o.csv")] if command == "export" else [])
    assert main(args) == 2
    _one_line(capsys, str(folder), "directory")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["looks_like.cwa"]


@pytest.mark.parametrize("argv, existing", [
    (["calibrate", str(GOOD), "--plot", "{d}/e.png"], "e.png"),
    (["calibration", "--store-dir", "{d}/store", "export", "-o", "{d}/e.json"], "e.json"),
    (["align", str(GOOD), str(GOOD), "-o", "{d}/e.mcap"], "e.mcap"),
    (["align", str(GOOD), str(GOOD), "--plot", "{d}/e.png"], "e.png"),
    (["movements", str(GOOD), "-o", "{d}/e.csv"], "e.csv"),
    (["static-calibrate", str(GOOD), "-o", "{d}/e.json"], "e.json"),
    (["discrepancy", str(GOOD), "-o", "{d}/rep"], "rep/report.json"),
])
def test_every_writing_command_keeps_an_existing_output(tmp_path, capsys, argv, existing):
    target = tmp_path / existing
    target.parent.mkdir(exist_ok=True)
    target.write_text("mine\n")
    argv = [a.format(d=tmp_path) for a in argv]
    assert main(argv) == 2
    _one_line(capsys, existing, "already exists", "--overwrite")
    assert target.read_text() == "mine\n"


def test_calibration_export_and_calibrate_plot_replace_with_overwrite(tmp_path, capsys):
    pytest.importorskip("matplotlib", reason="calibrate --plot draws with matplotlib")
    out = tmp_path / "e.json"
    out.write_text("mine\n")
    assert main(["calibration", "--store-dir", str(tmp_path / "store"), "export", "-o", str(out),
                 "--overwrite"]) == 0
    assert out.read_text() != "mine\n"
    png = tmp_path / "e.png"
    png.write_text("mine\n")
    main(["calibrate", str(GOOD), "--plot", str(png), "--overwrite"])
    assert png.read_bytes()[:4] == b"\x89PNG"
