"""Clock-model fits of per-block lags: the Brønd iterative-exclusion regression and a robust
method (trimmed least squares, confidence intervals, step detection with a piecewise model,
optional crystal-temperature term chosen by ΔBIC and held-out blocks).

Pure functions on small arrays (one row per 1 h block). The model, in grid samples, is

    lag(t) = b0 + b1 * t + sum_j s_j * [t >= tau_j] + g * X(t)

with t seconds since the reference's first sample on the reference clock, and X(t) the integral
of ``(T_other - T0)^2 - (T_ref - T0)^2`` (°C²·s): a tuning-fork crystal's rate error is parabolic in
temperature around its turnover T0, so two devices at different temperatures drift apart by that
integral times the parabola coefficient.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Optional, Sequence

import numpy as np
from scipy.special import stdtrit  # Student t quantile (scipy.stats.t.ppf's numbers, without
#                                   importing scipy.stats, ~0.5 s of CPU per run)

from stillpoint.drivers.constants import (RTC_CRYSTAL_PARABOLA_PPM_PER_C2,
                                         RTC_CRYSTAL_PARABOLA_SD_PPM_PER_C2,
                                         RTC_CRYSTAL_TURNOVER_C)

from .lags import BlockLag
from .signal import MIN_BLOCKS

DAY_S = 86400.0
TRIM_K = 4.0  # robust fit: points beyond 4 robust SDs are excluded
MIN_SCALE = 0.02  # samples: floor of the robust residual scale (sub-sample lags are not exact)
STEP_MIN_SIDE = 2  # valid blocks needed on each side of a step
STEP_DBIC = 10.0  # a step must lower BIC by at least this ("very strong" evidence)
STEP_MIN_SAMPLES = 0.5  # and be at least half a grid sample (and 4 robust SDs)
MAX_STEPS = 3
TEMP_DBIC = 6.0  # the temperature term must lower BIC by this ("strong") ...
HELDOUT_FOLDS = 5  # ... and lower the held-out RMSE over contiguous folds of blocks


class CannotAlign(Exception):
    """Not enough information to align; ``reason`` says why (the CLI prints it)."""

    def __init__(self, reason: str):
        super().__init__(reason)
        self.reason = reason


@dataclass
class Step:
    """A step in the lag (a sampling halt or a restart of one device's clock)."""

    time_s: float  # best estimate, s since the reference's first sample
    window_s: tuple[float, float]  # the step lies in this interval
    size: float  # grid samples (positive: the other device's clock jumped ahead)
    after_block: int  # index of the last block before the step
    before_block: int  # index of the first block after the step

    def as_dict(self, rate: float, t0_ns: int) -> dict:
        return {"time_s": round(self.time_s, 3),
                "time_ns": int(t0_ns + round(self.time_s * 1e9)),
                "window_s": [round(self.window_s[0], 3), round(self.window_s[1], 3)],
                "size_samples": round(self.size, 4), "size_s": round(self.size / rate, 6),
                "after_block": self.after_block, "before_block": self.before_block}


@dataclass
class TemperatureRegressor:
    """X(t) table: cumulative integral of the devices' parabolic crystal-error difference."""

    time_s: np.ndarray
    x: np.ndarray  # °C²·s

    def __call__(self, t) -> np.ndarray:
        t = np.asarray(t, dtype=np.float64)
        out = np.interp(t, self.time_s, self.x)
        if self.time_s.size >= 2:  # linear extrapolation at the recording's mean rate
            span = self.time_s[-1] - self.time_s[0]
            rate = (self.x[-1] - self.x[0]) / span if span > 0 else 0.0
            out = np.where(t > self.time_s[-1], self.x[-1] + rate * (t - self.time_s[-1]), out)
            out = np.where(t < self.time_s[0], self.x[0] + rate * (t - self.time_s[0]), out)
        return out

    @staticmethod
    def from_temperatures(time_s: np.ndarray, t_ref: np.ndarray, t_other: np.ndarray,
                          turnover_c: float = RTC_CRYSTAL_TURNOVER_C
                          ) -> Optional["TemperatureRegressor"]:
        ok = np.isfinite(t_ref) & np.isfinite(t_other)
        if ok.sum() < 2:
            return None
        time_s, t_ref, t_other = time_s[ok], t_ref[ok], t_other[ok]
        h = (t_other - turnover_c) ** 2 - (t_ref - turnover_c) ** 2
        dt = np.diff(time_s)
        x = np.concatenate([[0.0], np.cumsum(0.5 * (h[1:] + h[:-1]) * dt)])
        return TemperatureRegressor(time_s.astype(np.float64), x)


@dataclass
class ClockFit:
    """A fitted clock model plus its diagnostics (all lags in grid samples)."""

    method: str  # "brond" or "robust"
    model: str  # "linear", "piecewise", "linear+temperature", "piecewise+temperature"
    rate: float
    b0: float
    b1: float
    steps: list[Step] = field(default_factory=list)
    temp_coef: float = 0.0
    temperature: Optional[TemperatureRegressor] = None
    included: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))  # over valid blocks
    block_index: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    t: np.ndarray = field(default_factory=lambda: np.zeros(0))
    y: np.ndarray = field(default_factory=lambda: np.zeros(0))
    rmse: float = np.nan  # of included residuals
    iterations: int = 0
    thresholds: list[float] = field(default_factory=list)
    cov: Optional[np.ndarray] = None  # covariance of (b0, b1, steps, temperature), samples, s
    dof: int = 0
    # the same coefficients' covariance from a jackknife over time folds, and its degrees of
    # freedom (robust fit): each interval uses whichever of the two is the wider for its quantity
    cov_folds: Optional[np.ndarray] = None
    dof_folds: int = 0
    diagnostics: dict = field(default_factory=dict)

    # ------------------------------------------------------------ evaluation
    def lag(self, t) -> np.ndarray:
        """Model lag (grid samples) at reference-clock times t (s since t0)."""
        t = np.asarray(t, dtype=np.float64)
        y = self.b0 + self.b1 * t
        for s in self.steps:
            y = y + s.size * (t >= s.time_s)
        if self.temperature is not None and self.temp_coef:
            y = y + self.temp_coef * self.temperature(t)
        return y

    def offset_s(self, t) -> np.ndarray:
        """Other-device clock minus reference clock (s) at reference times t (s since t0)."""
        return self.lag(t) / self.rate

    @property
    def initial_offset_s(self) -> float:
        return float(self.offset_s(0.0))

    @property
    def drift_s_per_day(self) -> float:
        """Crystal drift rate (linear part), s per day."""
        return self.b1 / self.rate * DAY_S

    @property
    def drift_day7_s(self) -> float:
        """Accumulated change of the offset after 7 days (steps and temperature term included)."""
        return float(self.offset_s(7 * DAY_S) - self.offset_s(0.0))

    def gradient(self, t: float) -> np.ndarray:
        """d lag(t) / d coefficients minus the same at t = 0 (the offset's change by t), over the
        coefficients of ``cov``; at t = 0 the initial offset's own gradient (1, 0, ...)."""
        p = self.cov.shape[0] if self.cov is not None else 2
        g = np.zeros(p)
        if t == 0.0:
            g[0] = 1.0
            return g
        g[1] = t
        k = 2
        for st in self.steps:
            if k < p:
                g[k] = float(t >= st.time_s) - float(0.0 >= st.time_s)
            k += 1
        if self.temperature is not None and self.temp_coef and k < p:
            g[k] = float(self.temperature(t) - self.temperature(0.0))
        return g

    def halfwidth(self, grad: np.ndarray, level: float = 0.95) -> float:
        """Half-width (grid samples) of the ``level`` interval of ``grad @ coefficients``.

        Two variances: the weighted least-squares one, which treats the blocks' lag errors as
        independent, and a jackknife over day-long time folds, which counts errors that persist
        for hours (a stretch of one kind of movement, the crystal's response to a day's
        temperature) once per fold. The wider is used, with its own degrees of freedom (blocks,
        or folds - 1) for the Student t quantile."""
        if self.cov is None or self.dof <= 0:
            return float("nan")
        var, dof = float(grad @ self.cov @ grad), self.dof
        if self.cov_folds is not None and self.dof_folds > 0:
            vf = float(grad @ self.cov_folds @ grad)
            if vf > var:
                var, dof = vf, self.dof_folds
        return float(stdtrit(dof, 0.5 + level / 2)) * math.sqrt(max(var, 0.0))

    def ci(self, level: float = 0.95) -> dict:
        if self.cov is None or self.dof <= 0:
            return {}
        h0 = self.halfwidth(self.gradient(0.0), level) / self.rate
        g1 = np.zeros(self.cov.shape[0])
        g1[1] = 1.0
        h1 = self.halfwidth(g1, level) / self.rate * DAY_S
        # day 7 is a combination of every coefficient (the line, the steps before day 7 and the
        # temperature term, which is correlated with the line's slope)
        h7 = self.halfwidth(self.gradient(7 * DAY_S), level) / self.rate
        o, d, d7 = self.initial_offset_s, self.drift_s_per_day, self.drift_day7_s
        return {"level": level,
                "initial_offset_s": [o - h0, o + h0],
                "drift_s_per_day": [d - h1, d + h1],
                "drift_day7_s": [d7 - h7, d7 + h7]}


