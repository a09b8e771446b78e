"""Activity outcomes in the tables: the cut-point set's band per epoch and minutes/bouts per day,
Verisense steps per epoch and per day, the columns named by key and set, the same tables
whatever the pipeline's block size, and the default tables unchanged."""

import csv
import gzip
import os
import subprocess
import sys
from types import SimpleNamespace

import numpy as np
import pytest

from stillpoint.engine.outcomes.bouts import ggir_bouts
from stillpoint.engine.outcomes.daily import OutcomeSettings
from stillpoint.engine.run import RunSettings, process_file
from stillpoint.engine.sim import WearerParams, simulate_recording
from stillpoint.engine.tables import TablesSettings, table_paths
from stillpoint.engine.tables.writer import EPOCH_COLUMNS

KEY = "hildebrand_adults_geneactiv_wrist"
SETS = ("original", "rowlands2022")


def _run(rec, out, **kw):
    ep, dp = table_paths(out)
    ts = TablesSettings(ep, dp, valid_day_hours=4.0,
                        outcomes=OutcomeSettings(cutpoints=KEY, steps=SETS, impute=True))
    s = process_file(rec, out, RunSettings(**kw), tables=ts)
    with gzip.open(ep, "rt") as f:
        e_text = f.read()
    with open(dp) as f:
        d_text = f.read()
    return s, e_text, d_text


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    d = tmp_path_factory.mktemp("outcomes")
    rec = d / "r.cwa"
    simulate_recording(rec, days=1.2, hz=12.5, seed=11, effects="offset,noise",
                       wearer=WearerParams(drawer_per_day=1.0), truth_path=False,
                       labels_path=False)
    s, e_text, d_text = _run(rec, d / "a.mcap", max_block_s=600.0)
    epochs = list(csv.DictReader(e_text.splitlines()))
    days = list(csv.DictReader(d_text.splitlines()))
    return SimpleNamespace(dir=d, rec=rec, summary=s, e_text=e_text, d_text=d_text,
                           epochs=epochs, days=days)


def test_columns_carry_the_key_and_the_sets(run):
    head = run.e_text.splitlines()[0].split(",")
    assert head[-4:] == [f"band_{KEY}", "steps_verisense_original", "steps_verisense_rowlands2022",
                         f"bouts_{KEY}"]
    cols = run.days[0].keys()
    for b in ("light", "moderate", "vigorous", "mvpa"):
        assert f"min_{b}_{KEY}" in cols
        for m in (1, 5, 10):
            assert f"bout_min_{b}_{m}m_{KEY}" in cols
    assert {"steps_verisense_original", "cadence_max_spm_verisense_rowlands2022"} <= set(cols)
    assert run.summary["tables"]["outcomes"]["cutpoints"] == KEY


def test_day_values_come_from_the_epoch_rows(run):
    by_day = {}
    for r in run.epochs:
        by_day.setdefault(r["time_local"][:10], []).append(r)
    days = [d for d in run.days if d["date"] != "all"]
    assert len(days) >= 2
    total = {s: 0 for s in SETS}
    for d in days:
        rows = by_day[d["date"]]
        band = np.array([r[f"band_{KEY}"] for r in rows])
        for b, sel in (("light", band == "light"), ("moderate", band == "moderate"),
                       ("vigorous", band == "vigorous"),
                       ("mvpa", (band == "moderate") | (band == "vigorous"))):
            assert float(d[f"min_{b}_{KEY}"]) == pytest.approx(sel.sum() * 5 / 60, abs=1e-3)
            for m in (1, 5, 10):
                inb = ggir_bouts(sel, 12 * m, 12)
                assert float(d[f"bout_min_{b}_{m}m_{KEY}"]) == pytest.approx(inb.sum() * 5 / 60, abs=1e-3)
                # the epoch table names the same epochs
                tagged = np.array([f"{b}_{m}m" in r[f"bouts_{KEY}"].split(";") for r in rows])
                assert np.array_equal(tagged, inb)
        for s in SETS:
            n = np.array([int(r[f"steps_verisense_{s}"]) for r in rows])
            assert int(d[f"steps_verisense_{s}"]) == n.sum()
            per_min = np.add.reduceat(n, np.arange(0, n.size, 12))
            assert int(d[f"cadence_max_spm_verisense_{s}"]) == per_min.max()
            total[s] += n.sum()
    # a simulated day walks: both sets count thousands of steps
    assert min(total.values()) > 1000


