"""Tables from the best estimate: ``process --mode online`` writes its epoch and day tables from a
second pass with the run's final estimate applied from the first sample (the log stays the
online one), so a day's ENMO is that of ``process`` (batch) and not of the identity in force until
the first accepted refit; the day table names the estimate (``calibration_source``) and the
epoch table says per epoch whether it was corrected (``corrected``)."""

from __future__ import annotations

import csv
import gzip
import json

import numpy as np
import pytest

from stillpoint.engine.calibration.estimate import (CalibrationEstimate, SOURCE_NONE, SOURCE_PRIOR,
                                                    SOURCE_RECORDING, SOURCE_STATIC,
                                                    STATIC_METHOD, calibration_source)
from stillpoint.engine.sim.record import simulate_recording
from stillpoint.tools.cli import main

from synthetic_recording import SENSOR_ERRORS



def day_enmo(path) -> dict:
    with open(path) as f:
        return {r["date"]: r for r in csv.DictReader(f)}


def epoch_rows(path) -> list:
    with gzip.open(path, "rt") as f:
        return list(csv.DictReader(f))


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    d = tmp_path_factory.mktemp("products")
    cwa = d / "rec.cwa"
    simulate_recording(cwa, days=1.0, hz=12.5, seed=5, effects=SENSOR_ERRORS, truth_path=False,
                       labels_path=False)
    assert main(["process", str(cwa), "-o", str(d / "b.mcap"), "-q"]) == 0
    assert main(["process", str(cwa), "-o", str(d / "o.mcap"), "--mode", "online", "-q",
                 "--summary", str(d / "o.json")]) == 0
    return d


def test_online_day_table_is_within_3_percent_of_batch_and_names_the_estimate(runs):
    b, o = day_enmo(runs / "b.days.csv"), day_enmo(runs / "o.days.csv")
    assert list(b) == list(o) and len(b) >= 3  # two local days and the summary row
    for date in b:
        eb, eo = float(b[date]["enmo_mean_mg"]), float(o[date]["enmo_mean_mg"])
        assert abs(eo - eb) <= 0.03 * eb, (date, eo, eb)
        assert o[date]["calibration_source"] == SOURCE_RECORDING
        assert b[date]["calibration_source"] == SOURCE_RECORDING
    # the online log is what was applied live: identity for the first 12 h, so its mean is far off
    summary = json.loads((runs / "o.json").read_text())
    live, best = summary["enmo_mean_mg"], float(o["all"]["enmo_mean_mg"])
    assert abs(live - best) > 0.2 * best, (live, best)
    assert summary["estimates"][0]["applied"]  # the log keeps the estimates it applied live


def test_epoch_table_says_each_epoch_was_corrected(runs):
    rows = epoch_rows(runs / "o.epochs.csv.gz")
    assert "corrected" in rows[0]
    corrected = np.array([r["corrected"] == "1" for r in rows])
    has = np.array([int(r["n"]) > 0 for r in rows])
    assert corrected[has].all() and not corrected[~has].any()


def test_export_of_the_online_log_gives_the_tables_process_wrote(runs, tmp_path):
    out = tmp_path / "days.csv"
    assert main(["export", str(runs / "o.mcap"), "--table", "days", "-o", str(out)]) == 0
    assert out.read_text() == (runs / "o.days.csv").read_text()


def test_no_calibration_applied_is_named_none_and_no_epoch_corrected(runs, tmp_path):
    out = tmp_path / "n.mcap"
    assert main(["process", str(runs / "rec.cwa"), "-o", str(out), "--mode", "online",
                 "--no-calibrate", "-q"]) == 0
    days = day_enmo(tmp_path / "n.days.csv")
    assert {d["calibration_source"] for d in days.values()} == {SOURCE_NONE}
    assert {r["corrected"] for r in epoch_rows(tmp_path / "n.epochs.csv.gz")} == {"0"}


