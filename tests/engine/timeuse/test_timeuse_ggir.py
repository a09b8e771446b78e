"""GGIR part 5's time use per window against GGIR's own code: ``identify_levels`` run on the whole
series and ``g.part5_analyseSegment`` per window (tools/crosschecks/ggir_part5_windows.py/.R
regenerates tests/data/ggir_part5/), on simulated weeks with waking activity and an afternoon of
nonwear: a default wearer, a shift worker sleeping by day, a recording cut mid-night, a spring DST
week. GGIR's part 5 reads its imputed series; so does the table with ``--impute``."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from stillpoint.engine.sim.sleep import SleepSpec
from stillpoint.engine.timeuse import time_use
from stillpoint.engine.timeuse.windows import TIMEUSE_COLUMNS
from stillpoint.engine.timezones import local_text

ROOT = Path(__file__).resolve().parents[3]
FIXTURES = ROOT / "tests" / "data" / "ggir_part5"
NAMES = sorted(p.stem for p in FIXTURES.glob("*.json"))
COMPARED = TIMEUSE_COLUMNS + ["nonwear_perc_day", "nonwear_perc_spt", "nonwear_perc_day_spt"]


def _spec(d: dict) -> SleepSpec:
    return SleepSpec(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.items()})


@pytest.fixture(scope="module", params=NAMES)
def scenario(request):
    sys.path.insert(0, str(ROOT / "tools" / "crosschecks"))
    import ggir_part5_windows as cc
    fx = json.loads((FIXTURES / f"{request.param}.json").read_text())
    s, sib, spt, nights, clean, imp = cc.scenario_inputs(_spec(fx["spec"]))
    return request.param, fx, s, sib, spt, nights, clean, imp


def _paired(rows, fx, s):
    ours = {(r["window_type"], r["start_local"], round(r["duration_h"] * 720)): r for r in rows}
    for g in fx["windows"]:
        f0, f1 = int(g["first"]) - 1, int(g["last"])
        yield g, ours.get((g["type"], local_text(int(s.t_ns[f0]), s.zone), f1 - f0))


def test_fixtures_cover_every_bout_class():
    assert len(NAMES) == 4
    for c in [c for c in TIMEUSE_COLUMNS if c.startswith("dur_day_") and "_bts_" in c]:
        assert any(w[c] for n in NAMES
                   for w in json.loads((FIXTURES / f"{n}.json").read_text())["windows"]), c


def test_every_column_of_every_window_is_ggirs_with_imputation(scenario):
    name, fx, s, sib, spt, nights, clean, imp = scenario
    rows = time_use(s.t_ns, imp, clean, s.nonwear, sib, spt, nights, s.zone, 5.0, imputed=True)
    pairs = list(_paired(rows, fx, s))
    assert pairs and all(r is not None for _, r in pairs), name
    assert len(rows) == len(pairs)  # no window GGIR leaves out
    for g, r in pairs:
        assert r["imputed"] == 1
        for c in COMPARED:
            if g[c] is None:
                assert r[c] is None, (name, g["type"], g["first"], c)
            else:
                assert r[c] == pytest.approx(g[c], rel=1e-9, abs=1e-9), (name, g["type"], g["first"], c)


def test_without_imputation_nonwear_is_in_no_class(scenario):
    name, fx, s, sib, spt, nights, clean, imp = scenario
    rows = time_use(s.t_ns, s.enmo, clean, s.nonwear, sib, spt, nights, s.zone, 5.0)
    for g, r in _paired(rows, fx, s):
        day_classes = sum(r[f"dur_day_total_{c}_min"] for c in ("IN", "LIG", "MOD", "VIG"))
        wake_nonwear = r["dur_day_min"] * (r["nonwear_perc_day"] or 0) / 100
        assert day_classes == pytest.approx(r["dur_day_min"] - wake_nonwear, abs=1e-6)
        # the sleep period's and the window's own totals do not depend on the values
        assert r["dur_spt_min"] == pytest.approx(g["dur_spt_min"])
        assert r["dur_spt_sleep_min"] == pytest.approx(g["dur_spt_sleep_min"])


def test_bout_classes_are_hierarchical(scenario):
    from stillpoint.engine.timeuse.levels import levels
    name, fx, s, sib, spt, nights, clean, imp = scenario
    lv = levels(imp, spt, sib, 5.0, (40.0, 100.0, 400.0))
    names = list(lv.names)
    mvpa = lv.bouts["day_MVPA_bts_10"] | lv.bouts["day_MVPA_bts_5_10"] | lv.bouts["day_MVPA_bts_1_5"]
    lig = lv.bouts["day_LIG_bts_10"] | lv.bouts["day_LIG_bts_5_10"] | lv.bouts["day_LIG_bts_1_5"]
    inact = lv.bouts["day_IN_bts_30"] | lv.bouts["day_IN_bts_20_30"] | lv.bouts["day_IN_bts_10_20"]
    assert mvpa.any() and lig.any() and inact.any()
    # the last bout class to claim a waking epoch names it (MVPA, then inactivity, then light)
    day = ~spt
    assert np.all(lv.level[day & lig] >= names.index("day_LIG_bts_10"))
    assert np.all(lv.level[day & mvpa & ~lig & ~inact] <= names.index("day_MVPA_bts_1_5"))
    # the waking epochs are in exactly one day class; the sleep period's in one spt class
    day_cls = lv.level[~spt]
    assert np.all(day_cls >= names.index("day_IN_unbt"))
    assert np.all(lv.level[spt] < names.index("day_IN_unbt"))