def test_imputed_columns_are_labelled_and_filled(run):
    days = [d for d in run.days if d["date"] != "all"]
    for d in days:
        assert float(d["enmo_mean_mg_imputed"]) > 0
        assert float(d[f"min_mvpa_{KEY}_imputed"]) >= 0
        assert 0 <= float(d[f"bout_min_mvpa_10m_{KEY}_imputed"]) <= float(d["day_hours"]) * 60
    # a day with nonwear gets values on the imputed epochs: not the clean-epoch mean
    nw = [d for d in days if float(d["nonwear_hours"]) > 0.2]
    assert nw and any(d["enmo_mean_mg_imputed"] != d["enmo_mean_mg"] for d in nw)


def test_tables_do_not_depend_on_the_block_size(run, tmp_path):
    _, e_text, d_text = _run(run.rec, tmp_path / "b.mcap", max_block_s=97.0)
    assert e_text == run.e_text
    assert d_text == run.d_text


def test_default_tables_have_no_outcome_columns(tmp_path):
    rec = tmp_path / "s.cwa"
    simulate_recording(rec, days=0.05, hz=12.5, seed=3, truth_path=False, labels_path=False)
    ep, dp = table_paths(tmp_path / "s.mcap")
    s = process_file(rec, tmp_path / "s.mcap", RunSettings(), tables=TablesSettings(ep, dp))
    with gzip.open(ep, "rt") as f:
        assert f.readline().strip().split(",") == EPOCH_COLUMNS[1:]
    with open(dp) as f:
        head = f.readline()
    assert "steps_" not in head and "bout_min_" not in head and "outcomes" not in s["tables"]


def test_cli_unknown_cutpoints_is_a_usage_error(tmp_path):
    r = subprocess.run([sys.executable, "-m", "stillpoint", "process", str(tmp_path / "x.cwa"),
                        "--cutpoints", "nope"], capture_output=True, text=True)
    assert r.returncode == 2
    assert "unknown cut-point set 'nope'" in r.stderr and "Traceback" not in r.stderr


