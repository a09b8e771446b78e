"""Window means of quantised samples, de-biased.

A device that stores coarse steps (AX3 packed at +-8 g: 15.6 mg) and is truly still (on a table,
or a worn wrist that hardly moves) reads Q(x + e) with e its white noise: when the noise SD is
below about half a step the window mean of those readings is pulled towards the nearest level by
up to (step / pi) exp(-2 pi^2 (sd / step)^2) (1.5 mg for 3.9 mg of noise), and the pull depends on
where x sits between two levels. As a cooling device drifts across levels, the pull becomes a
staircase in temperature, and the autocalibration turns it into a wrong temperature coefficient
(docs/calibration.md, "Why the simulator's default recordings gave wrong temperature coefficients").

:func:`dequantise_means` inverts it per window and axis: with the window's mean m and sample
variance s^2 of n readings, it solves mu(x, sigma) = m and v(x, sigma) = s^2 for the value x and
noise SD sigma, where mu and v are the exact mean and variance of Q(x + sigma z)
(:func:`level_moments`, rounding to the nearest level; a device that truncates instead reads the
same with x shifted by half a step, a constant the calibration offset absorbs). The problem is
periodic and scale-free, so it is solved on tables in units of the step. Windows whose spread
already dithers the step come back practically unchanged.

Building the tables needs ``scipy.special`` (~0.25 s to import) and ~0.1 s of arithmetic, more
than the de-biasing of a week of windows: they are built once per machine and kept in the user's
cache (engine/core/cache.py; a cache that cannot be read or written only costs the build).
"""

from __future__ import annotations

from dataclasses import replace
from functools import lru_cache
from typing import Optional

from ..core.cache import cached_array

import numpy as np

SPAN = 7.0  # levels within +-SPAN sigma of x carry the mass
# noise SD grid in steps: from 0.12 (below it the reading variance is not increasing in sigma
# at every mean; AX3 packed +-8 g noise is 0.18-0.25 steps) to 1.5 (the pull is nil beyond)
SIGMA = np.exp(np.linspace(np.log(0.12), np.log(1.5), 121))
GRID_X = 1024  # positions within a step for the tables
MU = np.linspace(0.0, 1.0, 513)  # fractional means for the tables
CHUNK = 512  # windows solved at a time: (CHUNK, sigma grid) temporaries of ~0.5 MB each


def level_count(x: np.ndarray, s: np.ndarray, step: float, span: float = SPAN) -> int:
    """How many levels ``level_moments`` sums over for these elements (the widest one's)."""
    s = np.maximum(np.asarray(s, np.float64), 1e-12)
    return int(np.max(np.ceil((x + span * s) / step) - np.floor((x - span * s) / step))) + 1 \
        if np.size(x) else 0


def level_moments(x: np.ndarray, s: np.ndarray, step: float, span: float = SPAN,
                  levels: Optional[int] = None):
    """Exact mean and variance of Q(x + s z) (rounding to multiples of ``step``), per element;
    ``levels``: how many levels to sum over from each element's lowest (default
    ``level_count``: a larger count adds only far levels of ~zero mass)."""
    from scipy.special import ndtr  # imported only when the tables are built

    x = np.asarray(x, np.float64)
    s = np.maximum(np.asarray(s, np.float64), 1e-12)
    k_lo = np.floor((x - span * s) / step)
    k_n = level_count(x, s, step, span) if levels is None else int(levels)
    m = np.zeros_like(x)
    m2 = np.zeros_like(x)
    for j in range(k_n):
        lev = (k_lo + j) * step
        p = ndtr((lev + 0.5 * step - x) / s) - ndtr((lev - 0.5 * step - x) / s)
        m += p * lev
        m2 += p * lev * lev
    return m, np.maximum(m2 - m * m, 0.0)


def dequantised(features, step):
    """``features`` (WindowFeatures) with their window means de-biased for ``step`` (g)."""
    return replace(features, mean=dequantise_means(features.mean, features.sd, step))


