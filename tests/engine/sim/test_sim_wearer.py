"""Wearer schedule, site rendering, temperature and clock models."""

import numpy as np
import pytest

from stillpoint.engine.sim.clock import make_clock
from stillpoint.engine.sim.model import SensorModel, resolve_model
from stillpoint.engine.sim.temperature import TemperatureParams, temperature_track
from stillpoint.engine.sim.wearer import (ACTIVITIES, MOTIONS, SITES, SiteModel, WearerParams,
                                          make_schedule)


@pytest.fixture(scope="module")
def week():
    return make_schedule(WearerParams(), 7 * 86400.0, seed=3)


def test_schedule_covers_a_week_with_plausible_behaviour(week):
    s = week
    assert s.start[0] == 0 and s.end[-1] >= 7 * 86400
    assert np.all(s.end > s.start) and np.allclose(s.start[1:], s.end[:-1])
    hours = {a: (s.end - s.start)[s.activity == i].sum() / 3600 / 7 for i, a in enumerate(ACTIVITIES)}
    assert 6.5 < hours["sleep"] < 9.5
    assert 0.5 < hours["walking"] < 3.5
    assert hours["sitting"] > 6
    # every night has posture changes
    sleep_groups = np.unique(s.group[s.activity == ACTIVITIES.index("sleep")])
    assert sleep_groups.size > 7 * 6
    hz = s.step_hz[s.motion == MOTIONS.index("gait")]
    walk = s.activity[s.motion == MOTIONS.index("gait")] == ACTIVITIES.index("walking")
    assert np.all((hz[walk] >= 1.6) & (hz[walk] <= 2.2))
    assert np.all((hz[~walk] >= 2.5) & (hz[~walk] <= 3.0))


def test_wrist_orientations_cover_the_sphere_over_a_week(week):
    site = SiteModel(week, "wrist", seed=3)
    still = np.nonzero((week.motion == 0) & (week.end - week.start > 20))[0]
    g = np.array([site.params(i).R_base[2, :] for i in still])  # gravity in the device frame
    assert np.allclose(np.linalg.norm(g, axis=1), 1.0)
    for k in range(3):
        assert g[:, k].min() < -0.3 and g[:, k].max() > 0.3


@pytest.mark.parametrize("site", SITES)
def test_render_is_chunk_invariant_and_physical(week, site):
    sm = SiteModel(week, site, seed=3)
    t = np.arange(0, 6 * 3600 * 25) / 25.0 + 8 * 3600  # 6 h at 25 Hz
    f, w = sm.render(t, gyro=True)
    parts = [SiteModel(week, site, seed=3).render(t[a:a + 77777], gyro=True) for a in range(0, t.size, 77777)]
    assert np.array_equal(np.concatenate([p[0] for p in parts]), f)
    assert np.array_equal(np.concatenate([p[1] for p in parts]), w)
    seg = week.segment_at(t)
    still = week.motion[seg] == 0
    after = t - week.start[seg] > week.trans_s[seg]
    # at rest the device reads gravity plus the worn micro-motion (mg, zero mean, no rotation)
    norm = np.linalg.norm(f[still & after], axis=1)
    assert np.allclose(norm, 1.0, atol=0.15) and abs(norm.mean() - 1.0) < 2e-3
    assert np.all(w[still & after] == 0)
    assert np.abs(f).max() < 8.5  # within a plausible range at every site
    gait = week.motion[seg] == 2
    if gait.any():
        assert np.std(np.linalg.norm(f[gait], axis=1)) > 0.1  # walking moves the device


def test_hip_is_upright_when_standing_still(week):
    sm = SiteModel(week, "hip", seed=3)
    stand = np.nonzero((week.activity == ACTIVITIES.index("standing")) & (week.motion == 0))[0]
    g = np.array([sm.params(i).R_base[2, :] for i in stand])
    assert np.all(g[:, 0] > 0.9)  # device x points up on a belt-worn device


def test_temperature_plausible_per_site_and_cools_off_body(week):
    p = TemperatureParams()
    for site, (lo, hi) in {"wrist": (25, 36), "hip": (28, 37), "thigh": (27, 36), "ankle": (25, 36)}.items():
        t, T = temperature_track(week, site, p, 3, 7 * 86400.0)
        seg = week.segment_at(t)
        worn = week.activity[seg] > 1
        settled = worn & (t - week.start[seg] > 1800)
        assert lo <= np.percentile(T[settled], 1) and np.percentile(T[settled], 99) <= hi
        off = (week.activity[seg] <= 1) & (t - week.start[seg] > 3 * p.tau_nonwear_s)
        if off.any():
            assert np.all(np.abs(T[off] - p.ambient_c) < 2.5)


