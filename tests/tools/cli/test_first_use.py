"""What a new user meets first: a folder or a recording where a file or a log is expected, a log
named like a table, the progress line of a run that also writes its report."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from stillpoint.tools.cli import main

FUZZ = Path(__file__).parents[2] / "data" / "fuzz"
GOOD = FUZZ / "ax3_unpacked_40_sectors.cwa"


def _one_line(capsys) -> str:
    cap = capsys.readouterr()
    lines = cap.err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in cap.err, cap.err
    return lines[0]


def test_process_a_folder_is_one_line_pointing_at_cohort(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["process", "."]) == 2
    line = _one_line(capsys)
    assert "is a directory, not a recording" in line and "stillpoint cohort run ." in line, line


@pytest.mark.parametrize("command", ["view", "report", "replay", "recover"])
def test_a_recording_given_for_a_log_says_to_process_it(tmp_path, capsys, command):
    rec = tmp_path / "week.cwa"
    shutil.copy(GOOD, rec)
    assert main([command, str(rec)]) == 2
    line = _one_line(capsys)
    assert f"{rec}: is a recording (AX3/AX6 .cwa), not a stillpoint log" in line, line
    assert f"run `stillpoint process {rec}` first" in line, line
    assert "recover" not in line.split("first")[-1] and "not finished" not in line, line


@pytest.mark.parametrize("command", ["view", "replay", "recover"])
def test_a_file_that_is_no_mcap_is_named_so(tmp_path, capsys, command):
    txt = tmp_path / "notes.txt"
    txt.write_text("hello\n")
    assert main([command, str(txt)]) == 2
    line = _one_line(capsys)
    assert "not a stillpoint log" in line and "not finished" not in line, line


def test_a_log_named_like_a_table_is_refused_before_any_work(tmp_path, capsys):
    out = tmp_path / "x.csv"
    assert main(["process", str(GOOD), "-o", str(out)]) == 2
    line = _one_line(capsys)
    assert "-o" in line and "NAME.mcap" in line, line
    assert list(tmp_path.iterdir()) == []


def test_process_with_report_says_done_only_after_the_report(tmp_path, capsys, monkeypatch):
    pytest.importorskip("matplotlib", reason="the report draws with matplotlib")
    import stillpoint.engine.report as report
    seen = {}
    real = report.write_report

    def spy(*a, **kw):
        seen["err_before_report"] = capsys.readouterr().err
        return real(*a, **kw)

    monkeypatch.setattr(report, "write_report", spy)
    assert main(["process", str(GOOD), "-o", str(tmp_path / "a.mcap"), "--report"]) == 0
    assert "done in" not in seen["err_before_report"], seen["err_before_report"]
    assert "process: done in" in capsys.readouterr().err