def test_cohort_carries_the_outcome_columns(run, tmp_path):
    out = tmp_path / "coh"
    r = subprocess.run([sys.executable, "-m", "stillpoint.tools", "cohort", "run", str(run.rec),
                        "-o", str(out), "--scheduler", "serial", "--cutpoints", KEY, "--steps",
                        "--valid-day-hours", "4"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    with open(out / "cohort_days.csv") as f:
        days = list(csv.DictReader(f))
    with open(out / "cohort_summary.csv") as f:
        [summary] = list(csv.DictReader(f))
    with open(out / "cohort_participants.csv") as f:
        [who] = list(csv.DictReader(f))
    mine = [d for d in run.days if d["date"] != "all"]
    assert [d["steps_verisense_rowlands2022"] for d in days] == \
        [d["steps_verisense_rowlands2022"] for d in mine]
    assert [d[f"bout_min_mvpa_10m_{KEY}"] for d in days] == [d[f"bout_min_mvpa_10m_{KEY}"] for d in mine]
    valid = [float(d["steps_verisense_original"]) for d in mine if d["valid_day"] == "1"]
    assert valid and float(summary["steps_verisense_original"]) == pytest.approx(np.mean(valid), abs=1e-3)
    assert float(who["steps_verisense_original"]) == pytest.approx(np.mean(valid), abs=1e-3)
    assert f"min_mvpa_{KEY}" in summary


def _need_matplotlib():
    if os.environ.get("CI") != "true":  # CI installs the plot extra: there it must run
        pytest.importorskip("matplotlib", reason="the report needs matplotlib (the plot extra)")


def test_report_shows_steps_and_mvpa_per_day(run, tmp_path):
    _need_matplotlib()
    from stillpoint.engine.report import _outcome_text, _qc_text, write_report
    d = next(x for x in run.days if x["date"] != "all")
    text = _outcome_text(d)
    assert text == (f"\nMVPA {float(d[f'min_mvpa_{KEY}']):.0f} min\nsteps "
                    f"{int(d['steps_verisense_original']):,} / "
                    f"{int(d['steps_verisense_rowlands2022']):,}")
    assert _outcome_text({"date": "x", "wear_hours": "3"}) == ""
    assert "steps per day (Verisense algorithm): original / rowlands2022 parameters" in \
        _qc_text({"summary": {}}, run.days)
    out = write_report(run.dir / "a.mcap", out_png=tmp_path / "r.png", out_html=tmp_path / "r.html")
    page = (tmp_path / "r.html").read_text()
    assert "steps_verisense_rowlands2022" in page and f"bout_min_mvpa_10m_{KEY}" in page
    assert out["report"] == str(tmp_path / "r.png")


def test_report_outcome_lines_fit_a_14_day_page():
    _need_matplotlib()
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from stillpoint.engine import report
    n_day, per = 14, 17280
    dates = [f"2025-03-{3 + i:02d}" for i in range(n_day)]
    hour = np.tile(np.arange(per) * 5 / 3600, n_day)
    ep = {"dates": dates, "date": np.repeat(dates, per), "hour": hour,
          "enmo_mg": np.full(n_day * per, 30.0), "temp_c": np.zeros(0), "temp_local": np.zeros(0)}
    for k in report._FLAG_COLUMNS:
        ep[k] = np.zeros(n_day * per, bool)
    days = [{"date": d, "valid_day": "0", "day_hours": "23", "wear_hours": "20.5",
             "timezone": "Europe/London", f"min_mvpa_{KEY}": "135.2",
             "steps_verisense_original": "123,456".replace(",", ""),
             "steps_verisense_rowlands2022": "110234"} for d in dates]
    fig = report._draw(plt, ep, days, None, None, {"summary": {}}, "t", 5.0)
    try:
        fig.canvas.draw()
        r = fig.canvas.get_renderer()
        boxes = [t.get_window_extent(r) for t in fig.findobj(
            lambda o: hasattr(o, "get_text") and hasattr(o, "get_window_extent"))
            if "steps" in (t.get_text() or "")]
        assert len(boxes) == n_day
        assert not any(a.overlaps(b) for i, a in enumerate(boxes) for b in boxes[i + 1:])
        assert all(b.x1 <= fig.bbox.x1 + 1 for b in boxes)
    finally:
        plt.close(fig)


def test_export_from_the_mcap_gives_the_same_outcome_tables(run, tmp_path):
    out = tmp_path / "x.days.csv"
    r = subprocess.run([sys.executable, "-m", "stillpoint", "export", str(run.dir / "a.mcap"),
                        "-o", str(out), "--table", "days", "--cutpoints", KEY, "--steps",
                        "--impute", "--valid-day-hours", "4"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert out.read_text() == run.d_text


def test_cli_outcome_options_parse():
    from stillpoint.tools import cli
    from stillpoint.tools.cli.commands._outcomeopts import outcome_settings

    def parse(*extra):
        argv = ["process", "rec.cwa", *extra]
        return outcome_settings(cli.build_parser(cli._only_requested(argv)).parse_args(argv))

    assert not parse().active
    o = parse("--cutpoints", KEY, "--steps", "--step-sets", "rowlands2022", "--bout-minutes",
              "2,10", "--bout-criterion", "0.9", "--impute")
    assert (o.cutpoints, o.steps, o.bout_minutes, o.bout_criterion, o.impute) == \
        (KEY, ("rowlands2022",), (2.0, 10.0), 0.9, True)
    assert parse("--steps").steps == SETS
    assert parse("--step-sets", "original").steps == ()  # sets without --steps count nothing
    r = subprocess.run([sys.executable, "-m", "stillpoint", "process", "rec.cwa", "--step-sets",
                        "bad"], capture_output=True, text=True)
    assert r.returncode == 2 and "Verisense parameter sets are original, rowlands2022" in r.stderr