def dequantise_means(mean: np.ndarray, sd: np.ndarray, step) -> np.ndarray:
    """Window means (k, 3) g of readings quantised to ``step`` (g, scalar or per axis) with
    their sample SDs ``sd`` (k, 3): the de-biased means (see the module docstring)."""
    m = np.asarray(mean, np.float64).reshape(-1, 3)
    v_obs = np.asarray(sd, np.float64).reshape(-1, 3) ** 2
    q = np.broadcast_to(np.asarray(step, np.float64), (3,))
    out = m.copy()
    for k in range(3):
        if q[k] > 0:
            for a in range(0, m.shape[0], CHUNK):  # (chunk, sigma grid) temporaries stay small
                out[a:a + CHUNK, k] = _solve(m[a:a + CHUNK, k], v_obs[a:a + CHUNK, k], float(q[k]))
    return out


@lru_cache(maxsize=1)
def _tables():
    """(X, V) of :func:`build_tables`, through the user's cache (engine/core/cache.py): built on a
    machine's first use, then loaded (~1 ms instead of ~0.35 s with scipy.special's import)."""
    key = (SPAN, GRID_X, SIGMA.tobytes(), MU.tobytes(), _scipy_version())
    xv = cached_array("quantisation_tables", key, lambda: np.stack(build_tables()),
                      shape=(2, MU.size, SIGMA.size))
    return xv[0], xv[1]


def release_tables() -> None:
    """Let the tables go (~1 MB; loaded again on the next use, ~1 ms): a batch run's pass 2
    fits nothing."""
    _tables.cache_clear()


def _scipy_version() -> str:
    from importlib.metadata import PackageNotFoundError, version
    try:
        return version("scipy")  # the tables' ndtr (metadata only: scipy itself not imported)
    except PackageNotFoundError:
        return ""


def build_tables():
    """In units of the step (the problem is scale-free and periodic): for each noise SD on the
    grid ``SIGMA`` and each fractional mean on ``MU`` (one period), the position x in the period
    that gives that mean (``X``) and the variance of the readings there (``V``)."""
    phi = np.linspace(0.0, 1.0, GRID_X + 1)
    X = np.empty((MU.size, SIGMA.size))
    V = np.empty((MU.size, SIGMA.size))
    # one SD at a time (temporaries of one column, not of the grid), each summed over the
    # levels of the widest column (the largest SD), as the whole grid at once was (same bits)
    n = level_count(phi, np.full(phi.size, SIGMA.max()), 1.0)
    for j in range(SIGMA.size):
        mu, v = level_moments(phi, np.full(phi.size, SIGMA[j]), 1.0, levels=n)
        mu[0], mu[-1] = 0.0, 1.0  # the period's ends sit on levels (exact by symmetry)
        X[:, j] = np.interp(MU, mu, phi)  # the mean is increasing in x: invert by interpolation
        V[:, j] = np.interp(MU, mu, v)
    return X, V


def _solve(m: np.ndarray, v_obs: np.ndarray, q: float) -> np.ndarray:
    """One axis, vectorised over windows, by the tables: at the window's fractional mean, the
    reading variance increases with sigma, so sigma is where it meets the observed s^2
    (clamped to the grid), and x is the position that gives the observed mean at that sigma."""
    out = m.copy()
    ok = np.isfinite(m) & np.isfinite(v_obs) & (v_obs < (SIGMA[-1] * q) ** 2)
    if not np.any(ok):
        return out
    X, V = _tables()
    level = np.floor(m[ok] / q)
    f = (m[ok] / q - level) * (MU.size - 1)
    i0 = np.minimum(f.astype(np.int64), MU.size - 2)
    t = (f - i0)[:, None]
    vrow = (1 - t) * V[i0] + t * V[i0 + 1]  # (k, sigma grid)
    vn = v_obs[ok] / (q * q)
    j = np.clip(np.sum(vrow < vn[:, None], axis=1), 1, SIGMA.size - 1)  # first grid sigma above
    r = np.arange(j.size)
    lo, hi = vrow[r, j - 1], vrow[r, j]
    w = np.clip((vn - lo) / np.where(hi > lo, hi - lo, 1.0), 0.0, 1.0)
    t = t[:, 0]
    x_lo = (1 - t) * X[i0, j - 1] + t * X[i0 + 1, j - 1]  # the position row at the two sigmas
    x_hi = (1 - t) * X[i0, j] + t * X[i0 + 1, j]
    x = (1 - w) * x_lo + w * x_hi
    out[np.nonzero(ok)[0]] = (level + x) * q
    return out
