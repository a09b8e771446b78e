"""The discrepancy workflow: fit a sensor model to nonmovement windows, locate where it and the
measurement disagree, name the missing effect from the candidate library, add it, and repeat while
the held-out gap shrinks.

Pre-declared metric (the "gap"): mean over held-out nonmovement windows of | ||a|| - 1 | in mg, a the
window mean corrected by the model. Held-out windows come from blocked cross-validation: the
recording is cut into ``folds`` contiguous time blocks of equal window count; each block is scored
with the model fitted on the others, so every window is held out once.

A candidate is selected only if (1) dBIC < -10 on all windows, with n counted as independent windows
(n over the integrated autocorrelation time of the new parameter's score, see ``sensor_fit.fit`` and
``sensor_fit.effective_n``), and
(2) the held-out gap with the candidate is lower than without it. Among those that pass, the one with
the lowest dBIC is named (candidates are scored on held-out data in dBIC order until one passes). A term that makes the held-out gap worse is never kept.

``run(prepared, start_model=None, truth=None) -> DiscrepancyResult`` (pure; I/O in report.py).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Dict, List, Optional

import numpy as np

from .candidates import Candidate, UNITS, DESCRIPTION, library
from .inputs import PreparedInput
from .locate import locate, binned
from .sensor_fit import (FitResult, SensorModel, WindowData, component_index, fit, invert,
                         norm_residual)

BIC_THRESHOLD = -10.0


@dataclass
class CandidateScore:
    candidate: Candidate
    delta_bic: float
    gap_heldout_mg: Optional[float]  # None when dBIC did not pass (held-out not needed)
    passed: bool
    value: float  # display units
    stderr: float

    def to_dict(self) -> dict:
        return {"effect": self.candidate.effect, "axis": self.candidate.component,
                "delta_bic": _r(self.delta_bic), "gap_heldout_mg": _r(self.gap_heldout_mg),
                "passed": self.passed, "value": _r(self.value, 6), "stderr": _r(self.stderr, 6),
                "unit": self.candidate.unit.name}


@dataclass
class Step:
    candidate: Candidate
    parameters: Dict[str, dict]  # name -> {value, stderr, unit}
    gap_before_mg: float
    gap_after_mg: float
    delta_bic: float
    n: int
    n_eff: float
    scores: List[CandidateScore]
    curve_before: dict  # binned residual vs the naming covariate
    curve_after: dict
    plot_before: dict = field(default_factory=dict)  # raw points (subsampled) for the PNG
    plot_after: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        c = self.candidate
        return {"effect": c.effect, "axis": c.component, "description": DESCRIPTION[c.effect],
                "parameters": self.parameters, "gap_before_mg": _r(self.gap_before_mg),
                "gap_after_mg": _r(self.gap_after_mg), "delta_bic": _r(self.delta_bic),
                "n_windows": self.n, "n_independent": _r(self.n_eff, 1),
                "covariate": c.covariate_name(), "residual_vs_covariate_before": self.curve_before,
                "residual_vs_covariate_after": self.curve_after,
                "candidates": [s.to_dict() for s in self.scores]}

    def sentence(self) -> str:
        c = self.candidate
        p = self.parameters[f"{c.effect}.{c.component}"]
        axis = "" if c.component == "all" else f" on {c.component}"
        return (f"{DESCRIPTION[c.effect]}{axis}: {p['value']:.4g} +- {p['stderr']:.2g} {p['unit']} "
                f"(held-out gap {self.gap_before_mg:.3f} -> {self.gap_after_mg:.3f} mg, "
                f"dBIC {self.delta_bic:.1f})")


@dataclass
class DiscrepancyResult:
    steps: List[Step]
    start_model: SensorModel
    base_fit: FitResult
    final_fit: FitResult
    gap_initial_mg: float
    gap_final_mg: float
    gap_insample_initial_mg: float
    gap_insample_final_mg: float
    noise_floor_mg: Optional[float]
    locate_initial: list
    locate_final: list
    distributions: dict
    skipped: list
    input_info: dict
    folds: int
    last_scores: List[CandidateScore]
    data: Optional[WindowData] = None  # the nonmovement windows compared (for per-window output)

    @property
    def named(self) -> List[tuple]:
        return [(s.candidate.effect, s.candidate.component) for s in self.steps]


def per_window(res: "DiscrepancyResult") -> dict:
    """What the sensor should have read in each nonmovement window (1 g in the window's
    orientation, at its temperature and time) under the start and the final model, next to what
    it read. The orientation is the measured mean corrected by the final model, normalised."""
    d = res.data
    u = invert(res.final_fit.model, d)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    from .sensor_fit import forward
    return {"t_days": d.t_days, "temperature": d.temperature, "measured": d.mean,
            "predicted_start": forward(res.base_fit.model, u, d),
            "predicted_final": forward(res.final_fit.model, u, d),
            "residual_start_mg": res.base_fit.residual * 1000.0,
            "residual_final_mg": res.final_fit.residual * 1000.0}


def _step_mg(prepared):
    step = getattr(prepared, "count_step_g", None)
    return None if step is None else np.asarray(step, np.float64) * 1000.0


def _r(x, nd=4):
    return None if x is None else float(round(float(x), nd))


def sphere_coverage(mean: np.ndarray, limit: float = 0.3) -> dict:
    """van Hees sphere criterion: on every axis the window means reach below -0.3 g and above
    +0.3 g; without it offset/gain (and anything else) are poorly constrained."""
    lo, hi = mean.min(axis=0), mean.max(axis=0)
    return {"min_g": [round(float(v), 4) for v in lo], "max_g": [round(float(v), 4) for v in hi],
            "covered": bool(np.all(lo < -limit) and np.all(hi > limit))}


def time_folds(t_days: np.ndarray, folds: int) -> np.ndarray:
    """Fold id per window: contiguous time blocks with equal window counts."""
    order = np.argsort(t_days, kind="stable")
    fid = np.empty(t_days.shape[0], np.int64)
    fid[order] = np.arange(t_days.shape[0]) * folds // t_days.shape[0]
    return fid


def heldout_residual(model: SensorModel, data: WindowData, fid: np.ndarray) -> np.ndarray:
    """Residual of every window under the model fitted without its time block."""
    r = np.empty(len(data))
    for f in np.unique(fid):
        test = fid == f
        fr = fit(model, data.take(~test))
        r[test] = norm_residual(fr.model, data.take(test))
    return r


def _gap(r) -> float:
    return float(np.mean(np.abs(r)) * 1000.0)


def delta_bic(base: FitResult, cand: FitResult, key) -> float:
    """dBIC = n_ind ln(L1 / L0) + dk ln(n_ind), both likelihoods on the same count of independent
    windows: n / tau, tau the integrated autocorrelation time of the new parameter's score
    contributions under the larger model (see sensor_fit.fit)."""
    ne = cand.n_independent(key)
    return float(ne * np.log(max(cand.loss, 1e-300) / max(base.loss, 1e-300))
                 + (cand.k - base.k) * np.log(ne))


def _parameters(fr: FitResult, effect: str) -> Dict[str, dict]:
    """All components of ``effect`` that are on in the fit, in display units."""
    unit = UNITS[effect]
    out = {}
    for e, c in fr.model.active:
        if e != effect:
            continue
        v = fr.model.values[e][component_index(e, c)]
        out[f"{e}.{c}"] = {"value": _r(unit.show(v), 6), "stderr": _r(unit.show_se(fr.stderr.get((e, c), np.nan)), 6),
                  "unit": unit.name}
    return out


def _curve(cand: Candidate, model: SensorModel, data: WindowData, r: np.ndarray, max_points=4000):
    u = invert(model, data)
    u = u / np.linalg.norm(u, axis=1, keepdims=True)
    x, w = cand.covariate(model, data, u)
    if cand.effect in ("offset", "gain", "misalignment", "nonlinearity"):
        sel = np.ones(len(data), bool)
        y = r
    else:
        aw = np.abs(w)
        sel = aw >= 0.6 * np.percentile(aw, 95) if aw.size else aw > 0
        y = r * np.sign(w)
    xs, ys = x[sel], y[sel] * 1000.0
    curve = binned(xs, ys)
    if xs.size > max_points:
        pick = np.linspace(0, xs.size - 1, max_points).astype(int)
        xs, ys = xs[pick], ys[pick]
    return curve, {"x": xs, "y": ys, "xlabel": cand.covariate_name(),
                   "ylabel": "residual ||a||-1 (mg)" + ("" if cand.effect in
                                                        ("offset", "gain", "misalignment",
                                                         "nonlinearity") else
                                                        " x sign of orientation weight")}


def run(prepared: PreparedInput, start_model: Optional[SensorModel] = None,
        truth: Optional[SensorModel] = None, folds: int = 5, bic_threshold: float = BIC_THRESHOLD,
        max_steps: int = 8, effects: Optional[List[str]] = None, noise_model_mg=None,
        rate_hz: Optional[float] = None) -> DiscrepancyResult:
    data = prepared.data
    if len(data) < 50:
        raise ValueError(f"only {len(data)} nonmovement windows: at least 50 are needed to compare")
    tref = float(np.mean(data.temperature)) if data.has_temperature else 25.0
    model = (start_model or SensorModel.baseline()).shift_temperature_ref(tref)
    if not data.has_temperature:
        model.active = [(e, c) for e, c in model.active
                        if e not in ("temperature_offset", "temperature_gain", "thermal_lag")]
    fid = time_folds(data.t_days, folds)

    current = fit(model, data)
    base_fit = current
    gap_now = _gap(heldout_residual(current.model, data, fid))
    gap_initial = gap_now
    loc0 = locate(current.model, data, current.residual)
    steps: List[Step] = []
    skipped_all = []
    scores: List[CandidateScore] = []
    for _ in range(max_steps):
        cands, skipped = library(current.model, data, effects)
        skipped_all = [{"effect": c.effect, "axis": c.component, "reason": why} for c, why in skipped]
        scores = []
        fits = {}
        for cand in cands:
            trial = current.model.with_component(cand.effect, cand.component)
            try:
                fr = fit(trial, data)
            except (ValueError, np.linalg.LinAlgError):
                continue
            db = delta_bic(current, fr, (cand.effect, cand.component))
            e_i = trial.active.index((cand.effect, cand.component))
            val = cand.unit.show(fr.model.theta()[e_i])
            se = cand.unit.show_se(fr.stderr.get((cand.effect, cand.component), np.nan))
            fits[cand] = fr
            scores.append(CandidateScore(cand, db, None, False, val, se))
        scores.sort(key=lambda s: s.delta_bic)
        # in dBIC order, the first candidate whose held-out gap falls is the best passing one;
        # held-out scores of the ones after it are not needed
        for sc in scores:
            if sc.delta_bic >= bic_threshold:
                break
            sc.gap_heldout_mg = _gap(heldout_residual(fits[sc.candidate].model, data, fid))
            sc.passed = sc.gap_heldout_mg < gap_now
            if sc.passed:
                break
        passing = [s for s in scores if s.passed]
        if not passing:
            break
        best = passing[0]
        fr = fits[best.candidate]
        cb, pb = _curve(best.candidate, current.model, data, current.residual)
        ca, pa = _curve(best.candidate, fr.model, data, fr.residual)
        steps.append(Step(best.candidate, _parameters(fr, best.candidate.effect),
                          gap_now, best.gap_heldout_mg, best.delta_bic, fr.n,
                          fr.n_independent((best.candidate.effect, best.candidate.component)), scores,
                          cb, ca, pb, pa))
        current = fr
        gap_now = best.gap_heldout_mg
    noise_floor = None
    if truth is not None:
        noise_floor = _gap(norm_residual(truth, data))
    from .locate import distributions
    info = dict(prepared.input_info_extra()) if hasattr(prepared, "input_info_extra") else {}
    info.update(prepared.describe())
    info["sphere"] = sphere_coverage(data.mean)
    return DiscrepancyResult(
        steps=steps, start_model=model, base_fit=base_fit, final_fit=current,
        gap_initial_mg=gap_initial, gap_final_mg=gap_now,
        gap_insample_initial_mg=base_fit.gap_mg, gap_insample_final_mg=current.gap_mg,
        noise_floor_mg=noise_floor, locate_initial=loc0,
        locate_final=locate(current.model, data, current.residual),
        distributions=distributions(base_fit.model, current.model, data, noise_model_mg,
                                    rate_hz if rate_hz is not None else prepared.rate_hz,
                                    _step_mg(prepared)),
        skipped=skipped_all, input_info=info, folds=folds, last_scores=scores, data=data)