def test_clock_skew_parabola_halts_and_rate_error():
    t = np.arange(0, 2 * 86400 + 10, 10.0)
    T = np.full_like(t, 35.0)
    m = SensorModel({"clock": {"offset_s": 2.0, "skew_ppm": 20.0, "curvature_ppm_per_c2": -0.035,
                               "turnover_c": 25.0},
                     "rate_error": {"pct": -1.1},
                     "halts": {"events": [{"start_s": 100.0, "duration_s": 50.0}]}})
    c = make_clock(m, t, T, 100.0)
    ppm = 20.0 - 0.035 * 100
    assert c.device_time(86400.0) - 86400.0 == pytest.approx(2.0 + ppm * 1e-6 * 86400, abs=1e-9)
    assert c.true_time(c.device_time(1234.5)) == pytest.approx(1234.5, abs=1e-6)
    assert c.rate_true_hz == pytest.approx(98.9)
    tt, keep = c.sample_times(0, int(300 * c.rate_true_hz))
    assert np.count_nonzero(~keep) == pytest.approx(50 * 98.9, abs=2)
    assert not np.any(keep & (tt >= 100) & (tt < 150))


def test_resolved_random_halts_start_after_day_one():
    m = resolve_model(SensorModel({"halts": {"count": 3}}), seed=1, duration_s=7 * 86400.0)
    ev = m.effects["halts"]["events"]
    assert len(ev) == 3 and all(e["start_s"] >= 86400 and 2 <= e["duration_s"] <= 400 for e in ev)


def test_still_windows_of_a_week_cover_the_sphere_on_every_axis():
    from stillpoint.engine.sim.device import build_model, make_devices
    [sim] = make_devices(sites=["wrist"], devices=["ax3"], days=7, hz=100, seed=21,
                         effects=build_model("offset,gain,temperature_offset,noise"))
    sw = sim.still_windows()  # no samples rendered: fast
    g = sw["gravity"]
    assert g.shape[0] > 7 * 8640 * 0.3  # a third of the windows are still
    for k in range(3):
        assert (g[:, k] < -0.3).sum() > 100 and (g[:, k] > 0.3).sum() > 100
    # and the device temperature spans a useful range for the temperature term
    assert np.ptp(sw["temperature_c"]) > 5


def test_worn_micromotion_at_rest():
    """Still segments of a worn device carry the micro-motion (breathing, pulse, tremor): a few
    mg per axis, zero mean, no rotation; nonwear segments and a body without it are exactly
    still; the closed-form window moments (for window-level simulation) match rendered samples."""
    sch = make_schedule(WearerParams(), 2 * 86400.0, seed=3)
    flat = make_schedule(WearerParams(still_micromotion_mg=0.0), 2 * 86400.0, seed=3)
    on, off = SiteModel(sch, "wrist", seed=3), SiteModel(flat, "wrist", seed=3)
    still = np.nonzero(sch.motion == MOTIONS.index("still"))[0]
    worn = [i for i in still if ACTIVITIES[sch.activity[i]] in ("sleep", "sitting", "standing")
            and sch.end[i] - sch.start[i] > 60]
    table = [i for i in still if ACTIVITIES[sch.activity[i]] == "nonwear_table"]
    assert len(worn) > 20 and table
    hz = 100.0
    rms = []
    for i in worn[:20]:
        t0 = sch.start[i] + sch.trans_s[i] + 1.0
        t = t0 + np.arange(int(10 * hz)) / hz
        f, w = on.render(t, gyro=True)
        f0, _ = off.render(t)
        assert np.allclose(np.linalg.norm(f0, axis=1), 1.0, atol=1e-6)  # off: exactly gravity
        np.testing.assert_allclose(f0, np.broadcast_to(on.params(i).R_base[2, :], f0.shape), atol=1e-6)
        assert np.all(w == 0)
        mean, sd = on.micromotion_window_moments(i, np.array([t0]), 10.0)
        np.testing.assert_allclose(f.mean(axis=0) - f0[0], mean[0], atol=2e-4)
        np.testing.assert_allclose(f.std(axis=0), sd[0], rtol=0.1, atol=3e-4)
        rms.append(np.sqrt(np.mean(sd[0] ** 2)))
    assert 2e-3 < np.median(rms) < 12e-3  # a few mg per axis
    i = table[0]
    t = sch.start[i] + sch.trans_s[i] + 1.0 + np.arange(1000) / hz
    f, _ = on.render(t)
    assert np.allclose(np.linalg.norm(f, axis=1), 1.0, atol=1e-6)  # off the body: still
    assert on.micromotion(i) is None


