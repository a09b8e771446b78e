"""Standard errors of the fitted calibration coefficients, with adjacent windows not independent.

The ICP fit converges to a stationary point of the weighted sum of squared sphere distances
``sum_i w_i r_i^2`` with ``r_i = ||cal(mean_i)|| - 1`` (at the fixed point each axis' weighted
least-squares step is the identity, i.e. ``sum_i w_i r_i u_ik [1, cal_ik, T_i - T_ref] = 0``).
Its covariance is the sandwich ``H^-1 M H^-1`` with ``H = J' W J`` (Gauss-Newton) and the
"meat" ``M`` summed over **blocks** of windows rather than over windows:

    M = G/(G-1) * sum_blocks s_b s_b',   s_b = sum_{i in b} w_i r_i J_i

(the leverage-adjusted, jackknife form of the block-robust sandwich: a block that carries much of
the information, such as the few cool nonwear hours that span the temperature range, would
otherwise hide its own residual), so residuals that share a cause within a block (the same posture's quantisation bias, a slow bias
wander, one night's temperature) count once, not once per window. A block is a run of nonmovement
windows with no gap longer than ``block_gap_s`` between them (default 10 min) and no change of
posture (a window mean more than ``posture_jump_g``, 50 mg, from the previous one: another
orientation carries another quantisation error). Without the posture split a night is one block
and the information of a coefficient can sit in 2-4 blocks, too few to estimate its variance: on
simulated packed recordings the split raised the coverage of +-2 SE from 88 % to 93 %
(tools/crosschecks/calibration_coverage.py; 20-100 mg thresholds gave the same on the seeds tried). ``G`` (the number of blocks)
is the effective number of independent pieces of evidence and is reported.

``J`` (one row per window, columns per fitted parameter) follows from
``cal_k = (raw_k + offset_k) scale_k + (T - T_ref) tempoffset_k`` and ``dr/dcal = cal / ||cal||``.

The reference temperature T_ref is the mean temperature of the windows; its standard error is the
block-robust standard error of that mean (it is a defined reference, so it does not add to the
other coefficients' errors, which are all stated at T_ref).

:func:`block_bootstrap` refits on blocks drawn with replacement: the check that the sandwich is
honest (tools/crosschecks/calibration_coverage.py compares both against the truth on simulated recordings).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Optional

import numpy as np

BLOCK_GAP_S = 600.0  # windows closer than this belong to one block (see the module docstring)
POSTURE_JUMP_G = 0.05  # a window mean this far from the previous one starts a new block
MIN_BLOCKS = 5  # fewer independent blocks: no standard errors (the block sums cannot estimate them)


@dataclass
class CoefficientUncertainty:
    """One standard error per coefficient (same units as the coefficients); NaN where a
    coefficient was not fitted (e.g. tempoffset without the temperature term)."""

    offset: np.ndarray
    scale: np.ndarray
    tempoffset: np.ndarray
    temperature_ref: float
    blocks: int  # independent blocks the errors were computed over
    windows: int
    covariance: Optional[np.ndarray] = None  # (p, p) over the fitted parameters
    names: list = field(default_factory=list)  # the parameters of ``covariance``, in order

    def to_dict(self) -> dict:
        def lst(a):
            return [None if not np.isfinite(v) else float(v) for v in a]
        t = float(self.temperature_ref)
        return {"offset": lst(self.offset), "scale": lst(self.scale),
                "tempoffset": lst(self.tempoffset),
                "temperature_ref": t if np.isfinite(t) else None}


def window_blocks(start_ns: np.ndarray, block_gap_s: float = BLOCK_GAP_S,
                  mean: Optional[np.ndarray] = None,
                  posture_jump_g: float = POSTURE_JUMP_G) -> np.ndarray:
    """(k,) block label of each window (windows in time order or not): a new block starts where
    the gap to the previous window's start exceeds ``block_gap_s`` or, with ``mean``, where the
    window mean moves by more than ``posture_jump_g`` from the previous window's (a new posture:
    another orientation, another quantisation error)."""
    s = np.asarray(start_ns, np.int64).reshape(-1)
    if s.size == 0:
        return np.zeros(0, np.int64)
    order = np.argsort(s, kind="stable")
    gap = np.diff(s[order]) > int(round(block_gap_s * 1e9))
    if mean is not None and posture_jump_g > 0:
        m = np.asarray(mean, np.float64).reshape(-1, 3)[order]
        gap |= np.sqrt(np.sum(np.diff(m, axis=0) ** 2, axis=1)) > posture_jump_g
    lab_sorted = np.r_[0, np.cumsum(gap)]
    out = np.empty_like(lab_sorted)
    out[order] = lab_sorted
    return out


def _jacobian(mean, temp_centered, offset, scale, tempoffset, fit_offset, fit_scale):
    cal = (mean + offset) * scale
    use_t = temp_centered is not None
    if use_t:
        cal = cal + temp_centered[:, None] * tempoffset
    norm = np.sqrt(np.sum(cal * cal, axis=1))
    u = cal / norm[:, None]
    cols, names = [], []
    for k, ax in enumerate("xyz"):
        if fit_offset:
            cols.append(u[:, k] * scale[k])
            names.append(f"offset_{ax}")
        if fit_scale:
            cols.append(u[:, k] * (mean[:, k] + offset[k]))
            names.append(f"scale_{ax}")
        if use_t:
            cols.append(u[:, k] * temp_centered)
            names.append(f"tempoffset_{ax}")
    return np.column_stack(cols), norm - 1.0, names


def _leave_block_out(H: np.ndarray, Hb: np.ndarray, S: np.ndarray) -> np.ndarray:
    """(g, p) rows (H - H_b)^+ s_b: one batched solve (a tenth of the time of g
    pseudo-inverses), the pseudo-inverse where a leave-one-block-out information matrix is
    singular (a block that alone determines a coefficient)."""
    A = H[None] - Hb
    try:
        x = np.linalg.solve(A, S[:, :, None])[:, :, 0]
        if np.all(np.isfinite(x)):
            return x
    except np.linalg.LinAlgError:
        pass
    return np.einsum("bjk,bk->bj", np.linalg.pinv(A), S)


def coefficient_uncertainty(mean: np.ndarray, temperature: Optional[np.ndarray], offset, scale,
                            tempoffset, temperature_ref: float, start_ns: np.ndarray, *,
                            fit_offset: bool = True, fit_scale: bool = True,
                            max_weight: float = 100.0,
                            block_gap_s: float = BLOCK_GAP_S,
                            posture_jump_g: float = POSTURE_JUMP_G) -> CoefficientUncertainty:
    """Block-robust sandwich standard errors of a converged fit (see the module docstring).

    ``temperature``: the windows' temperatures when the fit has a temperature term, else None.
    """
    mean = np.asarray(mean, np.float64).reshape(-1, 3)
    offset = np.asarray(offset, np.float64)
    scale = np.asarray(scale, np.float64)
    tempoffset = np.asarray(tempoffset, np.float64)
    n = mean.shape[0]
    tc = None if temperature is None else np.asarray(temperature, np.float64) - temperature_ref
    J, r, names = _jacobian(mean, tc, offset, scale, tempoffset, fit_offset, fit_scale)
    with np.errstate(divide="ignore"):
        w = np.minimum(1.0 / np.abs(r), max_weight)
    blocks = window_blocks(start_ns, block_gap_s, mean, posture_jump_g)
    g = int(blocks.max()) + 1 if n else 0
    p = J.shape[1]
    WJ = w[:, None] * J
    H = J.T @ WJ
    # per-block scores S_b and information H_b (for the leverage adjustment below), one
    # column at a time: sums in window order without an (n, p, p) temporary (80 MB for a
    # fortnight's windows); H_b is symmetric, so its upper triangle is summed and mirrored
    S = np.empty((g, p))
    Hb = np.empty((g, p, p))
    for j in range(p):
        S[:, j] = np.bincount(blocks, r * WJ[:, j], minlength=g)
        for i in range(j + 1):
            Hb[:, i, j] = np.bincount(blocks, J[:, i] * WJ[:, j], minlength=g)
            Hb[:, j, i] = Hb[:, i, j]
    cov = np.full((p, p), np.nan)
    if g >= MIN_BLOCKS:
        try:
            Hi = np.linalg.inv(H)
            # leverage-adjusted (jackknife, "CR3") block scores: s_b* = H (H - H_b)^-1 s_b, so
            # a block that pulls the fit towards itself (a few nonwear hours carrying the whole
            # temperature range) is not allowed to hide its own residuals
            adj = _leave_block_out(H, Hb, S) @ H.T
            cov = Hi @ (adj.T @ adj) @ Hi * ((g - 1.0) / g)
        except np.linalg.LinAlgError:
            pass
    se = np.sqrt(np.clip(np.diag(cov), 0, None))
    out = {"offset": np.full(3, np.nan), "scale": np.full(3, np.nan),
           "tempoffset": np.full(3, np.nan)}
    for name, v in zip(names, se):
        kind, ax = name.rsplit("_", 1)
        out[kind]["xyz".index(ax)] = v
    t_se = float("nan")
    if temperature is not None and g >= MIN_BLOCKS:
        Tb = np.zeros(g)
        np.add.at(Tb, blocks, tc)
        t_se = float(np.sqrt(np.sum(Tb ** 2) * g / (g - 1.0)) / n)
    return CoefficientUncertainty(out["offset"], out["scale"], out["tempoffset"], t_se, g, n,
                                  cov, names)


def block_bootstrap(mean: np.ndarray, temperature: Optional[np.ndarray], start_ns: np.ndarray,
                    fit: Callable, *, replicates: int = 200, seed: int = 0,
                    block_gap_s: float = BLOCK_GAP_S,
                    posture_jump_g: float = POSTURE_JUMP_G) -> dict:
    """Bootstrap standard errors: draw the blocks (as :func:`window_blocks` cuts them) with
    replacement, refit, and take the SD of each coefficient over the replicates.

    ``fit(mean, temperature) -> (offset, scale, tempoffset, temperature_ref)``. Coefficients are
    compared at one reference temperature (the full data's mean), so the offsets of the replicates
    are re-referenced (offset + (T - T_ref_b) tempoffset / scale) before taking their SD.
    """
    mean = np.asarray(mean, np.float64).reshape(-1, 3)
    blocks = window_blocks(start_ns, block_gap_s, mean, posture_jump_g)
    g = int(blocks.max()) + 1
    members = [np.nonzero(blocks == b)[0] for b in range(g)]
    rng = np.random.default_rng(seed)
    t_all = None if temperature is None else float(np.mean(temperature))
    rows = []
    for _ in range(replicates):
        pick = rng.integers(0, g, g)
        idx = np.concatenate([members[b] for b in pick])
        o, s, t, tref = fit(mean[idx], None if temperature is None else temperature[idx])
        o, s, t = np.asarray(o), np.asarray(s), np.asarray(t)
        if t_all is not None:
            o = o + (t_all - tref) * t / s
        rows.append(np.concatenate([o, s, t, [tref]]))
    a = np.array(rows)
    sd = a.std(axis=0, ddof=1)
    return {"offset": sd[0:3], "scale": sd[3:6], "tempoffset": sd[6:9],
            "temperature_ref": float(sd[9]), "blocks": g, "replicates": replicates}
