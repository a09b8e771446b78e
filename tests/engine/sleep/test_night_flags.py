"""Nights and days a study can filter: GGIR's fraction of the night invalid and cleaningcode, the
window cut by the recording's start or end, the night a participant summary keeps; M10/L5 with
GGIR's window starts and on GGIR's imputed epochs."""

from __future__ import annotations

import numpy as np
import pytest

from stillpoint.engine.outcomes.impute import AverageDay, imputed_days
from stillpoint.engine.sim.sleep import SleepSpec, sleep_scenario
from stillpoint.engine.sleep import SleepStage
from stillpoint.engine.sleep.table import night_record
from stillpoint.engine.tables.days import DAY_NS, m_window
from stillpoint.engine.tables.epochs import EpochRows


def _nights(s, chunk=1000):
    st = SleepStage(s.zone, 5.0)
    n = s.t_ns.shape[0]
    for a in range(0, n, chunk):
        b = min(n, a + chunk)
        z = np.zeros(b - a, bool)
        st.push(EpochRows(s.t_ns[a:b], np.full(b - a, 500), s.enmo[a:b], z * 0.0, z * 0.0,
                          s.anglez[a:b], z * 0.0, s.nonwear[a:b], z.copy(), z.copy(), z.copy(),
                          z.copy()))
    st.flush()
    return st, [night_record(x, st.first_ns, 5 * 10**9, s.zone) for x in st.nights]


def test_recording_cut_mid_night_flags_the_last_night():
    # 10:00 on day 0 to 03:00 on day 4: the last night's window is 15 h of 24
    s = sleep_scenario(SleepSpec("2026-05-04T10:00:00", "UTC", 3 + 17 / 24, seed=21))
    st, recs = _nights(s)
    last = recs[-1]
    assert last["window_cut"] == "end"
    # window: 12:00:05 to 02:59:55 (GGIR counts from noon + 1 epoch)
    assert last["fraction_night_invalid"] == pytest.approx((9 * 720 + 1) / 17280, abs=1e-6)
    assert last["cleaningcode"] == 2 and last["night_valid"] == 0
    for r in recs[:-1]:  # the full nights: no sleep log, enough data
        assert (r["window_cut"], r["cleaningcode"], r["night_valid"]) == ("", 1, 1), r
        assert r["fraction_night_invalid"] == 0.0


def test_sleep_period_running_into_the_recording_end_is_not_kept():
    # ends at 05:00: 7 h missing (0.29 < 1/3, GGIR's cleaningcode 1) but the sleep period is cut
    s = sleep_scenario(SleepSpec("2026-05-04T10:00:00", "UTC", 3 + 19 / 24, seed=22))
    st, recs = _nights(s)
    last, night = recs[-1], st.nights[-1]
    assert last["window_cut"] == "end" and last["cleaningcode"] == 1
    assert night.guider_span[1] >= st.n - 1 and last["night_valid"] == 0


def test_nonwear_counts_towards_the_fraction_invalid():
    s = sleep_scenario(SleepSpec("2026-05-04T10:00:00", "UTC", 4.0, seed=23, nonwear_nights=(1,)))
    st, recs = _nights(s)
    by = {r["night"]: (r, n) for r, n in zip(recs, st.nights)}
    r, n = by["2026-05-05"]
    assert n.invalid_epochs == 2 * 720
    assert r["fraction_night_invalid"] == pytest.approx(2 / 24, abs=1e-6)
    assert r["cleaningcode"] == 1 and r["night_valid"] == 1


def test_first_night_of_a_recording_started_after_midnight_is_cut():
    s = sleep_scenario(SleepSpec("2026-06-10T02:00:00", "UTC", 3.0, seed=24))
    st, recs = _nights(s)
    assert recs[0]["window_cut"] == "start"
    assert recs[0]["fraction_night_invalid"] > 1 / 3 and recs[0]["night_valid"] == 0
    assert all(r["window_cut"] == "" for r in recs[1:-1])


def test_m10_l5_windows_start_as_ggirs():
    """g.getM5L5 as g.analyse.perday calls it: starts every 10 min to 23:40, a window past the
    day's end completed from the day's first hours, ties to the middle start. GGIR's figures on
    this day (R: g.getM5L5(e / 1000, 60, 0, 24 + winhr - 1/6, 10, winhr)): L5 1 mg at 19:00,
    M5 50 mg at 07:00, L10 25.5 mg at 16:30, M10 50 mg at 04:30."""
    per_day = 1440
    local = np.arange(per_day, dtype=np.int64) * 60 * 10**9
    e = np.full(per_day, 50.0)
    e[19 * 60:] = 1.0  # quiet only from 19:00
    every = np.ones(per_day, bool)
    assert m_window(e, every, local, 5.0, np.argmin, 60.0) == (pytest.approx(1.0), "19:00")
    assert m_window(e, every, local, 5.0, np.argmax, 60.0) == (pytest.approx(50.0), "07:00")
    assert m_window(e, every, local, 10.0, np.argmin, 60.0) == (pytest.approx(25.5), "16:30")
    assert m_window(e, every, local, 10.0, np.argmax, 60.0) == (pytest.approx(50.0), "04:30")


