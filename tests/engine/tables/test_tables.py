"""Epoch and day tables: nonwear against the simulator's labels, a DST day, day sums = epoch sums,
reader-flagged data kept out of the means (real AX6 file), block-cut invariance, time zones."""

import csv
import gzip
import os
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from stillpoint.engine.operators.anglez import AnglezOperator, anglez_deg, first_subsample, hold_angles
from stillpoint.engine.run import RunSettings, process_file
from stillpoint.engine.sim import simulate_recording
from stillpoint.engine.sim.truth import load_labels
from stillpoint.engine.sim.wearer import WearerParams
from stillpoint.engine.tables import TablesSettings, table_paths
from stillpoint.engine.tables.epochs import fold_sums, sums_between
from stillpoint.engine.timezones import UNKNOWN_LABEL, ZoneError, parse_zone

REAL = os.environ.get("STILLPOINT_REAL_DATA")


def read_epochs(path):
    with gzip.open(path, "rt") as f:
        return list(csv.DictReader(f))


def read_days(path):
    with open(path) as f:
        return list(csv.DictReader(f))


def t_ns(iso_z):
    return np.array([np.datetime64(s[:-1], "ns").astype(np.int64) for s in iso_z])


def run_tables(src, out, settings=None, **kw):
    ep, dp = table_paths(out)
    s = process_file(src, out, settings or RunSettings(), tables=TablesSettings(ep, dp, **kw))
    return s, read_epochs(ep), read_days(dp)


@pytest.fixture(scope="module")
def dst_run(tmp_path_factory):
    """36 h across the spring DST change in London (29 March 2026), with a drawer period."""
    d = tmp_path_factory.mktemp("dst")
    rec = d / "dst.cwa"
    simulate_recording(rec, days=1.5, hz=12.5, seed=5, start="2026-03-28T12:00:00",
                       wearer=WearerParams(drawer_per_day=1.0, shower_per_day=0.0),
                       effects="offset,gain,noise")
    s, epochs, days = run_tables(rec, d / "dst.mcap", RunSettings(timezone="Europe/London"))
    return SimpleNamespace(dir=d, rec=rec, summary=s, epochs=epochs, days=days)


def test_dst_day_has_23_hours(dst_run):
    by_date = {r["date"]: r for r in dst_run.days}
    assert float(by_date["2026-03-29"]["day_hours"]) == 23.0
    assert float(by_date["2026-03-29"]["recorded_hours"]) == pytest.approx(23.0)
    assert float(by_date["2026-03-28"]["day_hours"]) == 24.0
    # local time jumps from +00:00 to +01:00 at 01:00 UTC
    local = {r["time_utc"]: r["time_local"] for r in dst_run.epochs}
    assert local["2026-03-29T00:59:55Z"] == "2026-03-29T00:59:55+00:00"
    assert local["2026-03-29T01:00:00Z"] == "2026-03-29T02:00:00+01:00"
    assert dst_run.summary["timezone"] == "Europe/London"


def test_nonwear_agrees_with_the_simulated_labels(dst_run):
    lab = load_labels(dst_run.rec.with_name("dst.labels.csv"))
    t = np.asarray(lab["device_start_ns"], np.int64)  # device clock = UTC here (GMT at set-up)
    off = np.asarray(lab["activity"]) <= 1  # nonwear_table, nonwear_drawer
    e = dst_run.epochs
    ts = t_ns([r["time_utc"] for r in e])
    flagged = np.array([r["nonwear"] == "1" for r in e])
    gap = np.array([r["gap"] == "1" for r in e])
    i = np.clip(np.searchsorted(t, ts, side="right") - 1, 0, len(t) - 1)
    truth = off[i]
    changes = t[np.flatnonzero(np.diff(off.astype(np.int8))) + 1]
    assert len(changes) >= 2, "the simulation must hold a nonwear period"
    dist = np.min(np.abs(ts[:, None] - changes[None, :]), axis=1)
    far = (dist > 3600 * 10**9) & ~gap & (ts > t[0] + 3600 * 10**9) & (ts < t[-1] - 3600 * 10**9)
    assert truth[far].sum() > 100 and (~truth[far]).sum() > 1000
    agreement = (flagged[far] == truth[far]).mean()
    assert agreement >= 0.99, agreement


