"""Whether a calibration fit can be trusted: its coefficients' standard errors and the warnings a
user acts on.

Checks on a converged fit (limits are module constants and appear in the messages):

* ``temperature_undetermined``: a temperature coefficient's standard error is above
  ``TEMPOFFSET_SE_LIMIT_MG_C`` (0.05 mg/degC, so that +-2 SE stays within 0.1 mg/degC) **and** the
  term cannot be told from zero (joint Wald statistic of the three coefficients, with their
  block-robust covariance, below ``TEMPERATURE_WALD_CRIT``: chi-square with 3 degrees of freedom
  at p = 0.001). The temperature range or the number of independent blocks spanning it is too
  small to separate the term from the offsets; the fit falls back to the model without it (C1),
  as GGIR does when the temperature is unusable.
* ``temperature_imprecise``: a standard error is above the limit but the term is clearly not
  zero (Wald statistic at or above the critical value): it is kept, with the warning. Dropping a
  real term moves its effect into the offsets (on simulated recordings with a 1.6 mg/degC term
  the C1 offsets fell 2.4-2.8 SE from the truth; on GGIR's real 84 h set the error after rose
  from 1.96 to 2.64 mg), which is worse than an imprecise coefficient that says how imprecise
  it is.
* ``offset_uncertain`` / ``scale_uncertain``: an offset SE above ``OFFSET_SE_LIMIT_MG`` (1 mg) or a
  scale SE above ``SCALE_SE_LIMIT_PCT`` (0.1 %).
* ``quantisation``: the stored values' step (e.g. AX3 packed +-8 g: 15.6 mg) is not dithered by
  the within-window variation, so a still window's mean can be biased by more than
  ``QUANTISATION_BIAS_LIMIT_MG`` (0.5 mg) depending on its orientation (first harmonic of the
  rounding sawtooth under Gaussian variation: (step / pi) exp(-2 pi^2 (sd / step)^2), with the
  median still-window SD).
* ``few_faces``: fewer than ``MIN_FACES`` of the six faces of the sphere (+-x, +-y, +-z, by the
  dominant axis of the window mean) hold ``FACE_MIN_SHARE`` (1 %) of the windows: the sphere
  criterion passed, but the offsets and scales rest on a few orientations.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

TEMPOFFSET_SE_LIMIT_MG_C = 0.05
TEMPERATURE_WALD_CRIT = 16.266  # chi-square, 3 degrees of freedom, upper 0.001 quantile
OFFSET_SE_LIMIT_MG = 1.0
SCALE_SE_LIMIT_PCT = 0.1
QUANTISATION_BIAS_LIMIT_MG = 0.5
FACE_MIN_SHARE = 0.01
MIN_FACES = 5
FACES = ("+x", "-x", "+y", "-y", "+z", "-z")


@dataclass
class FitWarning:
    code: str
    message: str

    def to_dict(self) -> dict:
        return {"code": self.code, "message": self.message}


def _axes(v, limit, fmt) -> str:
    return ", ".join(f"{ax} {fmt(x)}" for ax, x in zip("xyz", v) if np.isfinite(x) and x > limit)


def temperature_wald(tempoffset_g_c: np.ndarray, covariance: Optional[np.ndarray],
                     names: list) -> float:
    """Joint Wald statistic t' V^-1 t of the temperature coefficients (NaN when not computable)."""
    idx = [names.index(f"tempoffset_{ax}") for ax in "xyz" if f"tempoffset_{ax}" in names]
    if covariance is None or len(idx) != 3:
        return float("nan")
    v = np.asarray(covariance, np.float64)[np.ix_(idx, idx)]
    t = np.asarray(tempoffset_g_c, np.float64).reshape(3)
    if not (np.all(np.isfinite(v)) and np.all(np.isfinite(t))):
        return float("nan")
    try:
        return float(t @ np.linalg.solve(v, t))
    except np.linalg.LinAlgError:
        return float("nan")


def temperature_warning(tempoffset_g_c: np.ndarray, se_tempoffset_g_c: np.ndarray,
                        temperature: np.ndarray, blocks: int,
                        wald: float = float("nan")) -> Optional[FitWarning]:
    """None when every temperature coefficient's SE is within the limit; else
    ``temperature_imprecise`` (the term is clearly not zero: ``wald`` at or above the critical
    value; it is kept) or ``temperature_undetermined`` (the fallback to C1). The message names the
    axes over the limit, the temperature spread, the largest |coefficient| / SE and the Wald
    statistic."""
    se = np.asarray(se_tempoffset_g_c, np.float64) * 1000.0
    if np.all(np.isfinite(se)) and np.all(se <= TEMPOFFSET_SE_LIMIT_MG_C):
        return None
    t = np.asarray(temperature, np.float64)
    p5, p95 = np.percentile(t, [5, 95])
    worst = _axes(se, TEMPOFFSET_SE_LIMIT_MG_C, lambda x: f"{x:.3f}") or "not computable"
    coef = np.asarray(tempoffset_g_c, np.float64) * 1000.0
    with np.errstate(divide="ignore", invalid="ignore"):
        zs = np.abs(coef) / se
    hint = ""
    if np.any(np.isfinite(zs)):
        k = int(np.nanargmax(zs))
        hint = (f"; largest term {'xyz'[k]} {coef[k]:+.2f} +- {se[k]:.2f} mg/degC "
                f"({zs[k]:.1f} SE from zero)")
    if np.isfinite(wald):
        hint += f"; Wald {wald:.1f} against {TEMPERATURE_WALD_CRIT:g} (p = 0.001)"
    spread = (f"SE {worst} mg/degC > {TEMPOFFSET_SE_LIMIT_MG_C:g}; window temperature p5-p95 "
              f"{p5:.1f}-{p95:.1f} degC over {blocks} independent blocks{hint}")
    if np.isfinite(wald) and wald >= TEMPERATURE_WALD_CRIT:
        return FitWarning("temperature_imprecise", (
            f"temperature term imprecise ({spread}): kept, as it is clearly not zero "
            "(dropping it would move its effect into the offsets)"))
    return FitWarning("temperature_undetermined", (
        f"temperature term not determined ({spread}): fitted without it (C1), as GGIR does "
        "when the temperature is unusable"))


