"""Sleep on the epoch stream: SIB streaming rules, the guider order with a sleep log, the sleep-log
formats and their refusals, bounded memory, and the nights table from ``process``."""

from __future__ import annotations

import datetime as _dt

import numpy as np
import pytest

from stillpoint.engine.sim.sleep import SleepSpec, sleep_scenario
from stillpoint.engine.sleep import SibStream, SleepLogError, SleepOptions, SleepStage, read_sleep_log
from stillpoint.engine.sleep.diary import night_times
from stillpoint.engine.tables.epochs import EpochRows


def _rows(s, a, b):
    z = np.zeros(b - a, bool)
    return EpochRows(s.t_ns[a:b], np.full(b - a, 500), s.enmo[a:b], z * 0.0, z * 0.0, s.anglez[a:b],
                     z * 0.0, s.nonwear[a:b], z.copy(), z.copy(), z.copy(), z.copy())


def _run(s, options=None, chunk=1000, watch=None):
    st = SleepStage(s.zone, 5.0, options or SleepOptions())
    out = []
    for a in range(0, s.t_ns.shape[0], chunk):
        out += st.push(_rows(s, a, min(a + chunk, s.t_ns.shape[0])))
        if watch is not None:
            watch.append(st.n - st.base)
    out += st.flush()
    return st, out


# ---------------------------------------------------------------- SIB rules
def test_sib_bout_covers_both_changes_and_needs_more_than_5_min():
    a = np.zeros(400)
    a[10:] = 20.0  # change at epoch 9
    a[71:] = 40.0  # change at epoch 70: 61 epochs later -> bout 9..70
    a[131:] = 60.0  # change at 130: 60 epochs later -> no bout
    a[300:] = 0.0  # change at 299: bout 130..299
    a[301:] = 30.0  # change at 300 (1 later)
    s = SibStream()
    got = np.concatenate([s.push(a), s.flush()])
    want = np.zeros(400, np.int8)
    want[9:71] = 1
    want[130:300] = 1
    np.testing.assert_array_equal(got, want)


def test_sib_fallback_whole_recording_without_changes_is_sib():
    s = SibStream()
    got = np.concatenate([s.push(np.zeros(500)), s.flush()])
    assert got.tolist() == [1] * 500


def test_sib_release_bounds_an_endless_still_stretch():
    a = np.concatenate([np.tile([0.0, 30.0], 50), np.zeros(5000)])
    s = SibStream()
    s.push(a)
    assert s.pending() > 4000
    got = s.release(5000)
    assert s.pending() == a.shape[0] - 5000
    assert got[-1] == 1  # still for more than 5 min: a bout once a later change comes


# ---------------------------------------------------------------- nights
def test_daysleeper_and_dst_nights_are_flagged():
    s = sleep_scenario(SleepSpec("2026-03-25T10:00:00", "Europe/London", 6.0, seed=3,
                                 daysleeper_nights=(1,)))
    st, _ = _run(s)
    by = {n.date.isoformat(): n for n in st.nights}
    assert by["2026-03-28"].dst and not by["2026-03-27"].dst
    assert by["2026-03-28"].window_hours == 23.0
    assert by["2026-03-26"].daysleeper
    t = {x["night"]: x for x in s.truth}
    wake = s.t_ns[0] + by["2026-03-26"].spt[1] * 5 * 10**9
    assert abs(wake - t["2026-03-26"]["wake_ns"]) < 15 * 60 * 10**9  # wakes in the afternoon


def test_sleep_log_guides_and_missing_night_falls_back_to_hdcza(tmp_path):
    s = sleep_scenario(SleepSpec("2026-05-04T09:00:00", "UTC", 4.0, seed=21))
    log = tmp_path / "log.csv"
    # basic format; night 2 missing; night 1 a diary that differs from the data by an hour
    log.write_text("ID,onset_N1,wakeup_N1,onset_N2,wakeup_N2,onset_N3,wakeup_N3\n"
                   "p1,22:00:00,08:30:00,NA,NA,23:00,07:00\n")
    opts = SleepOptions(sleep_log=read_sleep_log(log, "p1"))
    st, _ = _run(s, opts)
    g = {n.date.isoformat(): n.guider for n in st.nights}
    assert g["2026-05-04"] == "sleeplog" and g["2026-05-05"] == "HDCZA" and g["2026-05-06"] == "sleeplog"
    n1 = [n for n in st.nights if n.date == _dt.date(2026, 5, 4)][0]
    g0 = s.t_ns[0] + n1.guider_span[0] * 5 * 10**9
    assert g0 == int(_dt.datetime(2026, 5, 4, 22, tzinfo=_dt.timezone.utc).timestamp()) * 10**9