# ---------------------------------------------------------------- design matrix and fits
def _design(t: np.ndarray, steps: Sequence[float], xtemp: Optional[np.ndarray],
            bias: Optional[np.ndarray] = None) -> np.ndarray:
    """Columns: 1, t, one indicator per step, then the weak-peak bias covariate (noise-to-signal
    ratio of each block's peak) and the temperature integral X(t) when given (X last: its prior
    applies to the last coefficient)."""
    cols = [np.ones_like(t), t]
    cols += [(t >= tau).astype(np.float64) for tau in steps]
    if bias is not None:
        cols.append(bias)
    if xtemp is not None:
        cols.append(xtemp)
    return np.column_stack(cols)


def _lstsq(A: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Least squares with column scaling (t is ~1e5 s, X ~1e8 °C²·s)."""
    scale = np.sqrt((A * A).sum(axis=0))
    scale[scale == 0] = 1.0
    coef, *_ = np.linalg.lstsq(A / scale, y, rcond=None)
    return coef / scale


def _robust_scale(r: np.ndarray) -> float:
    if r.size == 0:
        return MIN_SCALE
    return max(1.4826 * float(np.median(np.abs(r - np.median(r)))), MIN_SCALE)


def _difference_scale(t: np.ndarray, y: np.ndarray) -> float:
    """Robust SD of the lag noise from successive differences (model-free)."""
    if t.size < 3:
        return MIN_SCALE
    o = np.argsort(t)
    dt, dy = np.diff(t[o]), np.diff(y[o])
    ok = dt > 0
    if ok.sum() < 2:
        return MIN_SCALE
    m = float(np.median(dy[ok] / dt[ok]))
    rd = dy[ok] - m * dt[ok]
    return max(1.4826 * float(np.median(np.abs(rd - np.median(rd)))) / math.sqrt(2), MIN_SCALE)


def _weighted_difference_scale(t: np.ndarray, y: np.ndarray, sq: np.ndarray) -> float:
    """``_difference_scale`` of the standardised lags: successive differences around the median
    slope, each scaled by the combined weight of its two blocks."""
    if t.size < 3:
        return MIN_SCALE
    o = np.argsort(t)
    dt, dy = np.diff(t[o]), np.diff(y[o])
    s = sq[o]
    ok = dt > 0
    if ok.sum() < 2:
        return MIN_SCALE
    m = float(np.median(dy[ok] / dt[ok]))
    pair = 1.0 / np.sqrt(1.0 / s[1:] ** 2 + 1.0 / s[:-1] ** 2)  # 1/SD of a difference
    rd = (dy[ok] - m * dt[ok]) * pair[ok]
    return max(1.4826 * float(np.median(np.abs(rd - np.median(rd)))), MIN_SCALE)


def trimmed_fit(A: np.ndarray, y: np.ndarray, k: float = TRIM_K, iters: int = 30,
                weights: Optional[np.ndarray] = None
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(Weighted) least squares that repeatedly excludes points whose standardised residual
    ``r * sqrt(w)`` lies beyond k robust SDs.

    Starts from a least-absolute-deviation-like fit (iteratively reweighted) so that gross
    outliers cannot drag the first pass. Returns (coef, included mask, residuals)."""
    n, p = A.shape
    sq = np.ones(n) if weights is None else np.sqrt(weights)
    Aw, yw = A * sq[:, None], y * sq
    coef = _lstsq(Aw, yw)
    for _ in range(30):  # IRLS towards L1 for a robust start
        r = (y - A @ coef) * sq
        w = 1.0 / np.maximum(np.abs(r), MIN_SCALE)
        sw = np.sqrt(w)
        coef = _lstsq(Aw * sw[:, None], yw * sw)
    inc = np.ones(n, bool)
    for _ in range(iters):
        r = (y - A @ coef) * sq
        new = np.abs(r) <= k * _robust_scale(r[inc] if inc.sum() > p else r)
        if new.sum() <= p:
            break
        if np.array_equal(new, inc):
            break
        inc = new
        coef = _lstsq(Aw[inc], yw[inc])
    coef = _lstsq(Aw[inc], yw[inc])  # least squares on the final inliers (not the L1 start)
    r = y - A @ coef
    return coef, inc, r


def brond_fit(t: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, list[float]]:
    """Brønd 2021: OLS of lag on time; exclude |standardised residual| > 1, refit, then raise the
    threshold to e, e^e, ... until an iteration excludes nothing. Returns (coef, included,
    thresholds used)."""
    A = _design(t, (), None)
    inc = np.ones(t.size, bool)
    thr = 1.0
    used = []
    while True:
        coef = _lstsq(A[inc], y[inc])
        r = y - A @ coef
        sd = float(np.std(r[inc], ddof=1)) if inc.sum() > 2 else 0.0
        used.append(thr)
        if sd <= 0:
            break
        drop = inc & (np.abs(r / sd) > thr)
        if not drop.any() or inc.sum() - drop.sum() < 2:
            break
        inc &= ~drop
        thr = math.exp(thr)
    coef = _lstsq(A[inc], y[inc])
    return coef, inc, used


def _truncated_loss(r: np.ndarray, cap: float) -> float:
    return float(np.minimum(r * r, cap * cap).sum())


def _bic(loss: float, n: int, p: int) -> float:
    return n * math.log(max(loss, 1e-300) / n) + p * math.log(n)


def _covariance(A: np.ndarray, r: np.ndarray, weights: Optional[np.ndarray] = None,
                prior=None) -> tuple[Optional[np.ndarray], int]:
    """Covariance of the (weighted, with ``prior`` penalised: see ``_prior_lstsq``) least-squares
    coefficients from the residual scatter, and its degrees of freedom."""
    n, p = A.shape
    dof = n - p + (1 if prior is not None else 0)
    if dof <= 0:
        return None, 0
    w = np.ones(n) if weights is None else weights
    s2 = float((w * r) @ r) / dof
    M = A.T @ (A * w[:, None])
    if prior is not None:
        M[-1, -1] += s2 / prior[1] ** 2
    try:
        cov = s2 * np.linalg.inv(M)
    except np.linalg.LinAlgError:
        return None, 0
    return cov, dof


def _prior_lstsq(A: np.ndarray, y: np.ndarray, w: np.ndarray, prior) -> np.ndarray:
    """Weighted least squares whose last coefficient (the temperature term) has a Gaussian prior
    ``(mean, sd, residual variance)``: one pseudo-observation ``coef[-1] = mean`` with the
    weight ``residual variance / sd^2`` (ridge towards the mean; the posterior mean)."""
    sq = np.sqrt(w)
    if prior is None:
        return _lstsq(A * sq[:, None], y * sq)
    mean, sd, s2 = prior
    row = np.zeros((1, A.shape[1]))
    k = math.sqrt(s2) / sd
    row[0, -1] = k
    return _lstsq(np.vstack([A * sq[:, None], row]), np.concatenate([y * sq, [k * mean]]))


def heldout_rmse(t: np.ndarray, y: np.ndarray, steps: Sequence[float],
                 xtemp: Optional[np.ndarray], folds: int = HELDOUT_FOLDS) -> float:
    """RMSE of lags predicted for contiguous held-out groups of blocks (time-ordered folds)."""
    n = t.size
    order = np.argsort(t)
    groups = np.array_split(order, min(folds, n))
    errs = []
    for g in groups:
        train = np.ones(n, bool)
        train[g] = False
        A = _design(t, steps, xtemp)
        keep = np.abs(A[train]).sum(axis=0) > 0  # a step with no training point on one side
        if train.sum() <= keep.sum():
            continue
        coef = _lstsq(A[train][:, keep], y[train])
        errs.append(y[g] - A[g][:, keep] @ coef)
    if not errs:
        return np.nan
    e = np.concatenate(errs)
    return float(np.sqrt(np.mean(e * e)))


# ---------------------------------------------------------------- the two methods
def _valid_arrays(blocks: Sequence[BlockLag], block_time: str, min_corr: float = -1.0):
    v = [b for b in blocks if b.valid and np.isfinite(b.lag) and b.corr >= min_corr]
    idx = np.array([b.index for b in v], dtype=np.int64)
    if block_time == "start":
        t = np.array([b.start_s for b in v], dtype=np.float64)
    elif block_time == "centroid":
        t = np.array([b.centroid_s if np.isfinite(b.centroid_s) else b.centre_s for b in v],
                     dtype=np.float64)
    else:
        t = np.array([b.centre_s for b in v], dtype=np.float64)
    y = np.array([b.lag for b in v], dtype=np.float64)
    return v, idx, t, y


def _count_reasons(blocks: Sequence[BlockLag], min_corr: float = -1.0) -> dict:
    out: dict[str, int] = {}
    for b in blocks:
        if not b.valid:
            out[b.reason or "invalid"] = out.get(b.reason or "invalid", 0) + 1
        elif b.corr < min_corr:
            out["low_corr"] = out.get("low_corr", 0) + 1
    return out


def _check_enough(blocks: Sequence[BlockLag], n_valid: int, min_blocks: int,
                  min_corr: float = -1.0) -> None:
    if n_valid >= min_blocks:
        return
    reasons = _count_reasons(blocks, min_corr)
    detail = ", ".join(f"{v} {k}" for k, v in sorted(reasons.items()))
    size = f" {blocks[0].duration_s / 60:g} min" if blocks else ""  # no block: no length to name
    raise CannotAlign(
        f"too few blocks: {n_valid} usable{size} block(s) where at least {min_blocks} "
        f"are needed ({len(blocks)} block(s) in the overlap"
        + (f"; not usable: {detail}" if detail else "") + "); the recordings overlap too little "
        "or were worn while sedentary, so the second recording is left unaligned")


def fit_brond(blocks: Sequence[BlockLag], rate: float, block_time: str = "centre",
              min_blocks: int = MIN_BLOCKS) -> ClockFit:
    """The paper's regression with iterative exclusion (lags at integer or sub-sample precision,
    as the LagEstimator produced them)."""
    v, idx, t, y = _valid_arrays(blocks, block_time)
    _check_enough(blocks, len(v), min_blocks)
    coef, inc, used = brond_fit(t, y)
    A = _design(t, (), None)
    r = y - A @ coef
    cov, dof = _covariance(A[inc], r[inc])
    return ClockFit(method="brond", model="linear", rate=rate, b0=float(coef[0]),
                    b1=float(coef[1]), included=inc, block_index=idx, t=t, y=y,
                    rmse=float(np.sqrt(np.mean(r[inc] ** 2))), iterations=len(used),
                    thresholds=used, cov=cov, dof=dof,
                    diagnostics={"block_time": block_time, "n_valid": int(len(v)),
                                 "n_included": int(inc.sum()), "invalid": _count_reasons(blocks)})


def _fit_model(t, y, steps, xtemp, cap, weights=None):
    A = _design(t, steps, xtemp)
    coef, inc, r = trimmed_fit(A, y, weights=weights)
    loss = _truncated_loss(r if weights is None else r * np.sqrt(weights), cap)
    return coef, inc, r, _bic(loss, t.size, A.shape[1])


def _locate_step(blocks_by_index: dict, v: Sequence[BlockLag], j: int, pre, post,
                 lo: float, hi: float) -> tuple[float, tuple[float, float]]:
    """Step between valid blocks v[j-1] and v[j]: locate it with the sub-block lags of the blocks
    from v[j-1] to v[j]. ``pre``/``post`` predict the lag before/after the step."""
    cands = []
    for bi in range(v[j - 1].index, v[j].index + 1):
        b = blocks_by_index.get(bi)
        if b is None or b.sub_lags.size == 0:
            continue
        m = b.sub_lags.size
        for i in range(m):
            if not np.isfinite(b.sub_lags[i]):
                continue
            c = b.start_s + (i + 0.5) * b.duration_s / m
            cands.append((c, b.start_s + i * b.duration_s / m, b.start_s + (i + 1) * b.duration_s / m,
                          abs(b.sub_lags[i] - pre(c)) <= abs(b.sub_lags[i] - post(c))))
    if cands:
        cands.sort()
        # a mixed sub-block takes the lag of whichever side holds most of its movement, so the
        # step lies after the start of the last pre-side sub-block and before the end of the
        # first post-side one; the best estimate is the boundary between them
        first_post = next((k for k, c in enumerate(cands) if not c[3]), None)
        if first_post is not None:
            hi = min(hi, cands[first_post][2])
            mid = cands[first_post][1]
            pre_before = [c for c in cands[:first_post] if c[3]]
            if pre_before:
                lo = max(lo, pre_before[-1][1])
                mid = 0.5 * (pre_before[-1][2] + cands[first_post][1])
            return min(max(mid, lo), hi), (lo, hi)
    return 0.5 * (lo + hi), (lo, hi)


STEP_SHORTLIST = 8  # step positions fully evaluated per round (ranked by a mean-shift scan)


def _step_shortlist(t, y, best, cand_pos) -> list:
    """Positions worth a full fit: the largest shifts of the current model's residual ranks
    (a rank-sum scan over all positions at once, with cumulative sums)."""
    if len(cand_pos) <= STEP_SHORTLIST:
        return list(cand_pos)
    j = np.asarray(cand_pos)
    # (a) residuals of the current model, (b) lags detrended by the median successive slope
    # (robust when the current model is pulled by an unmodelled step)
    o = np.argsort(t)
    dt, dy = np.diff(t[o]), np.diff(y[o])
    m = float(np.median(dy[dt > 0] / dt[dt > 0])) if np.any(dt > 0) else 0.0
    out: list[int] = []
    for series in (best[2], y - m * t):
        r = np.argsort(np.argsort(series)).astype(np.float64)  # ranks: outliers cannot dominate
        n = r.size
        cs = np.concatenate([[0.0], np.cumsum(r)])
        n1, n2 = j, n - j
        score = n1 * n2 / n * ((cs[n] - cs[j]) / n2 - cs[j] / n1) ** 2
        for x in j[np.argsort(score)[::-1][:STEP_SHORTLIST // 2]]:
            if int(x) not in out:
                out.append(int(x))
    return out


def _model_search(t, y, xtemp, min_blocks, detect_steps, max_steps, weights=None) -> dict:
    """Greedy step search (ΔBIC) then the temperature term (ΔBIC and held-out blocks)."""
    n = t.size
    # noise scale shared by every candidate model (truncated loss makes their BICs comparable),
    # from successive differences around the median slope: a step or outliers barely move it
    sq = np.ones(n) if weights is None else np.sqrt(weights)
    cap = TRIM_K * _difference_scale(t, y * sq) if weights is None else \
        TRIM_K * _weighted_difference_scale(t, y, sq)
    best = _fit_model(t, y, (), None, cap, weights)
    bic_linear = best[3]
    steps: list[float] = []
    step_pos: list[int] = []
    cand_pos = list(range(STEP_MIN_SIDE, n - STEP_MIN_SIDE + 1)) if detect_steps else []
    diag_steps = []
    while detect_steps and len(steps) < max_steps:
        trial = None
        for j in _step_shortlist(t, y, best, cand_pos):
            bounds = [0] + sorted(step_pos + [j]) + [n]
            if j in step_pos or min(np.diff(bounds)) < STEP_MIN_SIDE:
                continue  # every stretch between steps keeps at least STEP_MIN_SIDE blocks
            tau = 0.5 * (t[j - 1] + t[j])
            st = sorted(steps + [tau])
            res = _fit_model(t, y, st, None, cap, weights)
            if trial is None or res[3] < trial[1][3]:
                trial = (j, res, st, tau)
        if trial is None:
            break
        j, res, st, tau = trial
        size = float(res[0][2 + st.index(tau)])
        scale = _robust_scale(res[2][res[1]])
        dbic = res[3] - best[3]
        diag_steps.append({"position": int(j), "dbic": round(dbic, 3), "size": round(size, 4)})
        if dbic < -STEP_DBIC and abs(size) >= max(STEP_MIN_SAMPLES, TRIM_K * scale):
            steps, step_pos, best = st, sorted(step_pos + [j]), res
            # the new step's neighbours can no longer host a step
        else:
            break
    # temperature term
    temp_diag = {}
    use_temp = False
    if xtemp is not None and np.ptp(xtemp) > 0 and n >= min_blocks + 2:
        with_t = _fit_model(t, y, steps, xtemp, cap, weights)
        inc_b = best[1]
        h_lin = heldout_rmse(t[inc_b], y[inc_b], steps, None)
        inc_t = with_t[1]
        h_tmp = heldout_rmse(t[inc_t], y[inc_t], steps, xtemp[inc_t])
        dbic = with_t[3] - best[3]
        use_temp = bool(dbic < -TEMP_DBIC and np.isfinite(h_tmp) and h_tmp < h_lin)
        temp_diag = {"dbic": round(dbic, 3), "heldout_rmse_without": h_lin,
                     "heldout_rmse_with": h_tmp, "chosen": use_temp}
        if use_temp:
            best = with_t
    return {"best": best, "steps": steps, "step_pos": step_pos, "use_temp": use_temp,
            "temp_diag": temp_diag, "bic_linear": bic_linear, "diag_steps": diag_steps,
            "cap": cap}


ROBUST_MIN_CORR = 0.4  # robust: weaker correlation peaks are not lags (ActiPASS uses 0.4 too)
CONSENSUS_TOL = 4.0  # samples: a candidate peak within this of the consensus line agrees
CONSENSUS_HYPOTHESES = 3000
MAX_SLOPE_PPM = 500.0  # lines steeper than this relative skew are not considered


def _candidates(v: Sequence[BlockLag], y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(n, K) candidate lags and heights per block (the chosen lag first), NaN-padded."""
    k = max([1] + [b.cand_lags.size + 1 for b in v])
    C = np.full((len(v), k), np.nan)
    H = np.full((len(v), k), np.nan)
    for i, b in enumerate(v):
        C[i, 0], H[i, 0] = y[i], b.corr
        m = b.cand_lags.size
        if m:
            keep = np.abs(b.cand_lags - y[i]) > 1e-9
            cl, ch = b.cand_lags[keep], b.cand_corr[keep]
            C[i, 1:1 + cl.size], H[i, 1:1 + cl.size] = cl, ch
    return C, H


def _nearest_candidate(C: np.ndarray, pred: np.ndarray, y: np.ndarray,
                       tol: float = CONSENSUS_TOL) -> np.ndarray:
    d = np.abs(C - pred[:, None])
    d = np.where(np.isfinite(d), d, np.inf)
    j = np.argmin(d, axis=1)
    best = C[np.arange(C.shape[0]), j]
    ok = d[np.arange(C.shape[0]), j] <= tol
    return np.where(ok, best, y)


def consensus_select(t: np.ndarray, C: np.ndarray, H: np.ndarray, y: np.ndarray,
                     rate_hint: float = 30.0, seed: int = 0) -> tuple[np.ndarray, int]:
    """Choose one correlation peak per block so that as many blocks as possible agree on one
    line (RANSAC over candidate peaks, deterministic). Blocks with no candidate near the line
    keep their highest peak (steps are found afterwards). Returns (lags, blocks switched)."""
    n, k = C.shape
    if n < 3 or k < 2:
        return y, 0
    rng = np.random.default_rng(seed)
    h = CONSENSUS_HYPOTHESES
    i = rng.integers(0, n, h)
    j = rng.integers(0, n, h)
    a = rng.integers(0, min(k, 3), h)
    b = rng.integers(0, min(k, 3), h)
    ok = (i != j) & np.isfinite(C[i, a]) & np.isfinite(C[j, b]) & (np.abs(t[i] - t[j]) > 0)
    i, j, a, b = i[ok], j[ok], a[ok], b[ok]
    # always include the plain highest-peak hypotheses as well
    slope = (C[j, b] - C[i, a]) / (t[j] - t[i])
    icpt = C[i, a] - slope * t[i]
    keep = np.abs(slope) <= MAX_SLOPE_PPM * 1e-6 * rate_hint
    slope, icpt = slope[keep], icpt[keep]
    if slope.size == 0:
        return y, 0
    Cf = np.where(np.isfinite(C), C, np.inf)
    Hf = np.where(np.isfinite(H), np.maximum(H, 0.0), 0.0)
    best_score, best_line = -1.0, None
    for s0 in range(0, slope.size, 256):
        pred = icpt[s0:s0 + 256, None] + slope[s0:s0 + 256, None] * t[None, :]
        near = np.abs(Cf[None, :, :] - pred[:, :, None]) <= CONSENSUS_TOL
        # score: summed correlation of the peaks on the line. Lines one gait step off the truth
        # collect as many blocks, but the true lag's peaks are higher on average.
        score = np.max(np.where(near, Hf[None, :, :], 0.0), axis=2).sum(axis=1)
        m = int(np.argmax(score))
        if score[m] > best_score:
            best_score, best_line = float(score[m]), (icpt[s0 + m], slope[s0 + m])
    pred = best_line[0] + best_line[1] * t
    out = _nearest_candidate(C, pred, y)
    return out, int(np.sum(out != y))


JACKKNIFE_FOLD_S = DAY_S  # one fold per day of blocks ...
JACKKNIFE_FOLDS = (5, 10)  # ... but at least 5 and at most 10 folds


def _jackknife_cov(A: np.ndarray, y: np.ndarray, w: np.ndarray, t: np.ndarray, prior=None
                   ) -> Optional[tuple[np.ndarray, int]]:
    """(covariance of the coefficients, degrees of freedom) from a delete-one-group jackknife
    over contiguous time folds of the included blocks (Efron & Tibshirani 1993, ch. 11; groups
    of neighbouring blocks, so errors that persist for hours, such as the crystal's response to
    a day's temperature, or a stretch of one kind of movement, are counted once per fold and not
    as independent blocks). The interval from the blocks' scatter alone assumes independent lag
    errors and covered the truth in too few simulated weeks. None when fewer than 5 folds fit."""
    n, p = A.shape
    span = float(t.max() - t.min()) if n else 0.0
    k = int(np.clip(round(span / JACKKNIFE_FOLD_S), *JACKKNIFE_FOLDS))
    order = np.argsort(t)
    if n < k * 2 or n - n // k <= p:
        return None
    thetas = []
    for g in np.array_split(order, k):
        keep = np.ones(n, bool)
        keep[g] = False
        Ak = A[keep]
        if np.linalg.matrix_rank(Ak[:, :-1] if prior is not None else Ak) < p - (prior is not None):
            continue  # a step with no block left on one side
        thetas.append(_prior_lstsq(Ak, y[keep], w[keep], prior))
    m = len(thetas)
    if m < JACKKNIFE_FOLDS[0]:
        return None
    th = np.array(thetas)
    d = th - th.mean(axis=0)
    return (m - 1) / m * (d.T @ d), m - 1


PEAK_MAX = 0.95  # a peak height above this counts as 0.95 (no block outweighs ~10 good ones)
PEAK_MIN = 0.1


def lag_weights(C: np.ndarray, H: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Inverse-variance weight of each block's chosen lag from the height rho of its peak:
    rho^2 / (1 - rho^2), the signal-to-noise ratio of the two activity signals, to which the
    variance of a cross-correlation time-delay estimate is inversely proportional (Carter 1987,
    Proc. IEEE 75:236, "Coherence and time delay estimation"). Brønd et al. 2021 give every
    block the same weight, and so did this fit: on realistic wear (wrist and hip, 7 days) the
    weak-peak blocks (rho 0.4-0.6) carry lags biased by -30 to -40 ms with SD 85 ms, the strong
    ones (rho >= 0.9) -1 ms with SD 30 ms, and the equal-weight line started 43 ms off."""
    d = np.abs(np.where(np.isfinite(C), C, np.inf) - y[:, None])
    j = np.argmin(d, axis=1)
    h = H[np.arange(C.shape[0]), j]
    h = np.clip(np.where(np.isfinite(h), h, PEAK_MIN), PEAK_MIN, PEAK_MAX)
    return h * h / (1.0 - h * h)


def fit_robust(blocks: Sequence[BlockLag], rate: float,
               temperature: Optional[TemperatureRegressor] = None,
               min_blocks: int = MIN_BLOCKS, detect_steps: bool = True,
               max_steps: int = MAX_STEPS) -> ClockFit:
    """Trimmed least squares with step detection (greedy, ΔBIC) and an optional temperature term
    (kept only if ΔBIC and the held-out RMSE both favour it). Block times are block centres."""
    v, idx, t, y = _valid_arrays(blocks, "centroid", ROBUST_MIN_CORR)
    _check_enough(blocks, len(v), min_blocks, ROBUST_MIN_CORR)
    n = t.size
    xtemp = temperature(t) if temperature is not None else None
    cands, heights = _candidates(v, y)
    y, n_switched = consensus_select(t, cands, heights, y, rate)
    w = lag_weights(cands, heights, y)
    search = _model_search(t, y, xtemp, min_blocks, detect_steps, max_steps, w)
    for _ in range(2):  # re-choose each block's peak against the fitted model, refit
        coef_, inc_, r_, _ = search["best"]
        pred = y - r_
        y2 = _nearest_candidate(cands, pred, y)
        if np.array_equal(y2, y):
            break
        y = y2
        w = lag_weights(cands, heights, y)
        search = _model_search(t, y, xtemp, min_blocks, detect_steps, max_steps, w)
    best, steps, step_pos = search["best"], search["steps"], search["step_pos"]
    use_temp, temp_diag, bic_linear = search["use_temp"], search["temp_diag"], search["bic_linear"]
    diag_steps, cap = search["diag_steps"], search["cap"]
    coef, inc, r, bic = best
    use_temp = xtemp is not None and bool(np.ptp(xtemp) > 0)
    xfit = xtemp if use_temp else None
    # the final model: the clock (line, steps, temperature) plus the weak peaks' bias, a term
    # in each block's noise-to-signal ratio (1 - rho^2) / rho^2 (the inverse of its weight).
    # On simulated wrist/hip wear the lags of weak peaks are biased, and the bias grows as the
    # peak weakens, one sign for a pair, the other sign in the next (docs/performance.md#code-figures;
    # movement only one site makes can pull a weak peak either way). The sign and size are the pair's own, so no weighting or
    # fixed correction removes it; its coefficient is estimated with the clock, and the clock
    # is the lag at a noise-free peak (ratio 0). Its uncertainty is in the clock's intervals.
    nsr = 1.0 / w
    bias = bool(inc.sum() >= 2 * min_blocks and np.ptp(nsr[inc]) > 0)
    A = _design(t, steps, xfit, nsr if bias else None)
    prior = None
    if use_temp:
        # the crystals' parabola is physics, not a choice: always in the model, its coefficient
        # estimated from the lags with the typical value as a prior (a free term is chosen by
        # ΔBIC only when the data alone show it; a week of wrist/hip lags rarely does, and a
        # line through a curved lag puts the initial offset 12 ms off on a simulated week)
        s2 = (cap / TRIM_K) ** 2  # weighted residual variance (the lags' noise scale)
        prior = (RTC_CRYSTAL_PARABOLA_PPM_PER_C2 * 1e-6 * rate,
                 RTC_CRYSTAL_PARABOLA_SD_PPM_PER_C2 * 1e-6 * rate, s2)
    if bias or prior is not None:
        coef = _prior_lstsq(A[inc], y[inc], w[inc], prior)
        r = y - A @ coef
    if use_temp:
        temp_diag = dict(temp_diag, prior_ppm_per_c2=RTC_CRYSTAL_PARABOLA_PPM_PER_C2,
                         prior_sd_ppm_per_c2=RTC_CRYSTAL_PARABOLA_SD_PPM_PER_C2,
                         estimate_ppm_per_c2=float(coef[-1]) / rate * 1e6)
    cov, dof = _covariance(A[inc], r[inc], w[inc], prior)
    jk = _jackknife_cov(A[inc], y[inc], w[inc], t[inc], prior)
    bias_diag = {}
    if bias:
        # the bias is not part of the clock: the clock's coefficients and their (marginal)
        # covariance without it
        kb = 2 + len(steps)
        bias_diag = {"samples_per_noise_to_signal": float(coef[kb]),
                     "sd": float(math.sqrt(cov[kb, kb])) if cov is not None else None,
                     "at_median_block_samples": float(coef[kb] * np.median(nsr[inc]))}
        keep = np.arange(A.shape[1]) != kb
        coef, A = coef[keep], A[:, keep]
        r = y - A @ coef  # the clock's residuals (the bias left in them)
        cov = cov[np.ix_(keep, keep)] if cov is not None else None
        jk = (jk[0][np.ix_(keep, keep)], jk[1]) if jk is not None else None
    interval = "weighted least squares"
    if jk is not None:
        interval = (f"the wider of weighted least squares and a jackknife over {jk[1] + 1} "
                    "time folds, per quantity")
    # step objects, located with the sub-block lags
    by_index = {b.index: b for b in blocks}
    step_objs = []
    for k, (_tau, j) in enumerate(zip(steps, step_pos)):
        size = float(coef[2 + k])
        others = [(s2, float(coef[2 + kk])) for kk, s2 in enumerate(steps) if kk != k]

        def pre(tc, k=k):
            base = coef[0] + coef[1] * tc + sum(sz * (tc >= s2) for s2, sz in others)
            if use_temp:
                base = base + coef[-1] * temperature(tc)
            return float(base)

        def post(tc, size=size, pre=pre):
            return pre(tc) + size

        tm, win = _locate_step(by_index, v, j, pre, post, float(v[j - 1].start_s),
                               float(v[j].start_s + v[j].duration_s))
        step_objs.append(Step(time_s=tm, window_s=win, size=size, after_block=int(v[j - 1].index),
                              before_block=int(v[j].index)))
    # the fitted steps were placed between block centres; re-express the model with the located
    # times (the lag is only observed at block centres, so the fit is unchanged)
    model = ("piecewise" if steps else "linear") + ("+temperature" if use_temp else "")
    heldout_final = heldout_rmse(t[inc], y[inc], steps, xtemp[inc] if use_temp else None)
    return ClockFit(method="robust", model=model, rate=rate, b0=float(coef[0]), b1=float(coef[1]),
                    steps=step_objs, temp_coef=float(coef[-1]) if use_temp else 0.0,
                    temperature=temperature if use_temp else None, included=inc,
                    block_index=idx, t=t, y=y, rmse=float(np.sqrt(np.mean(r[inc] ** 2))),
                    iterations=1, cov=cov, dof=dof,
                    cov_folds=jk[0] if jk is not None else None,
                    dof_folds=jk[1] if jk is not None else 0,
                    diagnostics={"block_time": "centroid", "n_valid": int(n),
                                 "n_included": int(inc.sum()),
                                 "invalid": _count_reasons(blocks, ROBUST_MIN_CORR),
                                 "bic_linear": round(bic_linear, 3), "bic_final": round(bic, 3),
                                 "step_search": diag_steps, "temperature": temp_diag,
                                 "peaks_switched_by_consensus": int(n_switched),
                                 "heldout_rmse_samples": heldout_final, "interval": interval,
                                 "residual_scale_samples": cap / TRIM_K,
                                 "weak_peak_bias": bias_diag})
