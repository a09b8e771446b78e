"""Agreement with GGIR's own rhythm functions on the same epoch series (tests/data/ggir_rhythm/,
made by tools/crosschecks/ggir_rhythm_fixtures.py with GGIR's R code and ActCR; CI needs no R):
IS, IV, cosinor and its times to 1e-9; the sleep regularity index and the transition
probabilities equal; phi (R's arima) and the extended cosinor (minpack.lm's nls.lm) to their
optimisers' tolerance, our fit never worse than R's."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from stillpoint.engine.rhythm import metrics
from stillpoint.engine.rhythm.series import RHYTHM_COLUMNS, local_midnights
from stillpoint.engine.sim.sleep import SleepSpec

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT / "tools" / "crosschecks"))
import ggir_rhythm_fixtures as gen  # noqa: E402

DATA = Path(__file__).parents[2] / "data" / "ggir_rhythm"
SCENARIOS = sorted(p.stem for p in DATA.glob("*.json"))
EXACT = [k for k in gen.COSINOR_FIELDS if not k.startswith("ext_") and k != "phi"]


@pytest.fixture(scope="module", params=SCENARIOS)
def case(request):
    fx = json.loads((DATA / f"{request.param}.json").read_text())
    spec = dict(fx["spec"])
    for k in ("awakening_min", "daysleeper_nights", "nonwear_nights"):
        spec[k] = tuple(spec[k])
    s, sib, spt = gen.scenario_series(SleepSpec(**spec))
    assert gen.series_digest(s.enmo, s.nonwear, sib) == fx["series_sha256"], (
        "the series is not the one GGIR was given: regenerate with "
        "tools/crosschecks/ggir_rhythm_fixtures.py")
    return request.param, fx, s, sib, spt, gen.ours(s, sib, spt)


def test_scenarios_present():
    assert {"default_week", "shift_worker", "cut_mid_night", "spring_dst_week"} <= set(SCENARIOS)


def test_is_iv_cosinor_equal_ggir(case):
    name, fx, s, sib, spt, got = case
    c, row = fx["cosinor"], got["row"]
    assert c is not None
    for k in EXACT:
        assert row[k] == pytest.approx(c[gen.COSINOR_FIELDS[k]], rel=1e-9, abs=1e-9), (name, k)
    assert 0 < row["is"] < 1 and row["iv"] > 0


def test_phi_is_rs_arima_optimum(case):
    name, fx, s, sib, spt, got = case
    assert got["row"]["phi"] == pytest.approx(fx["cosinor"]["phi"], abs=5e-4)


def test_extended_cosinor_at_least_as_good_as_nls_lm(case):
    """minpack.lm stops at a relative reduction of sqrt(eps); we go to the least squares: the
    parameters agree to 1e-3 (relative) and our residuals are never larger."""
    name, fx, s, sib, spt, got = case
    c, row = fx["cosinor"], got["row"]
    for k, v in gen.COSINOR_FIELDS.items():
        if k.startswith("ext_"):
            assert row[k] == pytest.approx(c[v], rel=1e-3, abs=1e-4), (name, k)
    ci = metrics.cosinor_input(s.enmo / 1000.0, s.nonwear, local_midnights(s.t_ns, s.zone), 5.0)
    x = metrics.to_mg(metrics.whole_days(ci.minutes))
    ok = np.isfinite(x)
    y = np.log(x[ok] + 1)
    t = (np.tile(np.arange(1, 1441), x.shape[0] // 1440) / 60.0)[ok]
    off = c["timeOffsetHours"]

    def rss(p):
        return float(np.sum((y - metrics._ext_model(np.array(p), t)) ** 2))
    theirs = rss([c["ext_minimum"], c["ext_amp"], c["ext_alpha"], c["ext_beta"],
                  c["ext_acrotime"] + off])
    ours = rss([row["ext_minimum"], row["ext_amplitude"], row["ext_alpha"], row["ext_beta"],
                row["ext_acrophase_h"] + off])
    assert ours <= theirs * (1 + 1e-12)


def test_sleep_regularity_equal_ggir(case):
    name, fx, s, sib, spt, got = case
    assert len(fx["sri"]) >= 4
    ours = [(d, v, f) for d, v, f in got["sri"]]
    theirs = [(r["date"], r["sri"], r["frac_valid"]) for r in fx["sri"]]
    assert ours == theirs


def test_fragmentation_equal_ggir(case):
    """Every g.fragmentation figure (part 6's "day" and "spt" modes, frag.metrics "all": transition
    probabilities, fragment counts, mean durations, SD, Gini, CoV, power law) on part 5's classes."""
    name, fx, s, sib, spt, got = case
    pairs = gen.frag_pairs(got["row"], fx["frag"])
    assert len(pairs) == 38
    assert sum(b is not None for a, b in pairs.values()) >= 34  # the distribution metrics defined
    for col, (a, b) in pairs.items():
        if b is None:
            assert a is None, (name, col)
        else:
            assert a == pytest.approx(b, rel=1e-9, abs=1e-12), (name, col)