def test_memory_is_bounded_over_two_weeks():
    s = sleep_scenario(SleepSpec("2026-01-05T10:00:00", "UTC", 14.0, seed=5))
    held = []
    st, out = _run(s, chunk=720, watch=held)
    assert len(st.nights) >= 13
    assert max(held) <= 31 * 720 + 720  # noon to noon + 6 h, plus one step
    assert sum(len(r) for r, _, _ in out) == s.t_ns.shape[0]


@pytest.mark.parametrize("chunk", [1000, 53])
def test_columns_do_not_depend_on_the_cut(chunk):
    s = sleep_scenario(SleepSpec("2026-03-25T10:00:00", "Europe/London", 3.0, seed=8))
    _, a = _run(s, chunk=4096)
    _, b = _run(s, chunk=chunk)
    for k in (1, 2):
        np.testing.assert_array_equal(np.concatenate([x[k] for x in a]), np.concatenate([x[k] for x in b]))


# ---------------------------------------------------------------- sleep logs
def test_night_times_follow_ggirs_daysleeper_rule():
    d = _dt.date(2026, 5, 4)
    assert night_times(d, 23.0, 7.0) == (_dt.datetime(2026, 5, 4, 23), _dt.datetime(2026, 5, 5, 7))
    assert night_times(d, 3.0, 17.0) == (_dt.datetime(2026, 5, 5, 3), _dt.datetime(2026, 5, 5, 17))
    assert night_times(d, 1.5, 9.0) == (_dt.datetime(2026, 5, 5, 1, 30), _dt.datetime(2026, 5, 5, 9))


def test_advanced_sleep_log_matched_by_id_and_date(tmp_path):
    log = tmp_path / "adv.csv"
    log.write_text("ID,D1_date,D1_wakeup,D1_onset,D1_nap1_start,D2_date,D2_wakeup,D2_onset\n"
                   "other,2026-05-04,07:00,23:00,,2026-05-05,07:00,23:00\n"
                   "p1,2026-05-04,07:00,22:15,13:00,2026-05-05,06:45,23:00\n")
    sl = read_sleep_log(log, "p1")
    assert sl.fmt == "advanced"
    assert sl.resolve(_dt.date(2026, 5, 4)) == {
        _dt.date(2026, 5, 4): (_dt.datetime(2026, 5, 4, 22, 15), _dt.datetime(2026, 5, 5, 6, 45))}


def test_sleep_log_refusals_name_the_row(tmp_path):
    log = tmp_path / "bad.csv"
    log.write_text("ID,onset_N1,wakeup_N1\nx,23:00,07:00\np1,25:61,07:00\n")
    with pytest.raises(SleepLogError, match=r"bad.csv row 3.*'25:61' is not a clock time"):
        read_sleep_log(log, "p1")
    with pytest.raises(SleepLogError, match=r"no row for participant 'nobody'.*x, p1"):
        read_sleep_log(log, "nobody")
    adv = tmp_path / "adv.csv"
    adv.write_text("ID,D1_date,D1_wakeup,D1_onset\np1,4 May,07:00,23:00\n")
    with pytest.raises(SleepLogError, match=r"row 2, column 'D1_date'.*not a date"):
        read_sleep_log(adv, "p1")


def test_cohort_collates_nights_tables(tmp_path):
    from stillpoint.engine.cohort.collate import Collation, _stacked
    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir()
    b.mkdir()
    (a / "recording.nights.csv").write_text("night,guider,spt_hours\n2026-05-04,HDCZA,7.5\n"
                                            "2026-05-05,sleeplog,8\n")
    out = Collation(rows=[{"participant": "p1", "file": "a.cwa", "key": "k1", "folder": str(a)},
                          {"participant": "p2", "file": "b.cwa", "key": "k2", "folder": str(b)}])
    cols, nights = _stacked(out, ".nights.csv", "nights table")
    assert cols == ["night", "guider", "spt_hours"] and not out.failures
    assert [(n["participant"], n["night"], n["guider"]) for n in nights] == [
        ("p1", "2026-05-04", "HDCZA"), ("p1", "2026-05-05", "sleeplog")]


