"""Cohorts collate the rhythm and windows tables per file and per participant; sleep is on by
default as for ``process``; one GGIR sleep log serves every participant; the participant summary
averages only valid nights."""

from __future__ import annotations

import csv
from pathlib import Path

import pytest

from stillpoint.engine.sim import simulate_recording
from stillpoint.tools.cli import main as cli

pytest.importorskip("distributed", reason="the cohort tests need the test extra (dask, distributed)")


def _rows(path: Path) -> list:
    with open(path, newline="", encoding="utf-8") as f:
        return list(csv.DictReader(f))


@pytest.fixture(scope="module")
def cohort(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("cohort")
    src = tmp / "in"
    src.mkdir()
    for name, seed in (("P01", 3), ("P02", 4)):
        simulate_recording(src / f"{name}.cwa", days=2.6, hz=12.5, seed=seed, truth_path=False)
    manifest = tmp / "manifest.csv"
    manifest.write_text(f"path,participant\n{src / 'P01.cwa'},P01\n{src / 'P02.cwa'},P02\n")
    log = tmp / "sleeplog.csv"
    # GGIR's basic format: ID, then onset / wake-up pairs per night (P02 has no row)
    log.write_text("ID,onset_N1,wakeup_N1,onset_N2,wakeup_N2\nP01,23:00:00,07:00:00,23:30:00,06:30:00\n")
    out = tmp / "out"
    assert cli(["cohort", "run", str(manifest), "-o", str(out), "--timezone", "UTC", "-q",
                "--sleep-log", str(log)]) == 0
    return out


def test_sleep_is_on_by_default_and_nights_are_collated(cohort):
    nights = _rows(cohort / "cohort_nights.csv")
    assert {n["participant"] for n in nights} == {"P01", "P02"}
    assert "night_valid" in nights[0] and "cleaningcode" in nights[0]


def test_one_sleep_log_for_the_cohort(cohort):
    nights = _rows(cohort / "cohort_nights.csv")
    p1 = [n for n in nights if n["participant"] == "P01"]
    p2 = [n for n in nights if n["participant"] == "P02"]
    assert any(n["guider"] == "sleeplog" and n["cleaningcode"] == "0" for n in p1)
    assert all(n["guider"] != "sleeplog" for n in p2)


def test_rhythm_and_windows_collated(cohort):
    rhythm = _rows(cohort / "cohort_rhythm.csv")
    assert sorted(r["participant"] for r in rhythm) == ["P01", "P02"]
    assert all(r["is"] and r["iv"] for r in rhythm)
    windows = _rows(cohort / "cohort_windows.csv")
    assert {w["window_type"] for w in windows} == {"WW", "MM", "OO"}
    assert {w["participant"] for w in windows} == {"P01", "P02"}


def test_participant_summary_has_sleep_and_rhythm(cohort):
    nights = _rows(cohort / "cohort_nights.csv")
    rhythm = {r["participant"]: r for r in _rows(cohort / "cohort_rhythm.csv")}
    for p in _rows(cohort / "cohort_participants.csv"):
        own = [n for n in nights if n["participant"] == p["participant"]]
        good = [n for n in own if n["night_valid"] == "1"]
        assert int(p["nights"]) == len(own) and int(p["nights_valid"]) == len(good) >= 1
        assert len(good) < len(own)  # the first and last (cut) nights are left out
        mean = sum(float(n["spt_hours"]) for n in good) / len(good)
        assert float(p["spt_hours"]) == pytest.approx(mean, abs=1e-4)
        assert float(p["is"]) == pytest.approx(float(rhythm[p["participant"]]["is"]), abs=1e-4)


def test_a_bad_cohort_sleep_log_is_refused_before_any_work(tmp_path, capsys):
    src = tmp_path / "in"
    src.mkdir()
    simulate_recording(src / "P01.cwa", days=0.04, hz=12.5, seed=3, truth_path=False)
    log = tmp_path / "bad.csv"
    log.write_text("ID,onset_N1,wakeup_N1\nP01,25:99,07:00:00\n")
    assert cli(["cohort", "run", str(src), "-o", str(tmp_path / "out"), "--timezone", "UTC",
                "-q", "--sleep-log", str(log)]) == 2
    err = capsys.readouterr().err
    assert "bad.csv" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "out" / "cohort_summary.csv").exists()


def test_a_sleep_log_gone_after_planning_is_not_a_bug():
    from stillpoint.engine.cohort.job import classify
    from stillpoint.engine.sleep import SleepLogError
    assert classify(SleepLogError("sleep log /x.csv: cannot be read")) == "corrupt_input"
