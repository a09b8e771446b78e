"""In-process fuzz smoke test: mutated .cwa, .bin, gzip and MCAP inputs (fixed seed) never give an
untyped exception or a hang. A fixed number of inputs per format (the same inputs on every machine,
whatever its load; ~10 s in all); ``python -m tools.fuzz`` runs 100,000 per format."""

from __future__ import annotations

import pytest

from tools import fuzz

COUNT = 500  # per format: MCAP inputs are also replayed (~10 ms each), the others cost less


@pytest.fixture(scope="module")
def seeds():
    return fuzz.build_seeds()


@pytest.mark.parametrize("fmt", fuzz.FORMATS)
def test_fuzz_smoke(fmt, seeds):
    res = fuzz.run([fmt], count=COUNT, seed=20261123, timeout_s=10.0, seeds=seeds)[fmt]
    c = res["counts"]
    print(f"{fmt}: {res['inputs']} inputs in {res['seconds']:.1f} s: {dict(c)}")
    assert res["inputs"] == COUNT
    assert c["untyped"] == 0 and c["hang"] == 0, res["kinds"].most_common(10)
    assert c["ok"] > 0  # the mutations reach both outcomes (a request is answered: never typed)
    assert c["typed"] > 0 or fmt == "http"


def test_mutators_are_deterministic(seeds):
    import numpy as np
    a = [fuzz.MUTATORS["cwa"](seeds["cwa"][0], np.random.default_rng(5)) for _ in range(1)]
    b = [fuzz.MUTATORS["cwa"](seeds["cwa"][0], np.random.default_rng(5)) for _ in range(1)]
    assert a == b