def test_report_draws_sleep_and_its_legend_fits():
    pytest.importorskip("matplotlib", reason="the report's plots need matplotlib (optional extra)")
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from stillpoint.engine import report
    n_day, per = 3, 17280
    dates = [f"2025-03-{3 + i:02d}" for i in range(n_day)]
    hour = np.tile(np.arange(per) * 5 / 3600, n_day)
    ep = {"dates": dates, "date": np.repeat(dates, per), "hour": hour,
          "enmo_mg": np.full(n_day * per, 20.0), "temp_local": np.zeros(0, "M8[s]"),
          "temp_c": np.zeros(0)}
    for k in report._FLAG_COLUMNS:
        ep[k] = np.zeros(n_day * per, bool)
    ep["spt"] = (hour >= 23) | (hour < 7)
    ep["sib"] = ep["spt"] & (hour % 1 < 0.8)
    days = [{"date": d, "valid_day": "1", "day_hours": "24", "wear_hours": "24"} for d in dates]
    fig = report._draw(plt, ep, days, None, None, {"summary": {}}, "title", 5.0)
    fig.canvas.draw()
    r = fig.canvas.get_renderer()
    ax = fig.axes[0]
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert "sleep period" in labels and "inactivity bout" in labels
    lb, fb, tb = ax.get_legend().get_window_extent(r), fig.bbox, ax.title.get_window_extent(r)
    assert lb.x0 >= fb.x0 and lb.x1 <= fb.x1
    assert not (lb.x0 < tb.x1 and tb.x0 < lb.x1 and lb.y0 < tb.y1 and tb.y0 < lb.y1)
    spans = [p for p in ax.patches if abs(p.get_facecolor()[3] - 0.25) < 1e-6]
    assert len(spans) == 2  # the first day: 00-07 h and 23-24 h
    plt.close(fig)


def test_guider_falls_back_to_l5_when_hdcza_has_no_window():
    from stillpoint.engine.sleep import HdczaOptions
    s = sleep_scenario(SleepSpec("2026-05-04T09:00:00", "UTC", 4.0, seed=31))
    a = int(_dt.datetime(2026, 5, 5, 12, tzinfo=_dt.timezone.utc).timestamp()) * 10**9
    # the whole noon-to-noon window of the night of 2026-05-05 flagged nonwear; nonwear counted
    # as movement (GGIR's HASPT.ignore.invalid = TRUE), so HDCZA finds nothing there
    s.nonwear[:] = (s.t_ns >= a) & (s.t_ns <= a + 86400 * 10**9)
    st, _ = _run(s, SleepOptions(hdcza=HdczaOptions(ignore_invalid=True)))
    g = {n.date.isoformat(): n.guider for n in st.nights}
    assert g["2026-05-05"] == "L512" and g["2026-05-04"] == "HDCZA" and g["2026-05-06"] == "HDCZA"
    n = [x for x in st.nights if x.guider == "L512"][0]
    assert n.guider_span[1] - n.guider_span[0] == 12 * 720  # L5's centre +- 6 h


@pytest.mark.parametrize("chunk", [997, 4096])
def test_tap_bouts_are_the_sib_runs_whatever_the_cut(chunk, tmp_path):
    from types import SimpleNamespace
    from stillpoint.engine.sleep.tap import SleepTap
    s = sleep_scenario(SleepSpec("2026-03-25T10:00:00", "Europe/London", 3.0, seed=8))
    ts = SimpleNamespace(nights_path=tmp_path / "n.csv", zone=s.zone, sleep=SleepOptions())
    tap = SleepTap(ts, 5.0)
    out = []
    n = s.t_ns.shape[0]
    for a in range(0, n, chunk):
        out += tap.feed([(_rows(s, a, min(a + chunk, n)), ["x"], None)], False)
    out += tap.feed([], True)
    assert sum(len(r) for r, _, _ in out) == n and all(x[0] == "x" for _, x, _ in out)
    sib = np.array([c == "1" for _, x, _ in out for c in x[2]])
    d = np.diff(np.concatenate([[0], sib.astype(np.int8), [0]]))
    runs = [(int(s.t_ns[a]), int(s.t_ns[0]) + int(b) * 5 * 10**9)
            for a, b in zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1))]
    assert tap.bouts == runs and len(runs) > 10