def test_day_sums_equal_epoch_sums(dst_run):
    e = dst_run.epochs
    flags = ("nonwear", "clipping", "gap", "qc", "filter_warmup")
    clean = np.array([all(r[f] == "0" for f in flags) for r in e])
    date = np.array([r["time_local"][:10] for r in e])
    enmo = np.array([float(r["enmo_mg"]) if r["enmo_mg"] else np.nan for r in e])
    mad = np.array([float(r["mad_mg"]) if r["mad_mg"] else np.nan for r in e])
    h = 5.0 / 3600
    rows = [r for r in dst_run.days if r["date"] != "all"]
    for r in rows:
        sel = date == r["date"]
        assert float(r["recorded_hours"]) == pytest.approx(sel.sum() * h, abs=1e-3)
        assert float(r["wear_hours"]) == pytest.approx((sel & clean).sum() * h, abs=1e-3)
        assert float(r["enmo_mean_mg"]) == pytest.approx(enmo[sel & clean].mean(), rel=1e-4)
        assert float(r["mad_mean_mg"]) == pytest.approx(mad[sel & clean].mean(), rel=1e-4)
        bands = [k for k in r if k.startswith("min_enmo_")]
        assert sum(float(r[k]) for k in bands) == pytest.approx((sel & clean).sum() * 5 / 60, abs=0.01)
    total = dst_run.days[-1]
    assert total["date"] == "all"
    assert float(total["wear_hours"]) == pytest.approx(clean.sum() * h, abs=1e-3)
    assert float(total["enmo_mean_mg"]) == pytest.approx(enmo[clean].mean(), rel=1e-4)
    assert float(total["mad_mean_mg"]) == pytest.approx(mad[clean].mean(), rel=1e-4)
    assert int(total["valid_day"]) == sum(int(r["valid_day"]) for r in rows)
    assert int(total["valid_day"]) >= 1


@pytest.fixture(scope="module")
def small_run(tmp_path_factory):
    """2.4 h with logging restarts (gaps), zone unknown."""
    d = tmp_path_factory.mktemp("small")
    rec = d / "r.cwa"
    simulate_recording(rec, days=0.1, hz=12.5, seed=2, effects="offset,noise,restarts",
                       truth_path=False, labels_path=False)
    s, e, days = run_tables(rec, d / "a.mcap", RunSettings(max_block_s=600.0))
    return SimpleNamespace(dir=d, rec=rec, summary=s, epochs=e, days=days)


def test_rows_cover_the_span_with_gap_rows(small_run, tmp_path):
    """A restart gap becomes flagged rows; the first epoch after each segment start carries the
    BFEN start-up flag; tables do not depend on the pipeline's block size."""
    e1, d1 = small_run.epochs, small_run.days
    s2, e2, d2 = run_tables(small_run.rec, tmp_path / "b.mcap", RunSettings(max_block_s=7.3))
    assert e1 == e2 and d1 == d2
    t = t_ns([r["time_local"] + "Z" for r in e1])  # zone unknown: time_local is the device clock
    assert np.all(np.diff(t) == 5 * 10**9)
    assert "time_utc" not in e1[0] and d1[0]["timezone"] == UNKNOWN_LABEL  # no UTC column
    gaps = [r for r in e1 if r["gap"] == "1"]
    assert any(r["n"] == "0" and r["enmo_mg"] == "" for r in gaps)
    warm = [i for i, r in enumerate(e1) if r["filter_warmup"] == "1"]
    assert warm and warm[0] <= 1 and len(warm) < len(e1) // 10


