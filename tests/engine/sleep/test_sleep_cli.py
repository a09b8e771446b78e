"""``stillpoint process FILE --timezone ZONE [--sleep-log LOG.csv]``: the spt/sib columns, the nights
table, the day table's night columns and the MCAP topics; refusals are one line with exit 2."""

from __future__ import annotations

import csv
import gzip
import json

import pytest

from stillpoint.engine.mcap.stream import iter_messages
from stillpoint.engine.sim.record import simulate_recording
from stillpoint.engine.sleep import NIGHT_COLUMNS
from stillpoint.tools.cli import main


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    d = tmp_path_factory.mktemp("sleep")
    cwa = d / "p7.cwa"
    simulate_recording(cwa, days=2.0, hz=12.5, seed=9, truth_path=False, labels_path=False)
    log = d / "log.csv"
    log.write_text("ID,onset_N1,wakeup_N1,onset_N2,wakeup_N2\np7,22:30,07:00,NA,NA\n")
    mcap = d / "p7.mcap"
    code = main(["process", str(cwa), "-o", str(mcap), "--timezone", "UTC", "--sleep-log", str(log),
                 "-q"])
    return code, cwa, mcap, log


def test_process_writes_nights(run):
    code, _, mcap, _ = run
    assert code == 0
    nights = list(csv.DictReader(open(mcap.with_name("p7.nights.csv"))))
    assert list(nights[0]) == NIGHT_COLUMNS
    assert [n["guider"] for n in nights][:2] == ["sleeplog", "HDCZA"]  # night 2 missing: HDCZA
    assert nights[0]["guider_onset_local"].endswith("T22:30:00+00:00")
    for n in nights:
        assert 3 < float(n["spt_hours"]) < 16
        assert float(n["sleep_hours"]) + float(n["waso_hours"]) == pytest.approx(float(n["spt_hours"]), abs=2e-4)
    with gzip.open(mcap.with_name("p7.epochs.csv.gz"), "rt") as f:
        rows = list(csv.DictReader(f))
    assert list(rows[0])[-2:] == ["spt", "sib"]
    spt_h = sum(r["spt"] == "1" for r in rows) * 5 / 3600
    assert spt_h == pytest.approx(sum(float(n["spt_hours"]) for n in nights), abs=1e-3)
    days = list(csv.DictReader(open(mcap.with_name("p7.days.csv"))))
    first = [d for d in days if d["date"] == nights[0]["night"]][0]
    assert first["night_guider"] == "sleeplog" and first["night_spt_hours"] == nights[0]["spt_hours"]
    topics = {}
    for topic, _, msg in iter_messages(mcap, ["/sleep/night", "/sleep/sib"]):
        topics.setdefault(topic, []).append(json.loads(bytes(msg.data)))
    assert [m["night"] for m in topics["/sleep/night"]] == [n["night"] for n in nights]
    assert len(topics["/sleep/sib"]) > 5


def test_nights_table_is_not_replaced_without_overwrite(run, tmp_path, capsys):
    _, cwa, mcap, _ = run
    out = tmp_path / "p7.mcap"
    (tmp_path / "p7.nights.csv").write_text("keep\n")
    code = main(["process", str(cwa), "-o", str(out), "--timezone", "UTC", "-q"])
    err = capsys.readouterr().err
    assert code == 2 and "p7.nights.csv" in err and len(err.strip().splitlines()) == 1
    assert (tmp_path / "p7.nights.csv").read_text() == "keep\n"


@pytest.mark.parametrize("text,needle", [
    ("ID,onset,wakeup\np7,23:00,7h\n", "row 2"),
    ("ID,onset,wakeup\nsomeone,23:00,07:00\n", "no row for participant 'p7'"),
])
def test_bad_sleep_log_is_one_line_exit_2(run, tmp_path, capsys, text, needle):
    _, cwa, _, _ = run
    log = tmp_path / "bad.csv"
    log.write_text(text)
    code = main(["process", str(cwa), "-o", str(tmp_path / "x.mcap"), "--timezone", "UTC",
                 "--sleep-log", str(log), "-q"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and needle in err and "bad.csv" in err and len(err.splitlines()) == 1
    assert not (tmp_path / "x.mcap").exists()


def test_sleep_log_needs_the_zone(run, tmp_path, capsys):
    _, cwa, _, log = run
    code = main(["process", str(cwa), "-o", str(tmp_path / "x.mcap"), "--sleep-log", str(log), "-q"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "--timezone" in err and len(err.splitlines()) == 1


def test_text_summary_names_the_nights():
    from stillpoint.tools.cli.commands._tableopts import tables_text
    t = {"epoch_rows": 10, "clean_epochs": 10, "day_rows": 1, "nonwear_version": "2023",
         "flags": {k: 0 for k in ("nonwear", "clipping", "gap", "qc", "filter_warmup")},
         "file": {"valid_day": 0, "enmo_mean_mg": None},
         "sleep": {"nights": "a.nights.csv", "night_rows": 2, "guiders": {"HDCZA": 1, "sleeplog": 1},
                   "sib_bouts": 40}}
    text = tables_text({"timezone": "UTC", "tables": t})
    assert "sleep: 2 night(s) (guider: HDCZA 1, sleeplog 1), 40 inactivity bouts; nights table a.nights.csv" in text


def test_sleep_with_activity_outcomes(run, tmp_path):
    _, cwa, _, _ = run
    out = tmp_path / "o.mcap"
    assert main(["process", str(cwa), "-o", str(out), "--timezone", "UTC", "--cutpoints",
                 "hildebrand_adults_geneactiv_wrist", "--steps", "-q"]) == 0
    with gzip.open(tmp_path / "o.epochs.csv.gz", "rt") as f:
        rows = list(csv.DictReader(f))
    head = list(rows[0])
    assert head[-2:] == ["spt", "sib"] and "band_hildebrand_adults_geneactiv_wrist" in head
    nights = list(csv.DictReader(open(tmp_path / "o.nights.csv")))
    spt_h = sum(r["spt"] == "1" for r in rows) * 5 / 3600
    assert nights and spt_h == pytest.approx(sum(float(n["spt_hours"]) for n in nights), abs=1e-3)


def test_sleep_without_a_zone_is_on_the_device_clock(run, tmp_path, capsys):
    """GGIR computes sleep on the device's clock when the zone is not known: nights of 24 h, no
    DST, no UTC; the summary says which clock the nights are on."""
    _, cwa, _, _ = run
    mcap = tmp_path / "dev.mcap"
    assert main(["process", str(cwa), "-o", str(mcap)]) == 0
    out = capsys.readouterr().out
    assert "times: device local time, zone unknown" in out
    assert "night(s) on the device's clock (zone unknown: nights of 24 h, DST not applied" in out
    nights = list(csv.DictReader(open(tmp_path / "dev.nights.csv")))
    assert len(nights) >= 1 and list(nights[0]) == NIGHT_COLUMNS
    full = [n for n in nights if n["window_cut"] == ""]
    assert full and all(n["window_hours"] == "24" and n["dst"] == "0" for n in full)
    for n in nights:
        assert n["onset_utc"] == n["wake_utc"] == ""  # the device clock is not UTC
        if n["onset_local"]:
            assert "+" not in n["onset_local"][10:] and not n["onset_local"].endswith("Z")
    with gzip.open(tmp_path / "dev.epochs.csv.gz", "rt") as f:
        assert {"spt", "sib"} <= set(next(csv.reader(f)))
