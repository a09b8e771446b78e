"""MIMS-units' extrapolation of near-range samples (John et al. 2019, J Meas Phys Behav 2(4):268-281,
section "Extrapolation"), reproducing the reference implementation (R package MIMSunit 0.11.2,
mHealthGroup/MIMSunit, MIT; R/extrapolate.R, re-written here) on the 100 Hz signal, axis by axis:

1. **marker** (``.mark_gamma``): a sample ``v >= 0`` gets ``pgamma(v - (range - 5 * sd), shape)``,
   a sample ``v < 0`` gets ``-pgamma(-v - (range - 5 * sd))``, with ``sd = noise_level + 1e-5``
   (``noise_level`` 0.03 g) and the gamma shape for which ``pgamma(3 * sd, shape)`` is nearest
   0.95 on the grid 0.5, 0.499, ..., 0.001 (``.optimize_gamma``). The shape is about 0.02, so a
   sample beyond ``range - 0.15 g`` gets a marker above 0.5 and one below it 0;
2. **runs** (``.extrapolate_edges``): a run of a hill starts at a sample whose marker rose by more
   than 0.5 from the previous one (``left_end``) and ends at a sample whose marker falls by more
   than 0.5 to the next one (``right_start``); valleys alike with the signs turned. A run at the
   segment's start or end is extrapolated only if it is longer than 5 s (500 samples), and then
   its samples become -200 (the reference's "extra huge value": the epochs holding them have no
   value and the filter skips them, R/mims_unit.R); shorter ones are only dropped in step 4;
3. **fits** (``.fit_weighted``): on each side a weighted smoothing spline (``stats::smooth.spline``,
   ``spar`` 0.6) through 5 points (``k * sr`` = 0.05 s x 100 Hz): the run's first sample and the 4
   before it (left), its last sample and the 4 after it (right), linearly re-gridded to 5 equally
   spaced points (``stats::approx(n = 5)``), values and weights ``1 - marker`` alike. Each fit is
   evaluated (linearly extended beyond its data, ``predict.smooth.spline``) at the run's middle
   time ``t_left_end + (t_right_start - t_left_end) / 2``, and the two values are averaged;
4. **re-interpolation** (``.extrapolate_interpolate``): the samples whose marker is at least 0.5 in
   magnitude are dropped, the runs' middle points added, and the 100 Hz grid re-evaluated by an
   interpolating cubic spline (``stats::spline``, method "fmm": Forsythe, Malcolm and Moler's end
   conditions). Kept samples keep their values; dropped ones get the spline's.

``stats::smooth.spline`` with 5 distinct x and ``spar`` given (R's stats, smooth.spline.R, sbart.c,
sgram.f, stxwx.f, sslvrg.f): x is scaled to [0, 1]; weights are normalised to
``w * sum(w > 0) / sum(w)``; the basis is the cubic B-splines on the knots
``(0, 0, 0, 0, x2, x3, x4, 1, 1, 1, 1)`` (all 5 scaled x as knots: fewer than 50 points); the
penalty matrix is the integral of products of the basis' second derivatives, computed with the
linear second derivatives' exact formula except that 1/3 is written 0.3330 (sgram.f); the
coefficients solve ``(X'WX + lambda * Sigma) c = X'Wy`` with
``lambda = r * 256^(3 * spar - 1)``, ``r = tr(X'WX) / tr(Sigma)`` over the diagonal elements 3 to
``nk - 3`` only (sbart.c).

Streaming: runs are local. Each axis's runs are resolved one by one, as soon as ``CONTEXT`` samples
below the band (and the 5 samples the fits need) follow the run: the run's samples get the fmm
spline through the ``CONTEXT`` kept samples before and after it and the middle points of the
runs among them (an interpolating spline's dependence on a knot decays by about 0.27 per knot, so
40 knots leave differences from the spline through the whole segment below 1e-22 relative). The
samples from the first unresolved run on are held back; the fits of all the runs resolved
together are computed at once. Within ``CONTEXT`` kept samples of the segment's edges the spline's
end conditions are the reference's. Which samples form a run's spline depends on the samples
only, so the result does not depend on how the stream was cut.

Not reproduced (the reference decides these on the whole segment at once):

- a run that needs more than ``MAX_HOLD`` samples (10 min at 100 Hz) with the kept samples after
  it (an axis stuck at the range): its samples go out as recorded, so memory stays bounded, and
  the epochs holding them are counted (``MimsOperator.unextrapolated_epochs``);
- a segment in which fewer than 30 % of an axis's samples are below the near-range band: the
  reference then extrapolates nothing on that axis; here it is extrapolated as usual;
- a segment whose both ends are within near-range runs of the same axis and sign, in different
  clusters: the reference's pairing of run starts and ends then shifts across the whole segment;
  here each end is treated on its own.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

NOISE_LEVEL_G = 0.03  # R/mims_unit.R mims_unit: noise_level = 0.03
NOISE_SD_EPS = 1e-05  # R/extrapolate.R .mark_gamma: noise_sd <- noise_sd + 1e-05
GAMMA_P = 0.95  # R/extrapolate.R .optimize_gamma: confident probability 0.95 at 3 sd
CONFIDENT = 0.5  # R/extrapolate.R .extrapolate_neighbor / .extrapolate_interpolate: confident = 0.5
NEIGHBOURS = 5  # R/mims_unit.R k = 0.05 (s) x 100 Hz (R/extrapolate.R: n_neighbor <- k * sr)
SPAR = 0.6  # R/mims_unit.R mims_unit: spar = 0.6
EDGE_SAMPLES = 500  # R/extrapolate.R .extrapolate_edges: threshold_maxedout <- sr * 5
EDGE_VALUE = -200.0  # R/extrapolate.R .extrapolate_fit: rep(-200, n_rep) "extra huge value"
ABNORMAL_BELOW = -150.0  # R/mims_unit.R: rows with a value < -150 skip the filter
MIN_KEPT_FRACTION = 0.3  # R/extrapolate.R .extrapolate_interpolate: length_t_mark / length(t) < 0.3
SGRAM_THIRD = 0.3330  # R stats sgram.f: yw2(ii)*yw2(jj)*0.3330d0 (the integral's 1/3)
CONTEXT = 40  # kept samples each side of a run in its re-interpolating spline
MAX_HOLD = 60_000  # 100 Hz samples a run and its context may hold back (10 min)


@lru_cache(maxsize=8)
def gamma_shape(noise_level: float = NOISE_LEVEL_G) -> float:
    """``.optimize_gamma(3 * (noise_level + 1e-5))``: the shape on the grid 0.5, 0.499, ..., 0.001
    where ``pgamma(value, shape)`` first reaches 0.95, or the grid point before it if that one is
    nearer 0.95."""
    from scipy.special import gammainc
    value = 3 * (noise_level + NOISE_SD_EPS)
    shapes = 0.5 + np.arange(500) * -0.001  # seq(0.5, 0.001, by = -0.001)
    p = gammainc(shapes, value)
    prev = np.concatenate([[1.0], p[:-1]])
    hit = np.flatnonzero((prev < GAMMA_P) & (p >= GAMMA_P))
    if not hit.shape[0]:
        return 0.0
    i = int(hit[0])
    return float(shapes[i]) if abs(GAMMA_P - prev[i]) > abs(p[i] - GAMMA_P) else float(shapes[i - 1])


def markers(v: np.ndarray, range_g: float, noise_level: float = NOISE_LEVEL_G) -> np.ndarray:
    """The gamma-rule marker of every value (any shape): 0 well inside the range, about +1 near
    the top of it, about -1 near the bottom."""
    from scipy.special import gammainc
    sd = noise_level + NOISE_SD_EPS
    hi = v - (range_g - 5 * sd)
    lo = -v + (-range_g + 5 * sd)
    m = np.zeros(v.shape)
    up = (v >= 0) & (hi > 0)
    down = (v < 0) & (lo > 0)
    if up.any() or down.any():
        shape = gamma_shape(noise_level)
        m[up] = gammainc(shape, hi[up])
        m[down] = -gammainc(shape, lo[down])
    return m


# -- stats::smooth.spline through 5 points, batched -------------------------------------------

def _approx5(x: np.ndarray, y: np.ndarray) -> tuple:
    """``stats::approx(x, y, n = 5)`` row by row: (xout, yout) at ``seq.int(x[1], x[n],
    length.out = 5)``."""
    a, b = x[:, :1], x[:, -1:]
    by = (b - a) / 4.0
    k = np.arange(5, dtype=np.float64)
    xo = np.where(k < 2, a + k * by, b - (4 - k) * by)  # R's seq.int(from, to, length.out)
    xo[:, 0], xo[:, -1] = a[:, 0], b[:, 0]
    n = x.shape[1]
    i = np.clip((x[:, None, :] <= xo[:, :, None]).sum(axis=2) - 1, 0, n - 2)  # bisection's i
    rows = np.arange(x.shape[0])[:, None]
    xi, xj, yi, yj = x[rows, i], x[rows, i + 1], y[rows, i], y[rows, i + 1]
    with np.errstate(invalid="ignore", divide="ignore"):
        yo = yi + (yj - yi) * ((xo - xi) / (xj - xi))
    yo = np.where(xo == xj, yj, np.where(xo == xi, yi, yo))
    return xo, yo


def _basis(knots: np.ndarray, x: np.ndarray, interval: np.ndarray, deriv: int) -> np.ndarray:
    """Cubic B-spline basis (or its ``deriv``-th derivative) on ``knots`` (F, nk + 4) at x (F, P),
    each x evaluated with the polynomial piece of its knot interval ``interval`` (F, P); -> (F, P,
    nk)."""
    nt = knots.shape[1]
    T = knots[:, None, :]
    xx = x[..., None]
    N = (np.arange(nt - 1)[None, None, :] == interval[..., None]).astype(np.float64)

    def ratio(num, den):
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(den > 0, num / np.where(den > 0, den, 1.0), 0.0)

    levels = [N]
    for d in range(1, 4):
        left = ratio(xx - T[..., :nt - 1 - d], T[..., d:nt - 1] - T[..., :nt - 1 - d])
        right = ratio(T[..., d + 1:] - xx, T[..., d + 1:] - T[..., 1:nt - d])
        N = left * N[..., :-1] + right * N[..., 1:]
        levels.append(N)
    if deriv == 0:
        return levels[3]
    # derivatives: dB(i,d) = d * (B(i,d-1) / (t[i+d] - t[i]) - B(i+1,d-1) / (t[i+d+1] - t[i+1]))
    D = levels[3 - deriv]
    for d in range(4 - deriv, 4):
        D = d * (ratio(D[..., :-1], T[..., d:nt - 1] - T[..., :nt - 1 - d])
                 - ratio(D[..., 1:], T[..., d + 1:] - T[..., 1:nt - d]))
    return D


def smooth_spline_predict(x: np.ndarray, y: np.ndarray, w: np.ndarray, xo: np.ndarray,
                          spar: float = SPAR) -> np.ndarray:
    """``predict(stats::smooth.spline(x, y, w, spar = spar), xo)$y`` for F fits at once: x, y, w
    (F, 5) with x increasing, xo (F,) (see the module docstring)."""
    F, n = x.shape
    w = (w * (w > 0).sum(axis=1, keepdims=True)) / w.sum(axis=1, keepdims=True)
    ybar = (w * y) / np.where(w > 0, w, 1.0)
    lo, rng = x[:, :1], x[:, -1:] - x[:, :1]
    xbar = (x - lo) / rng
    knots = np.concatenate([np.repeat(xbar[:, :1], 3, axis=1), xbar,
                            np.repeat(xbar[:, -1:], 3, axis=1)], axis=1)  # (F, nk + 4)
    nk = n + 2
    last = nk - 1  # the last non-empty knot interval (0-based)
    first = 3
    # data: each x in its interval [t_l, t_l+1) (the right end in the last one)
    iv = np.clip(np.arange(n) + first, first, last)[None, :] * np.ones((F, 1), np.int64)
    X = _basis(knots, xbar, iv, 0)  # (F, n, nk)
    ws = np.sqrt(w)  # sbart.c: ws <- sqrt(ws); stxwx.f uses ws^2
    w2 = ws * ws
    XtWX = np.einsum("fi,fij,fik->fjk", w2, X, X)
    XtWy = np.einsum("fi,fij->fj", w2 * ybar, X)
    # Sigma (sgram.f): over each interval, B'' is linear between its ends' values
    a = knots[:, first:last + 1]
    b = knots[:, first + 1:last + 2]
    ivs = np.arange(first, last + 1)[None, :] * np.ones((F, 1), np.int64)
    y1 = _basis(knots, a, ivs, 2)
    y2 = _basis(knots, b, ivs, 2) - y1
    wpt = (b - a)[..., None, None]
    S = (wpt * (y1[..., :, None] * y1[..., None, :]
                + (y2[..., :, None] * y1[..., None, :] + y2[..., None, :] * y1[..., :, None]) * 0.5
                + y2[..., :, None] * y2[..., None, :] * SGRAM_THIRD)).sum(axis=1)
    d = np.arange(2, nk - 3)  # sbart.c: for (i = 3 - 1; i < (*nk - 3); ++i)
    ratio = XtWX[:, d, d].sum(axis=1) / S[:, d, d].sum(axis=1)
    lam = ratio * 16.0 ** (spar * 6.0 - 2.0)
    coef = np.linalg.solve(XtWX + lam[:, None, None] * S, XtWy[..., None])[..., 0]
    # predict.smooth.spline.fit: inside [0, 1] the spline, outside its ends' value and slope
    xs = (xo - lo[:, 0]) / rng[:, 0]
    ends = np.stack([np.zeros(F), ((lo[:, 0] + rng[:, 0]) - lo[:, 0]) / rng[:, 0]], axis=1)
    end_iv = np.stack([np.full(F, first), np.full(F, last)], axis=1)
    end_val = np.einsum("fpk,fk->fp", _basis(knots, ends, end_iv, 0), coef)
    end_slope = np.einsum("fpk,fk->fp", _basis(knots, ends, end_iv, 1), coef) / rng * rng
    iv_o = np.clip((knots[:, first:last + 1] <= xs[:, None]).sum(axis=1) - 1 + first,
                   first, last)[:, None]
    val = np.einsum("fk,fk->f", _basis(knots, xs[:, None], iv_o, 0)[:, 0, :], coef)
    val = np.where(xs < 0, end_val[:, 0] + end_slope[:, 0] * (xs - 0), val)
    val = np.where(xs > 1, end_val[:, 1] + end_slope[:, 1] * (xs - 1), val)
    return val


# -- stats::spline(method = "fmm") -------------------------------------------------------------

def fmm_spline(x: np.ndarray, y: np.ndarray, xo: np.ndarray) -> np.ndarray:
    """``stats::spline(x, y, xout = xo, method = "fmm")`` for increasing x without ties: the
    interpolating cubic spline whose third derivatives at the ends are those of the cubics through
    the first and last 4 points (R's splines.c ``fmm_spline``, ``spline_eval``)."""
    from scipy.linalg import solve_banded
    n = x.shape[0]
    if n == 1:
        return np.full(xo.shape, y[0])
    h = np.diff(x)
    s = np.diff(y) / h  # slopes
    if n == 2:
        return y[0] + (xo - x[0]) * s[0]
    rhs = np.zeros(n)
    rhs[1:-1] = s[1:] - s[:-1]
    if n > 3:
        rhs[0] = rhs[2] / (x[3] - x[1]) - rhs[1] / (x[2] - x[0])
        rhs[-1] = rhs[-2] / (x[-1] - x[-3]) - rhs[-3] / (x[-2] - x[-4])
        rhs[0] = rhs[0] * h[0] * h[0] / (x[3] - x[0])
        rhs[-1] = -rhs[-1] * h[-1] * h[-1] / (x[-1] - x[-4])
    ab = np.zeros((3, n))
    ab[0, 1:] = h  # upper diagonal
    ab[2, :-1] = h  # lower diagonal
    ab[1, 0], ab[1, -1] = -h[0], -h[-1]
    ab[1, 1:-1] = 2.0 * (h[:-1] + h[1:])
    sig = solve_banded((1, 1), ab, rhs)
    b = np.empty(n)
    b[:-1] = s - h * (sig[1:] + 2.0 * sig[:-1])
    b[-1] = s[-1] + h[-1] * (sig[-2] + 2.0 * sig[-1])
    d = np.empty(n)
    d[:-1] = (sig[1:] - sig[:-1]) / h
    d[-1] = d[-2]
    c = 3.0 * sig
    i = np.clip(np.searchsorted(x, xo, side="right") - 1, 0, n - 1)
    dx = xo - x[i]
    return y[i] + dx * (b[i] + dx * (c[i] + dx * d[i]))


# -- runs and their middle points --------------------------------------------------------------

def _pairs(lefts: list, rights: list, n_segment: int | None) -> list:
    """``.extrapolate_edges`` for one sign: (left_end, right_start) index pairs (global, 0-based;
    -1: the run reaches the segment's edge and is longer than 5 s). ``n_segment``: the segment's
    length when the block reaches its end (else the end case cannot arise)."""
    L, R = list(lefts), list(rights)
    if len(L) - len(R) == 1:
        if n_segment is not None and n_segment - (L[-1] + 1) > EDGE_SAMPLES:
            R.append(-1)
        else:
            L = L[:-1]
    elif len(L) != len(R):  # R: `length(left) - length(right == -1)`, i.e. any other difference
        if R and R[0] + 1 > EDGE_SAMPLES:
            L = [-1] + L
        else:
            R = R[1:]
    if len(R) > 1 and any(r - l < 0 for l, r in zip(L, R)):
        L, R = L[:-1], R[1:]
    return list(zip(L, R))


def run_pairs(m: np.ndarray, k0: int, k1: int, offset: int, n_segment: int | None) -> list:
    """The (left_end, right_start) pairs (segment indices; -1: a run reaching the segment's edge,
    longer than 5 s) of one axis's runs among the samples [k0, k1) of ``m``, the markers of the
    segment's samples ``offset`` onwards. ``n_segment``: the segment's length if ``m`` reaches
    its end."""
    dl = np.diff(m, prepend=m[:1])  # R: c(0, diff(marker)) at the segment's start
    dr = np.diff(m, append=m[-1:])  # R: c(diff(marker), 0) at its end
    inside = np.zeros(m.shape[0], bool)
    inside[k0:k1] = True
    pairs = []
    for sign in (1.0, -1.0):
        lefts = np.flatnonzero((sign * dl > CONFIDENT) & (sign * m > 0) & inside) + offset
        rights = np.flatnonzero((sign * dr < -CONFIDENT) & (sign * m > 0) & inside) + offset
        pairs += _pairs(lefts.tolist(), rights.tolist(), n_segment)
    return pairs


def middle_points(x: np.ndarray, v: np.ndarray, m: np.ndarray, pairs: list, offset: int) -> tuple:
    """Each run's middle time and value: the average of the two weighted smoothing splines'
    predictions there (``.extrapolate_fit``), for many runs at once; x, v, m: one axis's samples
    from segment index ``offset`` (the runs' 5 samples each side included, or the segment's
    edge). -> (times, values) aligned with ``pairs`` (NaN where a side has fewer than 2
    samples)."""
    n = x.shape[0]
    wins = []
    for le, rs in pairs:
        a, b = le - offset, rs - offset
        wins.append((np.arange(max(a - NEIGHBOURS + 1, 0), a + 1),
                     np.arange(b, min(b + NEIGHBOURS - 1, n - 1) + 1), x[a] + (x[b] - x[a]) / 2.0))
    t_mid = np.array([w[2] for w in wins], np.float64)
    preds = []
    for side in (0, 1):
        out = np.full(len(wins), np.nan)
        lens = np.array([w[side].shape[0] for w in wins], np.int64)
        for k in np.unique(lens):
            if k < 2:
                continue
            sel = np.flatnonzero(lens == k)
            idx = np.stack([wins[i][side] for i in sel])
            xa, ya = _approx5(x[idx], v[idx])
            _, wa = _approx5(x[idx], 1.0 - m[idx])
            out[sel] = smooth_spline_predict(xa, ya, wa, t_mid[sel])
        preds.append(out)
    return t_mid, (preds[0] + preds[1]) / 2.0


def spline_fill(x: np.ndarray, v: np.ndarray, m: np.ndarray, mid_t: np.ndarray,
                mid_v: np.ndarray, edge: np.ndarray) -> np.ndarray:
    """``.extrapolate_interpolate`` on a stretch of one axis: the samples whose marker is below
    0.5 in magnitude, the runs' middle points and the -200 samples at the indices ``edge`` as
    knots (ties averaged, as ``regularize.values``), the fmm spline through them evaluated at
    every sample's time."""
    keep = np.abs(m) < CONFIDENT
    ok = np.isfinite(mid_v)
    kx = np.concatenate([x[keep], mid_t[ok], x[edge]])
    ky = np.concatenate([v[keep], mid_v[ok], np.full(edge.shape[0], EDGE_VALUE)])
    order = np.argsort(kx, kind="stable")
    kx, ky = kx[order], ky[order]
    if kx.shape[0] and (np.diff(kx) == 0).any():
        ux, inv = np.unique(kx, return_inverse=True)
        ky = np.bincount(inv, weights=ky) / np.bincount(inv)
        kx = ux
    if not kx.shape[0]:
        return v.copy()
    return fmm_spline(kx, ky, x)


# -- streaming -----------------------------------------------------------------------------------

class Extrapolator:
    """The 100 Hz samples of one segment -> the same samples extrapolated, in order:
    ``push(x, v)`` and ``flush()`` return ``(x, v, flags)`` of the samples that are final, with
    ``flags`` (n, 2) bool: [near range (marked on any axis), left as recorded (a run that needed
    more than ``MAX_HOLD`` samples)]. See the module docstring."""

    def __init__(self, range_g: float):
        self.range_g = float(range_g)
        self.x = np.zeros(0)
        self.raw = np.zeros((0, 3))  # the samples as they came (the fits' and the spline's data)
        self.val = np.zeros((0, 3))  # the samples as they go out
        self.m = np.zeros((0, 3))  # their markers
        self.asis = np.zeros((0, 3), bool)
        self.base = 0  # segment index of the buffers' first sample
        self.n = 0  # samples seen
        self.done = 0  # first sample not given out
        self.next = [0, 0, 0]  # per axis: first sample not resolved
        self.abandoned = [False, False, False]  # per axis: in a run going out as recorded

    def push(self, x: np.ndarray, v: np.ndarray):
        if x.shape[0]:
            self.x = np.concatenate([self.x, x])
            self.raw = np.concatenate([self.raw, v])
            self.val = np.concatenate([self.val, v])
            self.m = np.concatenate([self.m, markers(v, self.range_g)])
            self.asis = np.concatenate([self.asis, np.zeros((x.shape[0], 3), bool)])
            self.n += x.shape[0]
        return self._advance(final=False)

    def flush(self):
        return self._advance(final=True)

    def _kept(self, c: int, a: int, b: int) -> np.ndarray:
        """Segment indices of the samples in [a, b) not marked on axis c."""
        return np.flatnonzero(np.abs(self.m[a - self.base:b - self.base, c]) < CONFIDENT) + a

    def _left(self, c: int, s: int) -> int:
        """Where the spline for a run starting at s starts: its CONTEXT-th kept sample before s
        (no further back than MAX_HOLD samples, nor than the segment's start)."""
        lim = max(0, s - MAX_HOLD)
        kept = self._kept(c, max(lim, self.base), s)  # the buffer holds it (see _advance)
        return int(kept[-CONTEXT]) if kept.shape[0] >= CONTEXT else lim

    def _axis(self, c: int, end: int, final: bool) -> None:
        """Resolve axis c's runs as far as the samples allow: find them (and those to leave as
        recorded), then fit all their neighbours' splines at once and fill each run."""
        b = self.base
        runs = []  # (first, stop, lo, hi, a0, a1, n_segment or None)
        while True:
            s0 = self.next[c]
            if s0 >= end:
                break
            marked = np.abs(self.m[s0 - b:end - b, c]) >= CONFIDENT
            if self.abandoned[c]:  # as recorded up to the run's first kept sample
                k = np.flatnonzero(~marked)
                stop = int(k[0]) + s0 if k.shape[0] else end
                self.asis[s0 - b:stop - b, c] = True
                self.next[c] = stop
                if not k.shape[0]:
                    break
                self.abandoned[c] = False
                continue
            j = np.flatnonzero(marked)
            if not j.shape[0]:
                self.next[c] = end
                break
            s = int(j[0]) + s0
            self.next[c] = s
            kept = np.flatnonzero(~marked[s - s0:]) + s
            e = int(kept[0]) - 1 if kept.shape[0] else None  # the run's last sample
            right = int(kept[CONTEXT - 1]) if kept.shape[0] >= CONTEXT else None
            if (right if right is not None else end) >= s + MAX_HOLD:
                self.abandoned[c] = True
                continue
            if not final and (right is None or end < right + 1 + NEIGHBOURS):
                break  # wait for the samples after it
            hi = right + 1 if right is not None else end
            lo = self._left(c, s)
            a0, a1 = max(0, lo - NEIGHBOURS - 1), min(end, hi + NEIGHBOURS)
            stop = e + 1 if e is not None else end
            runs.append((s, stop, lo, hi, a0, a1, self.n if final and a1 == end else None))
            self.next[c] = stop
        if not runs:
            return
        x, v, m = self.x, self.raw[:, c], self.m[:, c]
        blocks = [run_pairs(m[a0 - b:a1 - b], lo - a0, hi - a0, a0, ns)
                  for _, _, lo, hi, a0, a1, ns in runs]
        fit = sorted({p for ps in blocks for p in ps if p[0] >= 0 and p[1] >= 0})
        mids = {}
        if fit:
            t_mid, v_mid = middle_points(x, v, m, [(le - b, rs - b) for le, rs in fit], 0)
            mids = {p: (t, y) for p, t, y in zip(fit, t_mid.tolist(), v_mid.tolist())}
        for (s, stop, lo, hi, _, _, ns), ps in zip(runs, blocks):
            got = [mids[p] for p in ps if p in mids]
            edge = [np.arange(0, rs) for le, rs in ps if le == -1]
            edge += [np.arange(le + 1, ns) for le, rs in ps if rs == -1 and ns is not None]
            e_idx = np.concatenate(edge) if edge else np.zeros(0, np.int64)
            e_idx = e_idx[(e_idx >= lo) & (e_idx < hi)] - lo
            new = spline_fill(x[lo - b:hi - b], v[lo - b:hi - b], m[lo - b:hi - b],
                              np.array([g[0] for g in got], np.float64),
                              np.array([g[1] for g in got], np.float64), np.unique(e_idx))
            self.val[s - b:stop - b, c] = new[s - lo:stop - lo]

    def _advance(self, final: bool):
        end = self.n
        for c in range(3):
            self._axis(c, end, final)
        upto = min(self.next)
        out = slice(self.done - self.base, upto - self.base)
        flags = np.stack([(np.abs(self.m[out]) >= CONFIDENT).any(axis=1),
                          self.asis[out].any(axis=1)], axis=1)
        res = (self.x[out].copy(), self.val[out].copy(), flags)
        self.done = upto
        keep_from = min([self.done] + [self._left(c, min(self.next[c], end)) - NEIGHBOURS - 1
                                       for c in range(3)])
        drop = keep_from - self.base
        if drop > 0:
            self.x, self.raw, self.val = self.x[drop:], self.raw[drop:], self.val[drop:]
            self.m, self.asis = self.m[drop:], self.asis[drop:]
            self.base += drop
        return res
