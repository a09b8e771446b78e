"""Warm starts with Anderson mixing (engine/calibration/refit.py): on still windows that cover
the sphere unevenly, as a wrist's do, the plain ICP crawls to its fixed point (hundreds of
iterations even from the previous fit); the mixed iterations get there in a few dozen at most,
and the fit's own loop, started there, stops at once at the same fixed point."""

from __future__ import annotations

import numpy as np
import pytest

from stillpoint.engine.calibration import refit
from stillpoint.engine.calibration.fit import icp_sphere_fit


def _lopsided_windows(n=6000, seed=5):
    """Window means (g) and centred temperatures of a sensor with known offset, gain and
    temperature errors, still mostly with one side up (orientations bunched on a hemisphere)."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d[:, 2] = np.abs(d[:, 2])
    d[:, 0] += 0.4
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t = rng.normal(0.0, 2.0, n)
    off, sc, to = np.array([0.02, -0.015, 0.03]), np.array([1.02, 0.985, 1.01]), np.array([5e-4, -3e-4, 2e-4])
    mean = (d - t[:, None] * to) / sc - off + rng.normal(0.0, 0.002, (n, 3))
    return mean, t


def test_mixed_iterations_reach_the_plain_fixed_point_in_far_fewer_steps(monkeypatch):
    mean, t = _lopsided_windows()
    first = icp_sphere_fit(mean[:5000], t[:5000])  # the fit 12 h earlier, on fewer windows
    start = np.concatenate([first.offset, first.scale, first.tempoffset])
    exact = icp_sphere_fit(mean, t, param_tol=1e-14, max_iter=20000)
    assert exact.converged
    plain = icp_sphere_fit(mean, t, start=(first.offset, first.scale, first.tempoffset))
    assert plain.converged and plain.iterations > 200  # the slow case this is for
    calls = []

    def counted(*a, **k):
        calls.append(k.get("max_iter"))
        return icp_sphere_fit(*a, **k)

    monkeypatch.setattr(refit, "icp_sphere_fit", counted)
    v = refit.anderson_iterate(mean, t, start)
    assert 3 <= len(calls) <= 30 and set(calls) == {1}
    fit = icp_sphere_fit(mean, t, start=(v[:3], v[3:6], v[6:]))
    assert fit.converged and fit.iterations <= 2
    for r in (fit, plain):  # both within the loop's tolerance of the same fixed point
        np.testing.assert_allclose(r.offset, exact.offset, atol=1e-7)
        np.testing.assert_allclose(r.scale, exact.scale, atol=1e-7)
        np.testing.assert_allclose(r.tempoffset, exact.tempoffset, atol=1e-8)


def test_mixing_survives_a_breakdown():
    mean, t = _lopsided_windows(n=200)
    bad = mean.copy()
    bad[:] = 0.0  # every point at the origin: the first iteration breaks down
    start = np.r_[np.zeros(3), np.ones(3), np.zeros(3)]
    assert refit.anderson_iterate(bad, None, start) is None
    v = refit.anderson_iterate(mean, t, start, max_steps=2)  # stopped early: the best so far
    assert v is not None and np.all(np.isfinite(v))
    one = icp_sphere_fit(mean, t, max_iter=1, start=(start[:3], start[3:6], start[6:]))
    two = icp_sphere_fit(mean, t, max_iter=1, start=(one.offset, one.scale, one.tempoffset))
    # two steps of a slow contraction: the second plain iterate changes less than the first
    assert np.allclose(v, np.concatenate([two.offset, two.scale, two.tempoffset]))


@pytest.mark.parametrize("depth", [1, 5])
def test_depth_only_changes_the_path(depth):
    mean, t = _lopsided_windows(n=3000, seed=9)
    exact = icp_sphere_fit(mean, t, param_tol=1e-14, max_iter=20000)
    v = refit.anderson_iterate(mean, t, np.r_[np.zeros(3), np.ones(3), np.zeros(3)], depth=depth,
                               max_steps=400)
    np.testing.assert_allclose(v[:3], exact.offset, atol=1e-7)
    np.testing.assert_allclose(v[3:6], exact.scale, atol=1e-7)
