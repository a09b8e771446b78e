"""A cohort's per-participant rows when files overlap (the same device downloaded twice, or two
files covering one date): each date counted once, a warning; a damaged file that could still be
read says what was wrong in the summary table; the default participant id is the file name
without the format's ending."""

from __future__ import annotations

import csv
import shutil
from pathlib import Path

import pytest

from stillpoint.drivers.names import recording_stem
from stillpoint.engine.sim.record import simulate_recording
from stillpoint.tools.cli import main

FUZZ = Path(__file__).parents[2] / "data" / "fuzz"


def _rows(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_recording_stem_drops_the_format_ending_only():
    assert recording_stem("/a/P04_tiny.cwa.gz") == "P04_tiny"
    assert recording_stem("P04_tiny.CWA") == "P04_tiny"
    assert recording_stem("week.bin.gz") == "week"
    assert recording_stem("visit.2.gt3x") == "visit.2"
    assert recording_stem("notes.txt") == "notes.txt"
    assert recording_stem(".cwa") == ".cwa"


def test_overlapping_files_count_each_date_once_and_warn(tmp_path, capsys):
    # one device and session downloaded twice: the second file repeats the first's hours and
    # goes on a little (different seeds: not the same bytes, which the plan would merge)
    for name, days, seed in (("first", 0.3, 41), ("again", 0.35, 42)):
        simulate_recording(tmp_path / f"{name}.cwa", days=days, hz=12.5, seed=seed,
                           start="2026-03-28T08:00:00", effects="offset,noise", device_id=1234,
                           truth_path=False, labels_path=False)
    (tmp_path / "m.csv").write_text("path,participant\nfirst.cwa,P7\nagain.cwa,P7\n")
    out = tmp_path / "out"
    assert main(["cohort", "run", str(tmp_path / "m.csv"), "-o", str(out), "--scheduler",
                 "serial", "-q", "--valid-day-hours", "2"]) == 0
    err = capsys.readouterr().err
    warn = [ln for ln in err.splitlines() if ln.startswith("warning: participant P7")]
    assert len(warn) == 1 and "overlap in time" in warn[0] and "counted once" in warn[0], err
    files = _rows(out / "cohort_summary.csv")
    assert [int(r["valid_days"]) for r in files] == [1, 1]
    [p] = _rows(out / "cohort_participants.csv")
    assert p["participant"] == "P7" and p["files"] == "2" and p["shared_dates"] == "1"
    assert p["valid_days"] == "1" and p["valid_weekend_days"] == "1"  # 2026-03-28, a Saturday
    # wear: the date's best file, not the sum of both files (which would be 7-8 h)
    best = max(float(r["wear_time_h"]) for r in files)
    assert float(p["wear_time_h"]) == pytest.approx(best, abs=1e-3)
    # the collate command repeats the warning
    assert main(["cohort", "collate", str(out)]) == 0
    assert "overlap in time" in capsys.readouterr().err


def test_damaged_file_says_why_and_participant_is_the_file_stem(tmp_path, capsys, monkeypatch):
    import stillpoint.engine.cohort.job as job
    monkeypatch.setattr(job, "_subject_code", lambda mcap: "")  # a header without a subject code
    src = tmp_path / "in"
    src.mkdir()
    shutil.copy(FUZZ / "ax3_truncated.cwa.gz", src / "P04_tiny.cwa.gz")
    out = tmp_path / "out"
    assert main(["cohort", "run", str(src), "-o", str(out), "--scheduler", "serial", "-q"]) == 0
    [r] = _rows(out / "cohort_summary.csv")
    assert r["participant"] == "P04_tiny"
    assert int(r["qc_events"]) == 2
    assert "gzip stream ends" in r["qc_detail"] and "(truncated file)" in r["qc_detail"], r
    assert r["qc_detail"].startswith("read_error at sector 77: ")
    [p] = _rows(out / "cohort_participants.csv")
    assert p["participant"] == "P04_tiny"