def test_a_gap_of_weeks_is_written_a_slice_at_a_time(tmp_path, monkeypatch):
    """Two 20-minute stretches 40 days apart: the ~690,000 gap rows between them are built and
    written in slices of at most ROWS_PER_SLICE (they were one array: 2.8 GB for a year's gap),
    and the table is the same whatever the slice size."""
    import stillpoint.engine.tables.epochs as epochs_mod
    import stillpoint.engine.tables.writer as writer_mod
    from stillpoint.drivers.cwa import CwaWriter
    rec = tmp_path / "gap.cwa"
    rng = np.random.default_rng(0)
    with CwaWriter(rec, device_type="AX3", rate_hz=12.5, range_g=8, packed=False) as w:
        for base in (1_700_000_000 * 10**9, (1_700_000_000 + 40 * 86400) * 10**9):
            n = int(1200 * 12.5)
            a = rng.integers(-3, 4, size=(n, 3)).astype(np.int32)
            a[:, 2] += 256
            w.write(base + np.arange(n, dtype=np.int64) * 80_000_000, a, temperature_raw=300,
                    light_raw=0, battery_raw=190)
    sizes = []
    real = writer_mod.format_rows

    def spy(rows, *a, **k):
        sizes.append(len(rows))
        return real(rows, *a, **k)

    monkeypatch.setattr(writer_mod, "format_rows", spy)
    _s, e1, d1 = run_tables(rec, tmp_path / "a.mcap", RunSettings(calibrate=False))
    assert len(e1) > 40 * 17280 and max(sizes) <= epochs_mod.ROWS_PER_SLICE
    assert len(d1) >= 41 and sum(r["gap"] == "1" for r in e1) > 40 * 17000
    monkeypatch.setattr(epochs_mod, "ROWS_PER_SLICE", 1000)
    _s, e2, d2 = run_tables(rec, tmp_path / "b.mcap", RunSettings(calibrate=False))
    assert e1 == e2 and d1 == d2


def test_epochs_the_table_cannot_hold_are_counted_and_said(tmp_path, capsys):
    """A restart that sends the clock back a day: the log holds both hours, the table (written in
    time order as the run goes) only the first; the summary counts the epochs left out and the
    text summary says so, instead of losing them silently."""
    from stillpoint.drivers.cwa import CwaWriter
    from stillpoint.tools.cli import main as cli
    rng = np.random.default_rng(1)
    parts = []
    for name, base in (("a.cwa", 1_704_067_200), ("b.cwa", 1_704_067_200 - 86400)):
        with CwaWriter(tmp_path / name, device_type="AX3", rate_hz=12.5, range_g=8,
                       packed=False) as w:
            n = int(3600 * 12.5)
            a = rng.integers(-30, 31, size=(n, 3)).astype(np.int32)
            a[:, 2] += 256
            w.write(base * 10**9 + np.arange(n, dtype=np.int64) * 80_000_000, a,
                    temperature_raw=300, light_raw=0, battery_raw=190)
        parts.append((tmp_path / name).read_bytes())
    rec = tmp_path / "back.cwa"
    rec.write_bytes(parts[0] + parts[1][1024:])  # the second session's sectors after the first's
    s, e, _days = run_tables(rec, tmp_path / "back.mcap", RunSettings(calibrate=False))
    assert s["epochs"] == 1440 and len(e) == 720
    assert s["tables"]["epochs_not_in_table"] == 720
    assert cli(["process", str(rec), "-o", str(tmp_path / "c.mcap"), "--no-calibrate"]) == 0
    assert "warning: 720 epochs are in the MCAP log but not in the tables" in capsys.readouterr().out
    s2, _e, _d = run_tables(tmp_path / "a.cwa", tmp_path / "a.mcap", RunSettings(calibrate=False))
    assert "epochs_not_in_table" not in s2["tables"]  # only said when it happens


