"""GGIR's nonwear imputation: the average day per slot over 24-h pieces from the first epoch,
masked epochs replaced by their slot's mean, day means and band minutes on the imputed epochs."""

import datetime as dt

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