def test_calibration_source_names_prior_static_recording_and_none():
    t0 = 10**18
    own = CalibrationEstimate(status="ok", method="autocal-c1", fit_start_ns=t0, fit_end_ns=t0 + 10)
    prior = CalibrationEstimate(status="ok", method="autocal-c1", fit_start_ns=t0 - 100,
                                fit_end_ns=t0 - 50)
    static = CalibrationEstimate(status="ok", method=STATIC_METHOD, fit_end_ns=t0 - 50)
    assert calibration_source(own, True, t0) == SOURCE_RECORDING
    assert calibration_source(prior, True, t0) == SOURCE_PRIOR
    assert calibration_source(static, True, t0) == SOURCE_STATIC
    assert calibration_source(own, False, t0) == SOURCE_NONE


def test_online_run_and_its_tables_pass_keep_block_arrays_on_the_heap(runs, monkeypatch, tmp_path):
    """Both passes of an online run set glibc's block thresholds (engine/core/malloc.py): with the
    dynamic ones their block-sized arrays were trimmed off the heap and faulted in every step."""
    import stillpoint.engine.run.online as online
    import stillpoint.engine.tables.estimate_pass as estimate_pass
    calls = []
    monkeypatch.setattr(online, "tune_for_blocks", lambda: calls.append("online pass"))
    monkeypatch.setattr(estimate_pass, "tune_for_blocks", lambda: calls.append("tables pass"))
    assert main(["process", str(runs / "rec.cwa"), "-o", str(tmp_path / "o.mcap"), "--mode",
                 "online", "-q"]) == 0
    assert calls == ["online pass", "tables pass"]
    with gzip.open(tmp_path / "o.epochs.csv.gz", "rb") as a, gzip.open(runs / "o.epochs.csv.gz", "rb") as b:
        assert a.read() == b.read()


def test_batch_run_keeps_block_arrays_on_the_heap(runs, monkeypatch, tmp_path):
    """A batch run sets glibc's block thresholds too (engine/core/malloc.py), and its output is
    the same bytes."""
    import stillpoint.engine.run.batch as batch
    calls = []
    monkeypatch.setattr(batch, "tune_for_blocks", lambda: calls.append("batch"))
    assert main(["process", str(runs / "rec.cwa"), "-o", str(tmp_path / "b.mcap"), "-q"]) == 0
    assert calls == ["batch"]
    with gzip.open(tmp_path / "b.epochs.csv.gz", "rb") as a, gzip.open(runs / "b.epochs.csv.gz", "rb") as b:
        assert a.read() == b.read()


def test_tables_pass_steps_hold_at_most_its_samples_and_write_the_same_tables(runs, monkeypatch,
                                                                              tmp_path):
    """The tables' own pass joins blocks into steps of ``estimate_pass.step_s(rate)``: at most
    ``tuning.TABLES_PASS_STEP_S`` of data and at most ``tuning.TABLES_PASS_SAMPLES`` samples
    at any rate. With a small cap (and the reader's batches smaller still) every step stays under
    it, and the tables and the summary's numbers are those of the default steps."""
    import stillpoint.engine.tables.estimate_pass as estimate_pass
    from stillpoint.engine.run import tuning
    assert estimate_pass.step_s(100.0) == tuning.TABLES_PASS_STEP_S
    assert estimate_pass.step_s(1600.0) == tuning.TABLES_PASS_SAMPLES / 1600.0
    monkeypatch.setattr(tuning, "TABLES_PASS_SAMPLES", 3000)  # 240 s at 12.5 Hz
    monkeypatch.setattr(tuning, "TABLES_PASS_SECTORS", 3)
    steps = []
    coalesce = estimate_pass.coalesce_blocks

    def spy(src, max_s):
        for b in coalesce(src, max_s):
            steps.append(b.n)
            yield b
    monkeypatch.setattr(estimate_pass, "coalesce_blocks", spy)
    assert main(["process", str(runs / "rec.cwa"), "-o", str(tmp_path / "o.mcap"), "--mode",
                 "online", "-q", "--summary", str(tmp_path / "o.json")]) == 0
    assert len(steps) > 100 and max(steps) <= 3001
    with gzip.open(tmp_path / "o.epochs.csv.gz", "rb") as a, gzip.open(runs / "o.epochs.csv.gz", "rb") as b:
        assert a.read() == b.read()
    assert (tmp_path / "o.days.csv").read_text() == (runs / "o.days.csv").read_text()
    got, want = (json.loads(p.read_text())["tables"]["file"] for p in (tmp_path / "o.json", runs / "o.json"))
    assert got == want