def test_gini_is_ineqs():
    """ineq::Gini(c(1, 2, 3, 10), corr = TRUE) = (2 * 54 / 16 - 5) / 3 (R: 0.58333333333333337)."""
    assert metrics.gini(np.array([10, 1, 3, 2.0])) == pytest.approx((2 * 54 / 16 - 5) / 3, rel=1e-15)


def test_transition_probabilities_follow_rs_runs():
    """NA splits the series and every NA is a run of its own (R's rle)."""
    x = np.array([1, 1, 2, 3, np.nan, np.nan, 1, 2, 2, 1], float)
    tp = metrics.transition_probabilities(x)
    # a->b: (1,1)->2 and 1->(2,2): 2; b->a: (2,2)->1: 1; last runs: 3 (before NA) and the final 1
    assert tp[2:] == (2, 1)
    assert tp[0] == round((2 + 1e-6) / (2 + 1 + 1 - 1 + 1e-6), 6)
    assert tp[1] == round((1 + 1e-6) / (1 + 1 + 2 - 1 + 1e-6), 6)


def test_rhythm_table_from_process(tmp_path):
    """``process`` writes <stem>.rhythm.csv with the documented columns and one row."""
    import csv
    import subprocess
    from stillpoint.engine.sim import simulate_recording
    rec = tmp_path / "w.cwa"
    simulate_recording(rec, days=3.2, hz=12.5, seed=6, truth_path=False)
    exe = Path(sys.executable).with_name("stillpoint")
    subprocess.run([str(exe), "process", str(rec), "-o", str(tmp_path / "w.mcap"), "--timezone",
                    "UTC", "-q"], check=True)
    rows = list(csv.DictReader(open(tmp_path / "w.rhythm.csv")))
    assert len(rows) == 1 and list(rows[0]) == RHYTHM_COLUMNS
    r = rows[0]
    assert 0 < float(r["is"]) <= 1 and float(r["iv"]) > 0
    assert 0 <= float(r["cosinor_acrophase_h"]) < 24 and float(r["ra_avday"]) > 0
    assert r["sri"] != "" and r["timezone"] == "+00:00", r


def test_fragmentation_without_a_sleep_period_is_ggirs_empty_one():
    """g.fragmentation "spt" on a series that is all missing (no sleep period): every NA its own
    run, no fragments, TP (0 + 1e-6) / (0 + 1e-6) = 1 (R, GGIR 388064b7)."""
    from stillpoint.engine.rhythm.series import fragmentation
    n = 500
    e = np.where(np.arange(n) % 40 < 20, 10.0, 150.0)
    z = np.zeros(n, bool)
    f = fragmentation(e, z, z, z, 5.0)
    assert f["frag_nfrag_sleep_spt"] == 0 and f["frag_nfrag_in_spt"] == 0
    assert f["frag_tp_in2pa_spt"] == 1.0 and f["frag_tp_sleep2wake_spt"] == 1.0
    assert f["frag_nfrag_in2pa_day"] > 0