@pytest.mark.skipif(not REAL, reason="STILLPOINT_REAL_DATA is not set: real-recording test skipped")
def test_reader_flagged_sectors_stay_out_of_the_means(tmp_path):
    """GGIRread's AX6 file: sectors 0-25 hold gyro in the accel slots (the reader flags them)."""
    path = Path(REAL) / "ax6_ggirread_testfile_100hz_16g_gyro250dps.cwa"
    s, e, days = run_tables(path, tmp_path / "ax6.mcap")
    qc = [r for r in e if r["qc"] == "1"]
    assert 2 <= len(qc) <= 4 and e.index(qc[0]) == 0  # ~10.4 s of data from the first sector
    flags = ("nonwear", "clipping", "gap", "qc", "filter_warmup")
    clean = [float(r["enmo_mg"]) for r in e if all(r[f] == "0" for f in flags)]
    with_qc = clean + [float(r["enmo_mg"]) for r in qc]
    day = days[0]
    assert float(day["enmo_mean_mg"]) == pytest.approx(np.mean(clean), rel=1e-4)
    assert np.mean(clean) != pytest.approx(np.mean(with_qc), rel=1e-3)
    assert float(day["qc_hours"]) == pytest.approx(len(qc) * 5 / 3600, abs=1e-4)
    assert s["tables"]["flags"]["qc"] == len(qc)


# ---------------------------------------------------------------------------- anglez
RATE = 50.0


def _anglez_run(t, a, cuts):
    op = AnglezOperator(RATE)
    out = []
    b = [0] + sorted(cuts) + [len(t)]
    for i, j in zip(b[:-1], b[1:]):
        if j > i:
            out.append(op.push(SimpleNamespace(time_ns=t[i:j], accel=a[i:j], segment=0)))
    out.append(op.flush())
    return [np.concatenate([o[k] for o in out]) for k in range(3)]


def _signal():
    rng = np.random.default_rng(4)
    n = 9000
    t = (1_700_000_003 * 10**9 + np.arange(n) * 20_000_000).astype(np.int64)
    return t, rng.normal(0, 0.3, (n, 3)) + [0.2, 0.3, 0.8]