def quantisation_bias_bound_mg(step_mg, sd_mg):
    """Largest bias (mg) rounding to ``step_mg`` leaves in the mean of many samples of a constant
    value under Gaussian variation of SD ``sd_mg`` (see the module docstring)."""
    step = np.asarray(step_mg, np.float64)
    sd = np.asarray(sd_mg, np.float64)
    safe = np.where(step > 0, step, 1.0)
    return np.where(step > 0, step / np.pi * np.exp(-2.0 * np.pi ** 2 * (sd / safe) ** 2), 0.0)


def face_counts(mean: np.ndarray) -> np.ndarray:
    """(6,) windows per face (+x, -x, +y, -y, +z, -z) by the dominant axis of the window mean."""
    mean = np.asarray(mean, np.float64).reshape(-1, 3)
    k = np.argmax(np.abs(mean), axis=1)
    neg = mean[np.arange(mean.shape[0]), k] < 0
    return np.bincount(2 * k + neg, minlength=6)


def assess(uncertainty: Optional[dict], mean: np.ndarray, sd: Optional[np.ndarray], *,
           quantisation_step_g=None, dequantised: bool = False) -> list:
    """Warnings about an applied fit (the temperature fallback is decided by the fit itself)."""
    out: list[FitWarning] = []
    if uncertainty is not None:
        off = np.array([np.nan if v is None else v for v in uncertainty["offset"]]) * 1000.0
        sc = np.array([np.nan if v is None else v for v in uncertainty["scale"]]) * 100.0
        bad = _axes(off, OFFSET_SE_LIMIT_MG, lambda x: f"{x:.2f}")
        if bad:
            out.append(FitWarning("offset_uncertain", f"offset not well determined (SE {bad} mg > "
                                f"{OFFSET_SE_LIMIT_MG:g} mg)"))
        bad = _axes(sc, SCALE_SE_LIMIT_PCT, lambda x: f"{x:.3f}")
        if bad:
            out.append(FitWarning("scale_uncertain", f"scale not well determined (SE {bad} % > "
                                f"{SCALE_SE_LIMIT_PCT:g} %)"))
    if quantisation_step_g is not None and sd is not None and len(sd):
        step = np.broadcast_to(np.asarray(quantisation_step_g, np.float64), (3,)) * 1000.0
        med = np.median(np.asarray(sd, np.float64).reshape(-1, 3), axis=0) * 1000.0
        bound = quantisation_bias_bound_mg(step, med)
        if np.any(bound > QUANTISATION_BIAS_LIMIT_MG):
            out.append(FitWarning("quantisation", (
                f"quantisation dominates the noise: step {step.max():.1f} mg against a median "
                f"still-window SD of {'/'.join(f'{v:.1f}' for v in med)} mg, so window means can "
                f"be biased by up to {bound.max():.1f} mg by orientation ("
                + ("the means were de-biased for it; what remains is in the SEs)" if dequantised
                   else "coefficients and their SEs include it)"))))
    counts = face_counts(mean)
    n = max(int(counts.sum()), 1)
    thin = [f for f, c in zip(FACES, counts) if c < FACE_MIN_SHARE * n]
    if 6 - len(thin) < MIN_FACES:
        out.append(FitWarning("few_faces", (
            f"sphere covered on only {6 - len(thin)} of 6 faces ({', '.join(thin)} under "
            f"{FACE_MIN_SHARE:.0%} of the windows): offsets and scales rest on few orientations")))
    return out


def add_warnings(estimate, warnings: list) -> None:
    """Record warnings on an estimate: its diagnostics' ``warnings`` (code, message) and
    ``flags`` (codes), and the one-line reason ("; warning: ...")."""
    diag = estimate.diagnostics
    diag.warnings = list(diag.warnings or ())
    diag.flags = list(diag.flags or ())
    for w in warnings:
        diag.warnings.append(w.to_dict())
        diag.flags.append(w.code)
        estimate.reason += f"; warning: {w.message}"
    estimate.diagnostics = diag


STEP_ROWS = 512  # rows of a block whose counts' greatest common divisor gives the step


class CountStep:
    """The quantisation step of the stored counts (g), from the greatest common divisor of the
    first ``STEP_ROWS`` rows of every block pushed (AX3 packed +-8 g: 4 counts = 15.6 mg)."""

    def __init__(self):
        self._gcd = np.zeros(3, np.int64)
        self._cpg = None

    def push(self, block) -> None:
        acc = getattr(block, "accel", None)
        if acc is None or acc.shape[0] == 0 or np.all(self._gcd == 1):
            return
        c = np.abs(np.asarray(acc[:STEP_ROWS, :3], np.int64))
        self._gcd = np.gcd(self._gcd, np.gcd.reduce(c, axis=0))
        self._cpg = np.broadcast_to(np.asarray(block.accel_counts_per_g, np.float64), (3,))

    @property
    def step_g(self):
        """(3,) step in g, or None before any nonzero count."""
        if self._cpg is None or not np.all(self._gcd > 0):
            return None
        return self._gcd / self._cpg