def test_l5_on_imputed_epochs_finds_the_night_behind_night_nonwear():
    """Night sleep flagged nonwear on one day: on that day's own clean epochs L5 can only sit
    in the evening; on GGIR's imputed epochs (the average day of the other days) it is the night."""
    per_day, days = 1440, 4
    n = per_day * days
    tod = np.arange(n) % per_day
    asleep = (tod < 7 * 60) | (tod >= 23 * 60)
    rng = np.random.default_rng(5)
    e = np.where(asleep, 2.0, 60.0) + rng.uniform(0, 1, n)
    clean = np.ones(n, bool)
    clean[2 * per_day:2 * per_day + 7 * 60] = False  # day 2: the morning's sleep is nonwear
    day0 = 20000
    day = day0 + np.arange(n) // per_day
    av = AverageDay(60.0)
    local = (day0 * DAY_NS) + np.arange(n, dtype=np.int64) * 60 * 10**9
    av.push({"enmo_mg": e, "mad_mg": e}, clean, day, local)
    imp = imputed_days(av)
    av.close()
    import datetime as dt
    d2 = (dt.date(1970, 1, 1) + dt.timedelta(days=day0 + 2)).isoformat()
    sl = slice(2 * per_day, 3 * per_day)
    own = m_window(e[sl], clean[sl], local[sl], 5.0, np.argmin, 60.0)[1]
    assert own >= "17:00"  # the evening: the night's morning hours are missing
    start = imp[d2]["l5_start_imputed"]
    assert "00:00" <= start <= "02:00", start
    assert imp[d2]["l5_mg_imputed"] < 3.1


def _ggir_fixture():
    import json
    from pathlib import Path
    return json.loads((Path(__file__).parents[2] / "data" / "ggir_night_flags.json").read_text())


@pytest.mark.parametrize("name", sorted(_ggir_fixture()["scenarios"]))
def test_fraction_night_invalid_equals_ggirs(name):
    """GGIR's g.sib.sum on the same series (tools/crosschecks/ggir_night_flags.py): every night
    it reports has our fraction_night_invalid to 1e-12; the one night only we report is a
    recording's partial first night (started after midnight), flagged and not kept."""
    sc = _ggir_fixture()["scenarios"][name]
    spec = dict(sc["spec"])
    for k in ("awakening_min", "daysleeper_nights", "nonwear_nights"):
        spec[k] = tuple(spec[k])
    s = sleep_scenario(SleepSpec(**spec))
    st, recs = _nights(s)
    ours = {n.date.isoformat(): (n, r) for n, r in zip(st.nights, recs)}
    theirs = sc["fraction_night_invalid"]
    for date, frac in theirs.items():
        assert ours[date][0].fraction_invalid == pytest.approx(frac, abs=1e-12), date
    for date in set(ours) - set(theirs):
        n, r = ours[date]
        assert n.window[0] == 0 and r["window_cut"] == "start" and r["night_valid"] == 0


def test_day_table_relative_amplitude_per_day():
    """``ra`` per valid day from the day's own M10 and L5; the ``all`` row averages it."""
    from stillpoint.engine.tables.days import DayAccumulator
    from stillpoint.engine.tables.epochs import EpochRows
    from stillpoint.engine.timezones import parse_zone
    n = 3 * 1440
    t = np.arange(n, dtype=np.int64) * 60 * 10**9 + 20000 * DAY_NS
    tod = np.arange(n) % 1440
    e = np.where((tod < 7 * 60) | (tod >= 23 * 60), 3.0, 40.0) + (np.arange(n) // 1440) * 5.0
    z = np.zeros(n, bool)
    acc = DayAccumulator(parse_zone("UTC"), 60.0)
    acc.push(EpochRows(t, np.full(n, 100), e, z * 0.0, e, z * 0.0, z * 0.0, z, z, z, z, z))
    days = acc.close()
    assert len(days) == 3
    for d in days:
        assert d["ra"] == pytest.approx((d["m10_mg"] - d["l5_mg"]) / (d["m10_mg"] + d["l5_mg"]))
    assert days[0]["ra"] == pytest.approx((40 - 3) / 43) and days[2]["ra"] == pytest.approx((50 - 13) / 63)
    assert acc.summary()["ra"] == pytest.approx(np.mean([d["ra"] for d in days]))
