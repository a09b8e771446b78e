"""Whether a calibration fit can be trusted: its coefficients' standard errors and the warnings a
user acts on.

Checks on a converged fit (limits are module constants and appear in the messages):

* ``temperature_undetermined``: a temperature coefficient's standard error is above
  ``TEMPOFFSET_SE_LIMIT_MG_C`` (0.05 mg/degC, so that +-2 SE stays within 0.1 mg/degC). The
  temperature range or the number of independent blocks spanning it is too small to separate the
  temperature term from the offsets; the fit falls back to the model without it (C1), as GGIR does
  when the temperature is unusable.
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


def temperature_warning(tempoffset_g_c: np.ndarray, se_tempoffset_g_c: np.ndarray,
                        temperature: np.ndarray, blocks: int) -> Optional[FitWarning]:
    """The fallback warning when a temperature coefficient is not determined, else None. It
    names the axes over the limit, the temperature spread, and the largest |coefficient| / SE
    (a term several SE from zero is likely real, only imprecise: ``--variant c2`` keeps it)."""
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
    return FitWarning("temperature_undetermined", (
        f"temperature term not determined (SE {worst} mg/degC > {TEMPOFFSET_SE_LIMIT_MG_C:g}; "
        f"window temperature p5-p95 {p5:.1f}-{p95:.1f} degC over {blocks} independent "
        f"blocks{hint}): fitted without it (C1), as GGIR does when the temperature is unusable"))


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
           quantisation_step_g=None) -> list:
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
                f"be biased by up to {bound.max():.1f} mg by orientation (coefficients and their "
                "SEs include it)")))
    counts = face_counts(mean)
    n = max(int(counts.sum()), 1)
    thin = [f for f, c in zip(FACES, counts) if c < FACE_MIN_SHARE * n]
    if 6 - len(thin) < MIN_FACES:
        out.append(FitWarning("few_faces", (
            f"sphere covered on only {6 - len(thin)} of 6 faces ({', '.join(thin)} under "
            f"{FACE_MIN_SHARE:.0%} of the windows): offsets and scales rest on few orientations")))
    return out


def add_warnings(estimate, warnings: list) -> None:
    """Record warnings on an estimate: ``extra["warnings"]`` (code, message), ``extra["flags"]``
    (codes) and the one-line reason ("; warning: ...")."""
    extra = estimate.extra
    extra.setdefault("warnings", [])
    extra.setdefault("flags", [])
    for w in warnings:
        extra["warnings"].append(w.to_dict())
        extra["flags"].append(w.code)
        estimate.reason += f"; warning: {w.message}"


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
