"""GGIR part 5's time use per window: WW / OO windows from the sleep periods' edges as
g.part5.definedays finds them (diff(diur)), MM windows at local midnights with the partial first
and last days, the parts of each window adding up, band minutes on clean waking epochs, bouts by
g.getbout, GGIR's part 5 inclusion rule; and the table from ``process``."""

from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from stillpoint.engine.outcomes.bouts import ggir_bouts
from stillpoint.engine.sim.sleep import SleepSpec, sleep_scenario
from stillpoint.engine.sleep import SleepStage
from stillpoint.engine.tables.epochs import EpochRows
from stillpoint.engine.timeuse import WINDOW_COLUMNS, time_use


@pytest.fixture(scope="module")
def week():
    s = sleep_scenario(SleepSpec("2026-05-04T10:00:00", "Europe/London", 5 + 17 / 24, seed=41,
                                 nonwear_nights=(2,)))
    st = SleepStage(s.zone, 5.0)
    n = s.t_ns.shape[0]
    spt, sib = [], []
    for a in range(0, n, 3000):
        b = min(n, a + 3000)
        z = np.zeros(b - a, bool)
        for _, p, q in st.push(EpochRows(s.t_ns[a:b], np.full(b - a, 500), s.enmo[a:b], z * 0.0,
                                         z * 0.0, s.anglez[a:b], z * 0.0, s.nonwear[a:b], z.copy(),
                                         z.copy(), z.copy(), z.copy())):
            spt.append(p)
            sib.append(q)
    for _, p, q in st.flush():
        spt.append(p)
        sib.append(q)
    spt, sib = np.concatenate(spt).astype(bool), np.concatenate(sib).astype(bool)
    rows = time_use(s.t_ns, s.enmo, ~s.nonwear, s.nonwear, sib, spt, st.nights, s.zone, 5.0)
    return s, st, spt, sib, rows


def test_ww_and_oo_windows_are_ggirs(week):
    s, st, spt, sib, rows = week
    diur = spt.astype(int)
    d = np.diff(diur)
    for kind, edge in (("WW", -1), ("OO", 1)):
        e = np.flatnonzero(d == edge)  # R: which(diff(diur) == edge), 1-based + 1 = first epoch
        want = [(int(e[i]) + 1, int(e[i + 1]) + 1) for i in range(len(e) - 1)]
        got = [r for r in rows if r["window_type"] == kind]
        assert len(got) == len(want) >= 4
        for r, (a, b) in zip(got, want):
            assert r["duration_h"] == pytest.approx((b - a) * 5 / 3600)
            assert r["spt_h"] == pytest.approx(spt[a:b].sum() * 5 / 3600)


def test_mm_windows_and_parts_add_up(week):
    s, st, spt, sib, rows = week
    mm = [r for r in rows if r["window_type"] == "MM"]
    assert mm[0]["window_cut"] == "start" and mm[-1]["window_cut"] == "end"
    assert all(r["duration_h"] == pytest.approx(24.0) for r in mm[1:-1])
    assert sum(r["duration_h"] for r in mm) == pytest.approx(s.t_ns.shape[0] * 5 / 3600)
    for r in rows:
        assert r["spt_h"] + r["day_h"] == pytest.approx(r["duration_h"])
        assert r["sleep_h"] + r["wake_spt_h"] == pytest.approx(r["spt_h"])
        assert r["valid_h"] + r["invalid_h"] == pytest.approx(r["duration_h"])
        clean_day = r["day_h"] * 60 * (1 - (r["nonwear_perc_day"] or 0) / 100)
        bands = sum(r[f"dur_day_total_{b}_min"] for b in ("IN", "LIG", "MOD", "VIG"))
        assert bands == pytest.approx(clean_day, abs=1e-6)
        classes = sum(r[c] for c in r if c.startswith("dur_day_") and c.endswith("_min")
                      and ("_unbt_" in c or "_bts_" in c))
        assert classes == pytest.approx(bands, abs=1e-6)  # every counted waking epoch in one class
    assert [r["window_valid"] for r in mm] == [0] + [1] * (len(mm) - 2) + [0]


def test_nonwear_night_counts_in_its_windows(week):
    s, st, spt, sib, rows = week
    ww = [r for r in rows if r["window_type"] == "WW" and r["night"] == "2026-05-06"]
    assert ww and ww[0]["nonwear_h"] == pytest.approx(2.0)
    assert ww[0]["nonwear_perc_spt"] > 0 and ww[0]["nonwear_perc_day"] == 0


def test_mvpa_bouts_are_ggirs_on_the_waking_epochs(week):
    s, st, spt, sib, rows = week
    mark = ~spt & ~s.nonwear & (s.enmo >= 100)
    inb = ggir_bouts(mark, 120, 12)  # the longest MVPA class comes first: plain g.getbout
    r = [x for x in rows if x["window_type"] == "MM"][2]
    local = s.zone.local_ns(s.t_ns)
    day = local // (86400 * 10**9)
    sel = day == day[0] + 2
    assert r["dur_day_MVPA_bts_10_min"] == pytest.approx((inb[sel] & ~spt[sel]).sum() * 5 / 60)


def test_windows_table_from_process(tmp_path):
    from stillpoint.engine.sim import simulate_recording
    rec = tmp_path / "w.cwa"
    simulate_recording(rec, days=2.6, hz=12.5, seed=8, truth_path=False)
    exe = Path(sys.executable).with_name("stillpoint")
    subprocess.run([str(exe), "process", str(rec), "-o", str(tmp_path / "w.mcap"), "--timezone",
                    "Europe/London", "-q", "--impute"], check=True)
    rows = list(csv.DictReader(open(tmp_path / "w.windows.csv")))
    assert list(rows[0]) == WINDOW_COLUMNS
    assert {r["imputed"] for r in rows} == {"1"}  # GGIR's part 5 series: more than a day recorded
    assert {r["window_type"] for r in rows} == {"WW", "MM", "OO"}
    assert all(r["guider"] in ("HDCZA", "HDCZA+invalid", "L512", "sleeplog") for r in rows
               if r["window_type"] != "MM")


def test_shift_worker_windows_from_process(tmp_path):
    """A night-shift wearer (asleep about 05:00-14:00): its nights are found by day and its
    wake-to-wake windows start in the afternoon."""
    from stillpoint.engine.sim import simulate_recording
    from stillpoint.engine.sim.wearer import wearer_params
    rec = tmp_path / "s.cwa"
    simulate_recording(rec, days=3.2, hz=12.5, seed=5, truth_path=False, wearer=wearer_params("shift"))
    exe = Path(sys.executable).with_name("stillpoint")
    subprocess.run([str(exe), "process", str(rec), "-o", str(tmp_path / "s.mcap"), "--timezone", "UTC",
                    "-q", "--impute"], check=True)
    rows = list(csv.DictReader(open(tmp_path / "s.windows.csv")))
    ww = [r for r in rows if r["window_type"] == "WW"]
    assert len(ww) >= 2
    for r in ww:
        hour = int(r["start_local"][11:13])
        assert 12 <= hour <= 16, r["start_local"]  # the wake-up after a day's sleep
        assert 7.5 < float(r["spt_h"]) < 11
