"""In-process fuzz smoke test: mutated .cwa, .bin, gzip and MCAP inputs (fixed seed) never give an
untyped exception or a hang. Bounded to ~30 s in total (a time budget per format, a few thousand
inputs each on an idle machine); ``python -m tools.fuzz`` runs 100,000 per format."""

from __future__ import annotations

import pytest

from tools import fuzz

BUDGET_S = 6.5  # per format; 4 formats + seeds stay within ~30 s
COUNT = 3000


@pytest.fixture(scope="module")
def seeds():
    return fuzz.build_seeds()


@pytest.mark.parametrize("fmt", fuzz.FORMATS)
def test_fuzz_smoke(fmt, seeds):
    res = fuzz.run([fmt], count=COUNT, seed=20261123, timeout_s=10.0, seeds=seeds,
                   time_budget_s=BUDGET_S)[fmt]
    c = res["counts"]
    print(f"{fmt}: {res['inputs']} inputs in {res['seconds']:.1f} s: {dict(c)}")
    assert res["inputs"] >= 150, f"only {res['inputs']} inputs ran in {BUDGET_S} s"
    assert c["untyped"] == 0 and c["hang"] == 0, res["kinds"].most_common(10)
    assert c["ok"] > 0 and c["typed"] > 0  # the mutations reach both outcomes


def test_mutators_are_deterministic(seeds):
    import numpy as np
    a = [fuzz.MUTATORS["cwa"](seeds["cwa"][0], np.random.default_rng(5)) for _ in range(1)]
    b = [fuzz.MUTATORS["cwa"](seeds["cwa"][0], np.random.default_rng(5)) for _ in range(1)]
    assert a == b