def test_anglez_is_ggirs_definition():
    t, a = _signal()
    s, n, v = _anglez_run(t, a, [])
    step, _k, h = 5, 51, 25  # 50 Hz -> every 5th sample (10 Hz), 5 s median = 51 subsamples
    sub = a[::step]
    med = np.array([np.median(sub[q - h:q + h + 1], axis=0) if h <= q < len(sub) - h else [np.nan] * 3
                    for q in range(len(sub))])
    med[:h], med[len(sub) - h:] = med[h], med[len(sub) - h - 1]
    per_sample = anglez_deg(med)[np.arange(len(t)) // step]
    e = t // (5 * 10**9)
    ref = np.array([per_sample[e == u].mean() for u in np.unique(e)])
    np.testing.assert_allclose(v, ref, atol=1e-9)
    assert n.sum() == len(t)


@settings(max_examples=10, deadline=None)
@given(st.lists(st.integers(0, 9000), max_size=30))
def test_anglez_block_cut_invariance(cuts):
    t, a = _signal()
    ref = _anglez_run(t, a, [])
    got = _anglez_run(t, a, cuts)
    for x, y in zip(ref, got):
        np.testing.assert_array_equal(x, y)


def _day_rows(n=3 * 17280 + 999, seed=5):
    """Three days and a bit of 5 s epoch rows with ENMO/MAD of many magnitudes, some not clean."""
    from stillpoint.engine.tables.epochs import EpochRows
    rng = np.random.default_rng(seed)
    t = np.datetime64("2025-03-03T10:00:00", "ns").astype(np.int64) + np.arange(n) * 5_000_000_000
    e = rng.lognormal(2.0, 2.0, n)
    z = np.zeros(n, bool)
    nonwear = rng.random(n) < 0.1
    return EpochRows(t, np.full(n, 500), e, e * 0.5, e * 1.3, z * 0.0, z * 0.0, nonwear, z, z, z, z)


@settings(max_examples=25, deadline=None)
@given(st.lists(st.integers(1, 3 * 17280 + 998), max_size=40))
def test_day_table_totals_do_not_depend_on_how_the_rows_came(cuts):
    """The file row's means are the same numbers, bit for bit, however the epoch rows were cut
    into pushes (a pass's step: an online run's tables come from a pass with longer steps)."""
    from stillpoint.engine.tables.days import DayAccumulator, _slice
    rows = _day_rows()
    ref = DayAccumulator(parse_zone("UTC"), 5.0)
    ref.push(rows)
    ref.close()
    acc = DayAccumulator(parse_zone("UTC"), 5.0)
    edges = [0] + sorted(set(cuts)) + [len(rows)]
    for a, b in zip(edges[:-1], edges[1:]):
        acc.push(_slice(rows, a, b))
    acc.close()
    want, got = ref.summary(), acc.summary()
    assert got["enmo_mean_mg"] == want["enmo_mean_mg"] and got["mad_mean_mg"] == want["mad_mean_mg"]
    assert got == want


@settings(max_examples=200, deadline=None)
@given(st.integers(1, 12), st.integers(1, 40), st.integers(0, 30), st.integers(0, 300), st.integers(1, 300))
def test_hold_angles_is_the_per_sample_lookup(step, m, a0, p0, n):
    """Each sample holds the angle of its subsample position, the nearest end outside the known ones."""
    angle = np.arange(m, dtype=np.float64) + 0.5
    p1 = p0 + n
    ref = angle[np.clip(np.arange(p0, p1) // step - a0, 0, m - 1)]
    np.testing.assert_array_equal(hold_angles(angle, a0, p0, p1, step), ref)
    off = first_subsample(p0, step)
    assert (p0 + off) % step == 0 and 0 <= off < step


@settings(max_examples=200, deadline=None)
@given(st.lists(st.lists(st.tuples(st.integers(0, 12), st.sampled_from([0.1, 1.7, -2.3, 0.0, -0.0, 1e16])),
                         max_size=8), max_size=6))
def test_fold_sums_adds_each_epochs_parts_in_arrival_order(pushes):
    """Epochs seen again (a segment break inside an epoch, or out of order) are summed part by part
    in the order the parts arrived, as a running total per epoch would; signed zeros are kept."""
    ref = {}
    idx, sums = np.zeros(0, np.int64), np.zeros((0, 2))
    for rows in pushes:
        for k, v in rows:
            if k in ref:
                ref[k] = [ref[k][0] + 1.0, ref[k][1] + v]
            else:
                ref[k] = [1.0, v]
        new_idx = np.array([k for k, _ in rows], np.int64)
        new = np.array([[1.0, v] for _, v in rows]).reshape(-1, 2)
        idx, sums = fold_sums(idx, sums, new_idx, new)
    assert idx.tolist() == sorted(ref)
    got = {int(k): s.tolist() for k, s in zip(idx, sums)}
    for k, v in ref.items():
        assert got[k] == v and all(np.signbit(a) == np.signbit(b) for a, b in zip(got[k], v))
    at, part = sums_between(idx, sums, 3, 9)
    assert (at + 3).tolist() == [k for k in sorted(ref) if 3 <= k < 9] and part.shape == (len(at), 2)


def test_epoch_row_text():
    """Fixed decimals, empty cells for values that are not finite, flags as 0/1, ``corrected``
    last (zone unknown: no UTC time, the device clock as local time)."""
    from stillpoint.engine.tables.epochs import EpochRows
    from stillpoint.engine.tables.writer import format_rows
    f = np.array([True, False])
    rows = EpochRows(np.array([0, 5 * 10**9]), np.array([500, 0]), np.array([1.23456, np.nan]),
                     np.array([-0.0, np.inf]), np.array([1e17, -np.inf]), np.array([-0.0004, 45.0]),
                     np.array([25.125, np.nan]), f, ~f, f, ~f, f)
    assert format_rows(rows, parse_zone(None), 5 * 10**9) == (
        "1970-01-01T00:00:00,500,1.235,-0.000,100000000000000000.000,-0.000,25.12,1,0,1,0,1,1\n"
        "1970-01-01T00:00:05,0,,,,45.000,,0,1,0,1,0,0\n")  # zone unknown: no UTC column
    # ``corrected``: 1 on rows with samples when an estimate was applied, else 0
    assert format_rows(rows, parse_zone(None), 5 * 10**9, corrected=False).split("\n")[0].endswith(
        ",1,0,1,0,1,0")


# ---------------------------------------------------------------------------- time zones
def test_zones():
    z = parse_zone("Europe/London")
    t = np.array([1774745999, 1774746000]) * 10**9  # 2026-03-29 00:59:59 / 01:00:00 UTC
    assert z.offsets_s(t).tolist() == [0, 3600]
    assert z.device_offset_s(1782900000) == 3600  # a clock set in British summer time
    f = parse_zone("+05:30")
    assert f.fixed_s == 19800 and not f.iana and f.label == "+05:30"
    assert parse_zone(None).label == UNKNOWN_LABEL
    with pytest.raises(ZoneError):
        parse_zone("Mars/Olympus_Mons")


def test_cli_bad_zone_is_one_line(small_run, tmp_path):
    """A readable recording with an unknown zone: one line naming the zone, exit 2, nothing written
    (an unreadable recording is reported first, as the input is checked before the options)."""
    out = tmp_path / "z.mcap"
    r = subprocess.run([sys.executable, "-m", "stillpoint.tools", "process", str(small_run.rec), "-o",
                        str(out), "--timezone", "Nowhere/Land"], capture_output=True, text=True)
    assert r.returncode == 2 and "Nowhere/Land" in r.stderr and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and not out.exists()


def test_export_from_the_mcap_gives_the_same_tables(small_run):
    """An MCAP export says what it wants (--table or --topic): the output's name never decides."""
    def export(*args):
        return subprocess.run([sys.executable, "-m", "stillpoint.tools", "export",
                               str(small_run.dir / "a.mcap"), *map(str, args)],
                              capture_output=True, text=True)
    out = small_run.dir / "again.epochs.csv.gz"
    r = export("-o", out)
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "--table epochs|days" in r.stderr
    assert not out.exists()
    r = export("-o", out, "--table", "epochs")
    assert r.returncode == 0, r.stderr
    assert UNKNOWN_LABEL in r.stdout
    assert read_epochs(out) == small_run.epochs
    days = small_run.dir / "again.days.csv"
    assert not days.exists()  # only the table asked for
    r = export("-o", days, "--table", "days")
    assert r.returncode == 0, r.stderr
    assert read_days(days) == small_run.days
    r = export("-o", small_run.dir / "t.csv", "--table", "days", "--topic", "/metrics/epoch")
    assert r.returncode == 2 and "not both" in r.stderr
    assert not list(small_run.dir.glob(".tables-*"))  # the re-run's MCAP is removed
    assert not list(small_run.dir.glob(".again*"))  # nor the table not asked for


def test_report_page_is_written(small_run, tmp_path):
    from stillpoint.engine.report import write_report
    out = write_report(small_run.dir / "a.mcap", out_png=tmp_path / "r.png", out_html=tmp_path / "r.html")
    png = Path(out["report"]).read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 30_000
    page = Path(out["report_html"]).read_text()
    assert "data:image/png;base64," in page and small_run.days[0]["date"] in page


def test_report_reads_the_epoch_table_a_slice_at_a_time(small_run, tmp_path, monkeypatch):
    """The page keeps the rows of the days it draws and the finite temperatures only, whatever
    the cut of the reading; every date is still listed."""
    import stillpoint.engine.report as report
    from stillpoint.engine.tables import table_paths
    ep_path = table_paths(small_run.dir / "a.mcap")[0]
    whole = report._read_epochs(ep_path)
    monkeypatch.setattr(report, "READ_ROWS", 7)
    cut = report._read_epochs(ep_path)
    assert whole["dates"] == cut["dates"] == list(dict.fromkeys(r["time_local"][:10]
                                                               for r in small_run.epochs))
    for k, v in whole.items():
        assert np.array_equal(v, cut[k], equal_nan=v.dtype.kind == "f") if k != "dates" else True, k
    assert len(whole["enmo_mg"]) == len(small_run.epochs)
    temps = [float(r["temperature_c"]) for r in small_run.epochs if r["temperature_c"]]
    assert np.array_equal(whole["temp_c"], temps)
    one = report._read_epochs(ep_path, days_shown=1)  # only the first date's rows are kept
    assert set(one["date"].tolist()) == {whole["dates"][0]}
    assert len(one["temp_c"]) == len(temps)


def test_report_without_matplotlib_says_how_to_install(monkeypatch):
    from stillpoint.engine import report
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    with pytest.raises(report.ReportUnavailableError, match="pip install"):
        report.require_matplotlib()


@pytest.mark.skipif(not REAL, reason="STILLPOINT_REAL_DATA is not set: real-recording test skipped")
def test_cohort_takes_the_zone_and_writes_the_tables(tmp_path):
    rec = Path(REAL) / "ax3_ggirread_testfile_100hz_145blocks.cwa"
    out = tmp_path / "coh"
    r = subprocess.run([sys.executable, "-m", "stillpoint.tools", "cohort", "run", str(rec), "-o", str(out),
                        "--timezone", "Europe/London", "--scheduler", "serial"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    [days] = list(out.glob("files/*/*/recording.days.csv"))
    rows = read_days(days)
    assert rows[0]["timezone"] == "Europe/London" and rows[-1]["date"] == "all"
    e = read_epochs(days.with_name("recording.epochs.csv.gz"))
    assert e[0]["time_local"].endswith("+00:00") and e[0]["time_utc"].endswith("Z")


def test_export_from_an_online_run_gives_the_same_tables(small_run, tmp_path):
    s, e, d = run_tables(small_run.rec, tmp_path / "o.mcap", RunSettings(mode="online"))
    from stillpoint.engine.workflows.tables_from_mcap import tables_from_mcap
    tables_from_mcap(tmp_path / "o.mcap", tmp_path / "x.epochs.csv.gz")
    assert read_epochs(tmp_path / "x.epochs.csv.gz") == e and read_days(tmp_path / "x.days.csv") == d


@pytest.mark.parametrize("m,k", [(51, 51), (52, 51), (400, 51), (1000, 101), (60, 3)])
def test_anglez_medians_are_scipys_median_filter(m, k):
    """The rank kernel called directly gives scipy.ndimage.median_filter's numbers exactly (ties,
    repeated values and NaN-free noise alike), and it is the kernel in use where scipy has it."""
    from scipy.ndimage import median_filter

    from stillpoint.engine.operators import anglez

    rng = np.random.default_rng(m + k)
    sub = np.round(rng.normal(0, 1, (3, m)), 1)  # rounded: many equal values
    sub[1, ::7] = 0.5
    h = k // 2
    want = np.stack([median_filter(sub[j], size=k, mode="nearest")[h:m - h] for j in range(3)])
    got = anglez._medians(sub, k)
    assert got.shape == want.shape and np.array_equal(got, want)
    import scipy
    if tuple(int(p) for p in scipy.__version__.split(".")[:2]) >= (1, 14):
        assert anglez._RANK is not None  # the fast 1-D kernel ships with this scipy


def test_process_does_not_import_scipy_signal_or_ndimage(tmp_path):
    """A process run loads scipy's filter kernels on their own: no scipy.signal or
    scipy.ndimage import (0.35-0.5 s and ~20 MB each at start-up)."""
    from stillpoint.engine.calibration import quantisation

    quantisation._tables()  # the de-biasing tables in the cache (built once per machine)
    rec = tmp_path / "r.cwa"
    simulate_recording(rec, days=0.05, hz=25, seed=2)
    code = ("import sys; from stillpoint.engine.run import RunSettings, process_file; "
            f"process_file({str(rec)!r}, {str(tmp_path / 'o.mcap')!r}, RunSettings()); "
            "print([m for m in ('scipy.signal', 'scipy.ndimage', 'scipy.special') if m in sys.modules])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip().splitlines()[-1] == "[]"