def _wrist_epoch_enmo_mg(sch, seed, days, hz=25.0):
    """5 s epoch ENMO (mg) of the rendered wrist and the activity at each epoch's start."""
    sm = SiteModel(sch, "wrist", seed)
    ep = int(5 * hz)
    out, act = [], []
    n = int(days * 86400 * hz)
    for i0 in range(0, n, ep * 720):  # an hour at a time
        t = np.arange(i0, min(n, i0 + ep * 720)) / hz
        f = sm.render(t)
        f = f[0] if isinstance(f, tuple) else f
        e = np.maximum(np.linalg.norm(f, axis=1) - 1.0, 0.0)
        k = e.shape[0] // ep
        out.append(e[:k * ep].reshape(k, ep).mean(axis=1) * 1000.0)
        act.append(sch.activity[sch.segment_at(t[:k * ep:ep])])
    return np.concatenate(out), np.concatenate(act)


def test_default_wearer_spends_free_living_time_in_every_intensity_band():
    # Free-living wrist data (engine/sim/wearer.py REALISM_SOURCES): mean ENMO ~25-35 mg, light
    # activity (40-100 mg) about as common as MVPA (100-400 mg); the former wearer spent ~1 min a
    # day at 40-100 mg.
    days = 3
    sch = make_schedule(WearerParams(), days * 86400.0, seed=3)
    e, act = _wrist_epoch_enmo_mg(sch, 3, days)
    worn = act > 1
    per_day = lambda m: m.sum() * 5 / 60 / days  # noqa: E731
    light = per_day(worn & (e >= 40) & (e < 100))
    mvpa = per_day(worn & (e >= 100) & (e < 400))
    assert 60 < light < 300, light
    assert 40 < mvpa < 180, mvpa
    assert light > 0.5 * mvpa
    assert 20 < e[worn].mean() < 50


def test_default_wearer_takes_the_device_off_and_the_truth_says_how_long():
    from stillpoint.engine.sim.wearer import nonwear_summary
    days = 14
    sch = make_schedule(WearerParams(), days * 86400.0, seed=3)
    nw = nonwear_summary(sch)
    eps = nw["episodes"]
    # showers every day, and off-wrist episodes of 1-3 h in the day (on a table: flat, still)
    long_eps = [x for x in eps if x["end_s"] - x["start_s"] >= 3600]
    assert len(long_eps) >= 1 and nw["hours_in_episodes_ge_60_min"] >= 1.0
    assert abs(nw["hours"] - sum(x["end_s"] - x["start_s"] for x in eps) / 3600) < 1e-3
    # no nonwear during sleep; a week holds 1-20 h of it (Doherty 2017 Table 1: median ~1-3 h,
    # 7-18 h at the lower quartile of wear time)
    sleep = sch.activity == ACTIVITIES.index("sleep")
    for x in eps:
        assert not ((sch.start < x["end_s"]) & (sch.end > x["start_s"]) & sleep).any()
    assert 1.0 * days / 7 < nw["hours"] < 20.0 * days / 7
    off = (sch.activity == ACTIVITIES.index("nonwear_table"))
    assert set(MOTIONS[m] for m in sch.motion[off]) == {"still"}
    # the off-wrist episodes do not change the behaviour drawn around them
    plain = make_schedule(WearerParams(offwrist_per_week=0.0), days * 86400.0, seed=3)
    t = np.array([x["start_s"] - 600.0 for x in long_eps if x["start_s"] > 600])
    assert np.array_equal(plain.activity[plain.segment_at(t)], sch.activity[sch.segment_at(t)])


