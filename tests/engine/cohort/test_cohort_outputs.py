"""What a study reads from a cohort: per-file wear hours, valid days and clean-epoch ENMO/MAD
in the summary; a stacked day table and a per-participant summary (weekday and weekend valid
days); the table options of ``process`` accepted by ``cohort run`` and part of the key; a
per-file zone and participant id from the manifest; honest time labels."""

from __future__ import annotations

import csv
import json

import pytest

from stillpoint.engine.sim.record import simulate_recording
from stillpoint.engine.timezones import UNKNOWN_LABEL
from stillpoint.tools.cli import main


def _rows(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


@pytest.fixture(scope="module")
def cohort(tmp_path_factory):
    d = tmp_path_factory.mktemp("cohort_outputs")
    # P1 wears one device on a Saturday and another on a Monday; the third file has no
    # participant column value (its subject code names it) and its own zone
    for name, start, seed in (("sat", "2026-03-28T08:00:00", 31), ("mon", "2026-03-30T08:00:00", 32),
                              ("ldn", "2026-03-30T08:00:00", 33)):
        simulate_recording(d / f"{name}.cwa", days=0.2, hz=12.5, seed=seed, start=start,
                           effects="offset,noise", truth_path=False, labels_path=False)
    (d / "manifest.csv").write_text("path,participant,timezone\nsat.cwa,P1,\nmon.cwa,P1,\n"
                                    "ldn.cwa,,Europe/London\n")
    out = d / "out"
    code = main(["cohort", "run", str(d / "manifest.csv"), "-o", str(out), "--scheduler", "serial",
                 "-q", "--valid-day-hours", "2", "--enmo-bands", "30,100,400"])
    assert code == 0
    return d, out


def test_summary_has_wear_valid_days_and_clean_epoch_means(cohort):
    d, out = cohort
    rows = {r["file"].rsplit("/", 1)[-1]: r for r in _rows(out / "cohort_summary.csv")}
    assert set(rows) == {"sat.cwa", "mon.cwa", "ldn.cwa"}
    for r in rows.values():
        day_all = [x for x in _rows(r["days"]) if x["date"] == "all"][0]
        assert r["wear_time_h"] != "" and float(r["wear_time_h"]) == pytest.approx(
            float(day_all["wear_hours"]), abs=1e-3)
        assert 2.0 <= float(r["wear_time_h"]) <= 4.8  # 4.8 h recorded, less any nonwear
        assert int(r["valid_days"]) == 1  # >= 2 h of clean wear (--valid-day-hours 2)
        assert float(r["enmo_mean_mg"]) == pytest.approx(float(day_all["enmo_mean_mg"]), rel=1e-4)
        assert float(r["mad_mean_mg"]) == pytest.approx(float(day_all["mad_mean_mg"]), rel=1e-4)
        assert r["enmo_all_epochs_mg"] != ""  # the engine's mean over every epoch, named so
        assert r["min_enmo_30_100mg"] != "" and r["m10_mg"] == ""  # M10 needs a 10-h window
    assert rows["sat.cwa"]["participant"] == rows["mon.cwa"]["participant"] == "P1"
    assert rows["ldn.cwa"]["participant"] == "sim-seed-33"  # the recording's subject code
    # time labels: UTC only where the zone is known
    assert rows["sat.cwa"]["timezone"] == UNKNOWN_LABEL and rows["sat.cwa"]["start_utc"] == ""
    assert rows["sat.cwa"]["start_local"].startswith("2026-03-28T08:0")
    assert not rows["sat.cwa"]["start_local"].endswith("Z")
    assert rows["ldn.cwa"]["timezone"] == "Europe/London"
    assert rows["ldn.cwa"]["start_utc"].startswith("2026-03-30T07:0")  # BST: 08:00 local
    assert rows["ldn.cwa"]["start_utc"].endswith("Z")
    assert rows["ldn.cwa"]["start_local"].endswith("+01:00")


def test_stacked_days_and_participants(cohort):
    d, out = cohort
    days = _rows(out / "cohort_days.csv")
    assert list(days[0])[:5] == ["participant", "file", "key", "date", "weekday"]
    assert {r["participant"] for r in days} == {"P1", "sim-seed-33"}
    assert all(r["date"] != "all" for r in days)
    sat = [r for r in days if r["file"].endswith("sat.cwa")]
    assert [(r["date"], r["weekday"], r["valid_day"]) for r in sat] == [("2026-03-28", "Sat", "1")]
    people = {r["participant"]: r for r in _rows(out / "cohort_participants.csv")}
    p1 = people["P1"]
    assert (p1["files"], p1["valid_days"], p1["valid_weekdays"], p1["valid_weekend_days"]) == \
        ("2", "2", "1", "1")
    summ = [r for r in _rows(out / "cohort_summary.csv") if r["participant"] == "P1"]
    # both tables hold 4 decimals: sums and means of rounded cells agree to their rounding
    assert float(p1["wear_time_h"]) == pytest.approx(sum(float(r["wear_time_h"]) for r in summ),
                                                     abs=2e-4)
    w = [float(r["wear_time_h"]) for r in summ]
    e = [float(r["enmo_mean_mg"]) for r in summ]
    assert float(p1["enmo_mean_mg"]) == pytest.approx(sum(a * b for a, b in zip(w, e)) / sum(w),
                                                      abs=2e-4)


def test_numbers_are_rounded_as_the_day_table(cohort):
    """4 decimals as in the day table (trailing zeros dropped); calibration parameters 7 (8 for
    the temperature offset, g/degC); integers and text as they are."""
    d, out = cohort
    rows = _rows(out / "cohort_summary.csv")
    people = _rows(out / "cohort_participants.csv")

    def decimals(text):
        return len(text.split(".")[1]) if "." in text and "e" not in text.lower() else 0

    for r in rows:
        for k in ("duration_h", "wear_time_h", "enmo_mean_mg", "mad_mean_mg", "peak_rss_mb",
                  "min_enmo_30_100mg"):
            assert r[k] != "" and decimals(r[k]) <= 4, (k, r[k])
        for k in ("error_before_mg", "error_after_mg", "hours_used", "temperature_ref"):
            assert decimals(r[k]) <= 4, (k, r[k])
        assert any(decimals(r[k]) == 4 for k in ("duration_h", "enmo_mean_mg", "peak_rss_mb"))
        for k in ("offset_x", "offset_y", "scale_x", "scale_z"):
            assert decimals(r[k]) <= 7, (k, r[k])
        assert decimals(r["tempoffset_z"]) <= 8
        assert r["samples"].isdigit() and r["calibration_applied"] in ("True", "False")
        summary = json.loads(__import__("pathlib").Path(r["summary"]).read_text())
        assert float(r["offset_x"]) == pytest.approx(summary["calibration"]["offset"][0], abs=5e-8)
        assert float(r["duration_h"]) == pytest.approx(summary["duration_s"] / 3600, abs=5e-5)
    for p in people:
        assert decimals(p["wear_time_h"]) <= 4 and decimals(p["enmo_mean_mg"]) <= 4


def test_table_options_and_manifest_zone_are_in_the_key(cohort):
    d, out = cohort
    plan = json.loads((out / "cohort.json").read_text())
    assert plan["settings"]["tables"] == {"nonwear_version": "2023", "valid_day_hours": 2.0,
                                          "enmo_bands_mg": [30.0, 100.0, 400.0], "mvpa_bout_s": 60.0,
                                          "sleep": True}
    from stillpoint.engine.cohort import make_plan
    from stillpoint.engine.cohort.plan import read_plan
    old = read_plan(out)
    paths = [__import__("pathlib").Path(e.path) for e in old.entries]
    attrs = {e.path: {"timezone": e.timezone, "participant": e.participant} for e in old.entries}
    same = make_plan(paths, plan["settings"], attributes=attrs)
    assert [e.key for e in same.entries] == [e.key for e in old.entries]
    other = make_plan(paths, dict(plan["settings"], tables=dict(plan["settings"]["tables"],
                                                                valid_day_hours=16.0)),
                      attributes=attrs)
    assert not {e.key for e in other.entries} & {e.key for e in old.entries}
    no_zone = make_plan(paths, plan["settings"])
    changed = {e.path for e, f in zip(no_zone.entries, old.entries) if e.key != f.key}
    assert changed == {str(d / "ldn.cwa")}  # only the file the manifest gives a zone


def test_a_bad_manifest_zone_is_one_line(tmp_path, capsys):
    rec = tmp_path / "a.cwa"
    simulate_recording(rec, days=0.01, hz=12.5, seed=3, truth_path=False, labels_path=False)
    (tmp_path / "m.csv").write_text("path,timezone\na.cwa,Mars/Base\n")
    assert main(["cohort", "run", str(tmp_path / "m.csv"), "-o", str(tmp_path / "o"),
                 "--scheduler", "serial", "-q"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "Mars/Base" in err[0] and "m.csv" in err[0]


def test_a_cohort_zone_that_contradicts_a_geneactiv_header_fails_that_file(tmp_path, capsys):
    """One cohort-wide --timezone never silently moves a GENEActiv file away from the zone in
    its header: the file fails (one line naming it and both zones) unless --timezone-override,
    which the settings record."""
    rec = tmp_path / "us.bin"
    simulate_recording(rec, days=0.02, hz=25, seed=8, device="geneactiv", truth_path=False,
                       labels_path=False)  # header zone +00:00
    out = tmp_path / "o"
    assert main(["cohort", "run", str(rec), "-o", str(out), "--scheduler", "serial", "-q",
                 "--timezone", "America/Chicago"]) == 2  # its only file failed
    [fail] = _rows(out / "cohort_failures.csv")
    assert fail["class"] == "corrupt_input" and str(rec) in fail["error"]
    assert "+00:00" in fail["error"] and "--timezone-override" in fail["error"]
    assert _rows(out / "cohort_summary.csv") == []
    out2 = tmp_path / "o2"
    assert main(["cohort", "run", str(rec), "-o", str(out2), "--scheduler", "serial", "-q",
                 "--timezone", "America/Chicago", "--timezone-override"]) == 0
    [row] = _rows(out2 / "cohort_summary.csv")
    assert row["timezone"] == "America/Chicago"
    assert json.loads((out2 / "cohort.json").read_text())["settings"]["timezone_override"] is True


def test_cell_rounding_rules():
    from stillpoint.engine.cohort.collate import _cell
    assert _cell("offset_x", 0.03920130602945695) == "0.0392013"
    assert _cell("scale_y", 1.0108964556561584) == "1.0108965"
    assert _cell("tempoffset_z", -0.000788123456) == "-0.00078812"
    assert _cell("enmo_mean_mg", 30.96406740324302) == "30.9641"
    assert _cell("wear_time_h", 23.995833333333337) == "23.9958"
    assert _cell("rate_hz", 100.0) == "100" and _cell("samples", 8563385) == 8563385
    assert _cell("offset_x", float("nan")) == "" and _cell("enmo_mean_mg", float("inf")) == ""
    assert _cell("m10_mg", None) == "" and _cell("participant", "=HYPERLINK(1)").startswith("'")
