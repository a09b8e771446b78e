"""GGIR's nonwear imputation: the average day per slot over 24-h pieces from the first epoch,
masked epochs replaced by their slot's mean, day means and band minutes on the imputed epochs."""

import datetime as dt
from pathlib import Path

import numpy as np
import pytest

from stillpoint.engine.outcomes.daily import DailyOutcomes, OutcomeSettings
from stillpoint.engine.outcomes.impute import AverageDay, imputed_columns, imputed_days


def _ggir(values, masked, wpd):
    """g.impute.R lines 366-417 written out: pieces of wpd from the first epoch, NA-mean per slot,
    0 for a slot never seen, masked epochs replaced."""
    n = values.size
    nd = -(-n // wpd)
    imp = np.full((nd, wpd), np.nan)
    v = np.where(masked, np.nan, values)
    imp.flat[:n] = v
    with np.errstate(invalid="ignore"):
        avg = np.nanmean(imp, axis=0)
    avg[np.isnan(avg)] = 0.0
    out = np.where(np.isnan(imp), avg[None, :], imp).ravel()[:n]
    return out


def test_imputed_day_values_follow_ggir(tmp_path):
    rng = np.random.default_rng(3)
    n = 1440 * 3 + 500  # more than three days, from 07:00
    enmo = np.round(rng.gamma(1.5, 30.0, n), 3)
    mad = np.round(rng.gamma(1.5, 25.0, n), 3)
    nonwear = np.zeros(n, bool)
    nonwear[2000:2600] = True  # ten hours off on day 2
    nonwear[4000:4100] = True
    gap = np.zeros(n, bool)
    gap[300:320] = True
    av = AverageDay(60.0)
    clean = ~(nonwear | gap)
    day0 = (dt.date(2026, 1, 1) - dt.date(1970, 1, 1)).days
    day_no = day0 + (7 * 60 + np.arange(n)) // 1440  # from 07:00 on 1 January
    for a in range(0, n, 777):  # pushed in pieces, as rows stream
        b = min(n, a + 777)
        av.push({"enmo_mg": np.where(gap[a:b], np.nan, enmo[a:b]),
                 "mad_mg": np.where(gap[a:b], np.nan, mad[a:b])}, clean[a:b], day_no[a:b])
    outcomes = DailyOutcomes(OutcomeSettings(cutpoints="hildebrand_adults_geneactiv_wrist",
                                             impute=True), 60.0)
    days = imputed_days(av, outcomes)
    want_e = _ggir(enmo, ~clean, 1440)
    want_m = _ggir(mad, ~clean, 1440)
    start = 7 * 60
    day_of = (start + np.arange(n)) // 1440
    assert sorted(days) == [f"2026-01-{d:02d}" for d in range(1, 5)]
    for d in range(4):
        sel = day_of == d
        got = days[f"2026-01-{d + 1:02d}"]
        assert got["enmo_mean_mg_imputed"] == pytest.approx(want_e[sel].mean(), rel=1e-12)
        assert got["mad_mean_mg_imputed"] == pytest.approx(want_m[sel].mean(), rel=1e-12)
        mvpa = (want_e[sel] >= 93.2).sum()
        assert got["min_mvpa_hildebrand_adults_geneactiv_wrist_imputed"] == pytest.approx(mvpa)
    # the imputed day 2 differs from its clean-epoch mean: the nonwear hours were filled
    sel = (day_of == 1) & clean
    assert days["2026-01-02"]["enmo_mean_mg_imputed"] != pytest.approx(enmo[sel].mean(), rel=1e-3)
    assert set(days["2026-01-02"]) == set(imputed_columns(outcomes))


def test_one_day_is_not_imputed(tmp_path):
    av = AverageDay(60.0)
    av.push({"enmo_mg": np.ones(1440), "mad_mg": np.ones(1440)}, np.ones(1440, bool),
            np.zeros(1440, np.int64))
    assert not av.imputes
    assert imputed_days(av) == {}


_M5L5 = Path(__file__).resolve().parents[2] / "data" / "ggir_m5l5"


@pytest.mark.parametrize("name", sorted(p.stem for p in _M5L5.glob("*.json")))
def test_imputed_m10_l5_equal_ggirs_part2(name):
    """Per-day M10 / L5 on the imputed epochs against GGIR's part 2 on the same imputed days
    (g.analyse.perday's lines that bring a day to 24 h, then g.getM5L5;
    tools/crosschecks/ggir_m5l5.py): first and last partial days and the 23-h DST day included."""
    import json
    import sys
    sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "tools" / "crosschecks"))
    import ggir_part5_windows as p5
    from stillpoint.engine.sim.sleep import SleepSpec
    fx = json.loads((_M5L5 / f"{name}.json").read_text())
    spec = SleepSpec(**{k: tuple(v) if isinstance(v, list) else v for k, v in fx["spec"].items()})
    s, sib, spt, nights, clean, imp = p5.scenario_inputs(spec)
    local = s.zone.local_ns(s.t_ns)
    day = local // (86400 * 10**9)
    av = AverageDay(5.0)
    av.push({"enmo_mg": s.enmo, "mad_mg": s.enmo}, clean, day, local)
    ours = imputed_days(av)
    av.close()
    assert len(fx["days"]) == len(ours) >= 6
    for g in fx["days"]:
        o = ours[g["date"]]
        for key, col in (("m10", "M10"), ("l5", "L5")):
            assert o[f"{key}_mg_imputed"] == pytest.approx(g[col], rel=1e-9), (g["date"], key)
            m = int(round(g[col + "hr"] * 60)) % 1440  # GGIR: decimal hours, +24 below 12
            assert o[f"{key}_start_imputed"] == f"{m // 60:02d}:{m % 60:02d}", (g["date"], key)
        assert o["ra_imputed"] == pytest.approx((g["M10"] - g["L5"]) / (g["M10"] + g["L5"]))