def test_simulated_truth_json_records_the_nonwear(tmp_path):
    import json
    from stillpoint.engine.sim import simulate_recording
    simulate_recording(tmp_path / "a.cwa", device="ax3", site="wrist", days=0.25, hz=12.5, seed=3)
    truth = json.loads((tmp_path / "a.truth.json").read_text())
    nw = truth["summary"]["nonwear"]
    assert set(nw) == {"hours", "hours_in_episodes_ge_60_min", "episodes"}
    assert nw["hours"] == pytest.approx(truth["summary"]["activity_hours"]["nonwear_table"]
                                        + truth["summary"]["activity_hours"]["nonwear_drawer"], abs=0.02)


def test_still_wearer_has_long_still_periods_long_nights_and_long_nonwear():
    from stillpoint.engine.sim.wearer import WEARERS, nonwear_summary, wearer_params
    assert set(WEARERS) == {"default", "still", "shift"} and wearer_params() == WearerParams()
    with pytest.raises(ValueError, match="unknown wearer 'sofa'.*default, still, shift"):
        wearer_params("sofa")
    days = 7

    def profile(name):
        sch = make_schedule(wearer_params(name), days * 86400.0, seed=3)
        d = np.clip(sch.end, 0, days * 86400.0) - np.clip(sch.start, 0, days * 86400.0)
        hours = {a: d[sch.activity == i].sum() / 3600 / days for i, a in enumerate(ACTIVITIES)}
        still = sch.motion == MOTIONS.index("still")
        longest = d[still].max()
        return sch, hours, d[still].sum() / 3600 / days, longest, nonwear_summary(sch)

    _, h0, still0, long0, nw0 = profile("default")
    sch, h1, still1, long1, nw1 = profile("still")
    # still segments (worn or not): ~21 h a day against ~12 h for the default wearer
    assert still1 > 18 and still1 > still0 + 6, (still0, still1)
    assert h1["sleep"] > h0["sleep"] + 0.5 and h1["sleep"] > 9
    assert h1["running"] == 0 and h1["walking"] < 0.5 * h0["walking"]
    # hours-long off-wrist periods: several a week, more nonwear than the default wearer
    long_eps = [x for x in nw1["episodes"] if x["end_s"] - x["start_s"] >= 2 * 3600]
    assert len(long_eps) >= 2 and nw1["hours"] > nw0["hours"]
    assert long1 >= 2 * 3600 and long1 > long0 * 0.99
    # the same seed draws the same plan
    again = make_schedule(wearer_params("still"), days * 86400.0, seed=3)
    assert np.array_equal(again.start, sch.start) and np.array_equal(again.activity, sch.activity)


def test_simulate_cli_wearer_option_writes_the_still_wearer(tmp_path):
    import json

    from stillpoint.engine.sim.wearer import WEARERS
    from stillpoint.tools.cli import main
    out = tmp_path / "still.cwa"
    assert main(["simulate", "-o", str(out), "--days", "0.05", "--hz", "12.5", "--wearer",
                 "still", "-q"]) == 0
    truth = json.loads(out.with_suffix(".truth.json").read_text())
    assert truth["wearer"] == WearerParams(**WEARERS["still"]).to_dict()
    assert truth["wearer"]["still_bout_s"] == 300.0
    # a run that does not draw a wearer refuses the option in one line
    assert main(["simulate", "-o", str(tmp_path / "six.cwa"), "--scenario", "sixface",
                 "--wearer", "still"]) == 2


def test_shift_wearer_sleeps_by_day():
    from stillpoint.engine.sim.wearer import wearer_params
    days = 7
    sch = make_schedule(wearer_params("shift"), days * 86400.0, seed=2)  # starts 10:00 local
    asleep = np.zeros(days * 24 * 60, bool)  # per minute from the start
    for s, e, a in zip(sch.start, sch.end, sch.activity):
        if a == ACTIVITIES.index("sleep"):
            asleep[int(max(s, 0) // 60):int(min(e, days * 86400.0) // 60)] = True
    hour = (10 + np.arange(asleep.shape[0]) / 60.0) % 24
    by_day = asleep[(hour >= 6) & (hour < 13)].mean()
    by_night = asleep[(hour >= 16) | (hour < 3)].mean()
    assert by_day > 0.9 and by_night < 0.02, (by_day, by_night)
    assert 8 < asleep.sum() / 60 / days < 10
