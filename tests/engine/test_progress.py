"""Progress of long commands: percentage and ETA from the input size on a terminal, a plain line
every tenth (or 30 s) otherwise, nothing with -q; the cohort's ETA by bytes (engine/progress.py).
A fake clock and captured streams: nothing here depends on timing."""

from __future__ import annotations

import io
import re
from pathlib import Path

from stillpoint.engine.progress import Progress, hms, run_fraction
from stillpoint.tools.cli import main

FUZZ = Path(__file__).parents[1] / "data" / "fuzz"
GOOD = FUZZ / "ax3_unpacked_40_sectors.cwa"


class Clock:
    def __init__(self):
        self.t = 100.0

    def __call__(self):
        return self.t


def _bar(tty=False, **kw):
    out, clock = io.StringIO(), Clock()
    return Progress("job", stream=out, tty=tty, clock=clock, **kw), out, clock


def test_plain_lines_every_tenth_with_eta_and_a_closing_line():
    p, out, clock = _bar(total=1000)
    for done in range(0, 1001, 10):  # a hundred updates, one second apart
        clock.t += 1.0
        p.update(done)
    p.close()
    lines = out.getvalue().splitlines()
    assert len(lines) == 11, lines  # 10 %, 20 %, ... 100 %, then "done in"
    assert lines[0].startswith("job:  10.0 %") and "elapsed 0m11s" in lines[0]
    # ETA = elapsed * (1 - f) / f: 11 s for 10 % -> 99 s left
    assert "ETA 1m39s" in lines[0]
    assert lines[4].startswith("job:  50.0 %") and "ETA 0m51s" in lines[4]
    assert lines[-1] == "job: done in 1m41s"
    assert "\r" not in out.getvalue()


def test_plain_line_every_30_s_when_progress_is_slow():
    p, out, clock = _bar(total=100)
    for _ in range(7):
        clock.t += 10.0
        p.update(1)  # 1 %: no tenth crossed
    lines = out.getvalue().splitlines()
    assert len(lines) == 2 and all("1.0 %" in ln for ln in lines)  # at 30 s and 60 s


def test_terminal_bar_redrawn_in_place_at_most_five_times_a_second():
    p, out, clock = _bar(tty=True, total=200)
    clock.t += 10.0
    p.update(50)
    p.update(60)  # same instant: not redrawn
    text = out.getvalue()
    assert text.count("\r") == 1
    assert re.search(r"\[#{7}\.{23}\]  25\.0 %  elapsed 0m10s  ETA 0m30s", text), text
    p.close()
    assert out.getvalue().endswith("\r\033[K")  # the bar is cleared, no line left behind


def test_quiet_writes_nothing():
    p, out, clock = _bar(total=10, quiet=True)
    for i in range(11):
        clock.t += 40
        p.update(i)
    p.message("a warning")
    p.close()
    assert out.getvalue() == ""


def test_passes_share_the_bar_and_the_eta_is_unknown_before_any_work():
    p, out, clock = _bar()
    assert p.eta_s() is None and "ETA ?" in p.line()
    assert run_fraction("pass 1/2", 1.0) == 0.2 and abs(run_fraction("pass 2/2", 0.5) - 0.6) < 1e-12
    assert run_fraction("online", 0.5) == 0.5
    p.phase(1, 2)
    clock.t += 5
    p.update(fraction=0.5)
    assert p.fraction == 0.75
    assert hms(3725) == "1h02m" and hms(65) == "1m05s"


def test_cwa_reader_reports_the_share_of_the_file_read():
    from stillpoint.drivers import open_recording
    src = open_recording(GOOD)
    seen = []
    for _ in src:
        seen.append(src.progress())
    src.close()
    assert seen and seen[-1] == 1.0 and all(0 < f <= 1 for f in seen)
    assert seen == sorted(seen)


def test_process_piped_prints_percentage_lines_and_q_silences(tmp_path, capsys):
    assert main(["process", str(GOOD), "-o", str(tmp_path / "a.mcap")]) == 0
    err = capsys.readouterr().err.splitlines()
    assert err and all(ln.startswith("process: ") for ln in err), err
    assert any(re.search(r"100\.0 %  elapsed \d+m\d\ds  ETA 0m00s", ln) for ln in err), err
    assert err[-1].startswith("process: done in ")
    assert main(["process", str(GOOD), "-o", str(tmp_path / "b.mcap"), "-q"]) == 0
    assert capsys.readouterr().err == ""


def test_simulate_prints_progress_lines_and_q_silences(tmp_path, capsys):
    argv = ["simulate", "-o", str(tmp_path / "a.cwa"), "--days", "0.05", "--hz", "25"]
    assert main(argv) == 0
    err = capsys.readouterr().err.splitlines()
    assert err[-2].startswith("simulate: 100.0 %") and err[-1].startswith("simulate: done in")
    assert main(argv[:2] + [str(tmp_path / "b.cwa")] + argv[3:] + ["-q"]) == 0
    assert capsys.readouterr().err == ""


def test_cohort_eta_counts_the_bytes_of_files_still_running():
    from stillpoint.engine.cohort.execute import CohortProgress
    clock, running = Clock(), [0]
    out = io.StringIO()
    prog = CohortProgress(3, 3_000_000, stream=out, tty=False, interval=10.0,
                          partial=lambda: running[0], clock=clock)
    clock.t += 20.0
    running[0] = 1_000_000  # no file done yet, a third of the bytes read by the workers
    prog.tick()
    line = out.getvalue().splitlines()[-1]
    assert "0/3 files" in line and "ETA 0m40s" in line, line


def test_calibrate_export_and_report_show_progress(tmp_path, capsys):
    assert main(["calibrate", str(GOOD)]) == 0
    err = capsys.readouterr().err.splitlines()
    assert err[-2].startswith("calibrate: 100.0 %") and err[-1].startswith("calibrate: done in")
    assert main(["export", str(GOOD), "-o", str(tmp_path / "e.csv")]) == 0
    err = capsys.readouterr().err.splitlines()
    assert err[-2].startswith("export: 100.0 %") and err[-1].startswith("export: done in")
    assert main(["export", str(GOOD), "-o", str(tmp_path / "f.csv"), "-q"]) == 0
    assert capsys.readouterr().err == ""


def test_report_tells_its_steps(tmp_path, capsys):
    import pytest
    pytest.importorskip("matplotlib", reason="the report draws with matplotlib")
    mcap = tmp_path / "a.mcap"
    assert main(["process", str(GOOD), "-o", str(mcap), "-q"]) == 0
    assert main(["report", str(mcap)]) == 0
    err = capsys.readouterr().err.splitlines()
    assert any("66.7 %" in ln and "nonmovement windows" in ln for ln in err), err
    assert err[-1].startswith("report a.mcap: done in"), err


def test_replay_of_a_log_counts_its_samples(tmp_path, capsys):
    from stillpoint.engine.mcap.replay import McapRawSource
    mcap = tmp_path / "a.mcap"
    assert main(["process", str(GOOD), "-o", str(mcap), "-q"]) == 0
    src = McapRawSource(mcap)
    seen = [src.progress()]
    for _ in src:
        seen.append(src.progress())
    src.close()
    assert seen[0] == 0.0 and seen[-1] == 1.0 and seen == sorted(seen)
    assert main(["replay", str(mcap), "-o", str(tmp_path / "b.mcap")]) == 0
    err = capsys.readouterr().err.splitlines()
    assert err[-2].startswith("replay: 100.0 %") and err[-1].startswith("replay: done in"), err
