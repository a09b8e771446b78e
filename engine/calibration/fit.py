"""The autocalibration fit: weighted iterative closest point (ICP) of nonmovement window means to
the 1 g sphere (van Hees et al. 2014, J Appl Physiol 117:738; GGIR ``g.calibrate``).

Model (GGIR form), per axis k, temperature T in degC, T_ref the mean temperature of the fitted
windows::

    cal_k = (raw_k + offset_k) * scale_k + (T - T_ref) * tempoffset_k

Pure functions on arrays; :func:`fit_calibration` wraps them for a ``WindowFeatures`` table and
returns a :class:`CalibrationEstimate` whose ``status`` and one-line ``reason`` say what happened.

Two stopping rules:

* ``ggir_compatible=True``: GGIR's rule (stop when the weighted residual ``res`` changes by less
  than 1e-10 between iterations), GGIR's arithmetic and GGIR's error rounding (1e-5 g), so the
  numbers equal GGIR's for the same windows.
* default: iterate until no parameter moves by more than ``param_tol`` (1e-9): ``res`` is itself
  only ~1e-6..1e-9, so the absolute 1e-10 rule can stop long before the parameters settle.

Variants (the paper's comparison): ``"auto"`` (offset + scale, plus the temperature term when the
temperature is usable: C2, else C1), ``"c1"`` (offset + scale), ``"c2"`` (offset + scale +
temperature), ``"offset"`` (offset only), ``"scale"`` (scale only).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from ..features import WindowFeatures
from .estimate import CalibrationEstimate, FitDiagnostics
from .quantisation import dequantised
from .select import MAX_ABS_MEAN_G, SD_THRESHOLD_G, select_calibration_windows

WINDOW_S = 10.0  # window length of the calibration features (van Hees 2014)
MIN_WINDOWS = 10  # fewer nonmovement windows: no fit (spec section 4; GGIR)
SPHERE_CRIT_G = 0.3  # every axis must reach below -0.3 g and above +0.3 g (GGIR spherecrit)
TARGET_ERROR_MG = 10.0  # error below which a calibration is considered good (paper; GGIR 0.01 g)
MAX_WEIGHT = 100.0  # weights min(1/dist, 100): points within 10 mg of the sphere weigh the same
MAX_ITER = 1000
GGIR_RES_TOL = 1e-10  # GGIR's absolute tolerance on the change of res
PARAM_TOL = 1e-9  # default: largest parameter change at convergence
TEMP_MIN_SD_C = 0.01  # GGIR: temperature with SD below this is "flat" and not used
TEMP_MAX_C = 120.0  # GGIR: first temperatures above this are implausible, temperature not used
GGIR_ERROR_DIGITS = 5  # GGIR rounds the calibration error (g) to 5 decimals

VARIANTS = ("auto", "c1", "c2", "offset", "scale")


# ----------------------------------------------------------------------------- pure maths
def apply_model(mean: np.ndarray, temp_centered: Optional[np.ndarray], offset, scale, tempoffset,
                *, ggir_arithmetic: bool = False) -> np.ndarray:
    """Calibrated window means (k, 3). ``temp_centered`` is T - T_ref (k,) or None.

    ``ggir_arithmetic`` evaluates the model the way GGIR does (divide by 1/scale, 1/tempoffset),
    which differs from the plain form only in the last bits.
    """
    offset = np.asarray(offset, np.float64)
    scale = np.asarray(scale, np.float64)
    tempoffset = np.asarray(tempoffset, np.float64)
    if ggir_arithmetic:
        with np.errstate(divide="ignore"):
            cal = (mean - (-offset)) / (1.0 / scale)
            if temp_centered is not None:
                cal = cal + temp_centered[:, None] / (1.0 / tempoffset)
        return cal
    cal = (mean + offset) * scale
    if temp_centered is not None:
        cal += temp_centered[:, None] * tempoffset
    return cal


def calibration_error_g(cal: np.ndarray) -> float:
    """Mean over windows of | ||cal|| - 1 | in g (van Hees 2014's calibration error)."""
    cal = np.asarray(cal, np.float64).reshape(-1, 3)
    if cal.shape[0] == 0:
        return float("nan")
    return float(np.mean(np.abs(np.sqrt(np.sum(cal * cal, axis=1)) - 1.0)))


def round_ggir_error(error_g: float) -> float:
    """The calibration error as GGIR reports it: rounded to 1e-5 g."""
    return round(float(error_g), GGIR_ERROR_DIGITS)


@dataclass
class SphereCoverage:
    covered: bool
    minimum: np.ndarray  # (3,) lowest window mean per axis, g
    maximum: np.ndarray  # (3,) highest window mean per axis, g
    crit: float

    def describe(self) -> str:
        if self.covered:
            return f"sphere covered (every axis beyond +/-{self.crit:g} g)"
        parts = []
        for k, ax in enumerate("xyz"):
            if not self.minimum[k] < -self.crit:
                parts.append(f"{ax} never below -{self.crit:g} g (min {self.minimum[k]:+.3f} g)")
            if not self.maximum[k] > self.crit:
                parts.append(f"{ax} never above +{self.crit:g} g (max {self.maximum[k]:+.3f} g)")
        return "sphere not covered: " + "; ".join(parts)


def sphere_coverage(mean: np.ndarray, crit: float = SPHERE_CRIT_G) -> SphereCoverage:
    """Sphere criterion: on every axis some window mean is below -crit and some above +crit."""
    mean = np.asarray(mean, np.float64).reshape(-1, 3)
    if mean.shape[0] == 0:
        return SphereCoverage(False, np.full(3, np.nan), np.full(3, np.nan), crit)
    lo, hi = mean.min(axis=0), mean.max(axis=0)
    return SphereCoverage(bool(np.all(lo < -crit) and np.all(hi > crit)), lo, hi, crit)


def temperature_check(temperature: Optional[np.ndarray]) -> tuple[bool, str]:
    """Whether the temperature term can be fitted, and why not (GGIR's rules on window means)."""
    if temperature is None:
        return False, "temperature missing"
    t = np.asarray(temperature, np.float64).reshape(-1)
    finite = t[np.isfinite(t)]
    if finite.size == 0:
        return False, "temperature missing"
    if finite.size < t.size / 2:
        return False, f"temperature missing in {t.size - finite.size} of {t.size} windows"
    if np.mean(finite[:10]) > TEMP_MAX_C:
        return False, f"temperature implausible (first values above {TEMP_MAX_C:g} degC)"
    if finite.size < 2 or np.std(finite, ddof=1) < TEMP_MIN_SD_C:
        sd = np.std(finite, ddof=1) if finite.size > 1 else 0.0
        return False, f"temperature flat (SD {sd:.3g} degC < {TEMP_MIN_SD_C:g})"
    return True, "temperature used"


def _wls_qr(curr, closest, t, w, fit_offset, fit_scale):
    """Per-axis weighted least squares the way R's lm.wfit does it (orthogonal decomposition of
    sqrt(w)-scaled rows; fitted = y - residual / sqrt(w)). Returns coefficients (3, p) and the
    fitted current points (n, 3).

    The scaled design [1, current, T - T_ref] * sqrt(w) is filled column by column (element for
    element the ``column_stack(...) * sw[:, None]`` matrix, a fraction of the time on ~10k
    rows)."""
    n = curr.shape[0]
    sw = np.sqrt(w)
    p = int(fit_offset) + int(fit_scale) + int(t is not None)
    x = np.empty((n, p))
    j_cur = int(fit_offset)
    if fit_offset:
        x[:, 0] = sw  # 1 * sw
    if t is not None:
        np.multiply(t, sw, out=x[:, p - 1])
    coefs, fitted = [], np.empty_like(curr)
    for k in range(3):
        if fit_scale:
            np.multiply(curr[:, k], sw, out=x[:, j_cur])
        y = closest[:, k] if fit_scale else closest[:, k] - curr[:, k]
        yw = y * sw
        coef = np.linalg.lstsq(x, yw, rcond=None)[0]
        yhat = y - (yw - x @ coef) / sw
        fitted[:, k] = yhat if fit_scale else yhat + curr[:, k]
        coefs.append(coef)
    return np.array(coefs), fitted


def _model_columns(mean, t, offset, scale, tempoffset, out):
    """``apply_model`` (plain arithmetic) column by column into ``out`` (n, 3): the same
    element-wise operations, so the same numbers."""
    for j in range(3):
        c = out[:, j]
        np.add(mean[:, j], offset[j], out=c)
        c *= scale[j]
        if t is not None:
            c += t * tempoffset[j]
    return out


def _row_norms(a):
    """``np.sqrt(np.sum(a * a, axis=1))`` for (n, 3) ``a`` column by column (numpy sums three
    columns as (x + y) + z)."""
    x, y, z = a[:, 0], a[:, 1], a[:, 2]
    s = x * x
    s += y * y
    s += z * z
    return np.sqrt(s, out=s)


def _warm_state(mean, t, start, fit_offset, fit_scale, ggir_compatible, max_weight):
    """Parameters and weights to start the ICP from ``start`` (identity when unusable)."""
    n = mean.shape[0]
    o, s, to = (np.array(v, np.float64).reshape(3) for v in start)
    o = o if fit_offset else np.zeros(3)
    s = s if fit_scale else np.ones(3)
    to = to if t is not None else np.zeros(3)
    curr = apply_model(mean, t, o, s, to, ggir_arithmetic=ggir_compatible)
    with np.errstate(invalid="ignore", divide="ignore"):
        w = np.minimum(1.0 / np.abs(np.sqrt(np.sum(curr * curr, axis=1)) - 1.0), max_weight)
    if not (np.all(np.isfinite(w)) and np.all(np.isfinite(curr))):
        return np.zeros(3), np.ones(3), np.zeros(3), np.ones(n)
    return o, s, to, w


@dataclass
class IcpResult:
    """Parameters and diagnostics of one ICP run."""

    offset: np.ndarray
    scale: np.ndarray
    tempoffset: np.ndarray
    iterations: int
    converged: bool  # the stopping rule was met before max_iter
    stop_rule: str  # "ggir-res" or "parameters"
    res: list = field(default_factory=list)  # weighted residual per iteration
    failed: str = ""  # non-empty when the iteration broke down (non-finite values)


def icp_sphere_fit(mean: np.ndarray, temp_centered: Optional[np.ndarray] = None, *,
                   fit_offset: bool = True, fit_scale: bool = True, ggir_compatible: bool = False,
                   max_iter: int = MAX_ITER, param_tol: float = PARAM_TOL,
                   res_tol: float = GGIR_RES_TOL, max_weight: float = MAX_WEIGHT,
                   start: Optional[tuple] = None) -> IcpResult:
    """Weighted ICP of window means (k, 3) g to the unit sphere.

    Each iteration: project the current calibrated points to the sphere; per axis, weighted least
    squares of the projection on [1, current, T - T_ref] (columns per variant); fold the
    coefficients into offset/scale/tempoffset; new weights min(1/distance, max_weight).

    ``start``: (offset, scale, tempoffset) to iterate from instead of identity (a warm start,
    e.g. the previous fit on a subset of these windows); the first weights are then each point's
    distance to the sphere under it, which is what they are at a fixed point. The stopping rule
    is unchanged, so a warm start ends within the tolerance of the same fixed point.
    """
    if not (fit_offset or fit_scale):
        raise ValueError("at least one of offset and scale must be fitted")
    mean = np.asarray(mean, np.float64).reshape(-1, 3)
    n = mean.shape[0]
    use_t = temp_centered is not None
    t = np.asarray(temp_centered, np.float64).reshape(-1) if use_t else None
    offset, scale, tempoffset = np.zeros(3), np.ones(3), np.zeros(3)
    weights = np.ones(n)
    if start is not None:
        offset, scale, tempoffset, weights = _warm_state(mean, t, start, fit_offset, fit_scale,
                                                         ggir_compatible, max_weight)
    res_hist = [float("inf")]
    converged, failed, it = False, "", 0
    curr_buf, closest = np.empty((n, 3)), np.empty((n, 3))
    for it in range(1, max_iter + 1):
        if ggir_compatible:
            curr = apply_model(mean, t, offset, scale, tempoffset, ggir_arithmetic=True)
        else:
            curr = _model_columns(mean, t, offset, scale, tempoffset, curr_buf)
        norm = _row_norms(curr)
        with np.errstate(invalid="ignore", divide="ignore"):
            for j in range(3):
                np.divide(curr[:, j], norm, out=closest[:, j])
        if not np.all(np.isfinite(closest)):
            failed = f"non-finite values at iteration {it}"
            it -= 1
            break
        d_off, d_scale, d_t = np.zeros(3), np.ones(3), np.zeros(3)
        coefs, fitted = _wls_qr(curr, closest, t, weights, fit_offset, fit_scale)
        j = 0
        if fit_offset:
            d_off = coefs[:, j]
            j += 1
        if fit_scale:
            d_scale = coefs[:, j]
            j += 1
        if use_t:
            d_t = coefs[:, j]
        new_offset = offset + d_off / (scale * d_scale)
        new_tempoffset = tempoffset * d_scale + d_t if use_t else tempoffset
        new_scale = scale * d_scale
        change = max(np.max(np.abs(new_offset - offset)), np.max(np.abs(new_scale - scale)),
                     np.max(np.abs(new_tempoffset - tempoffset)))
        offset, scale, tempoffset = new_offset, new_scale, new_tempoffset
        diff = fitted - closest
        res_hist.append(float(3.0 * np.mean(weights[:, None] * diff ** 2 / np.sum(weights))))
        with np.errstate(divide="ignore"):
            weights = np.minimum(1.0 / _row_norms(diff), max_weight)
        if not np.all(np.isfinite(offset)) or not np.all(np.isfinite(scale)):
            failed = f"non-finite parameters at iteration {it}"
            break
        if ggir_compatible:
            if abs(res_hist[-1] - res_hist[-2]) < res_tol:
                converged = True
                break
        elif change < param_tol:
            converged = True
            break
    return IcpResult(offset, scale, tempoffset, it, converged,
                     "ggir-res" if ggir_compatible else "parameters", res_hist[1:], failed)


# ----------------------------------------------------------------------------- features -> estimate
def _hours(start_ns, end_ns) -> Optional[float]:
    if start_ns is None or end_ns is None:
        return None
    return (int(end_ns) - int(start_ns)) / 3.6e12


def _mg(error_g: float, ggir_compatible: bool) -> float:
    if ggir_compatible:
        return round(round_ggir_error(error_g) * 1000.0, 2)
    return float(error_g) * 1000.0


def fit_calibration(features: WindowFeatures, *, temperature: bool = True,
                    ggir_compatible: bool = False, variant: str = "auto", select: bool = True,
                    min_windows: int = MIN_WINDOWS, sphere_crit: float = SPHERE_CRIT_G,
                    target_error_mg: float = TARGET_ERROR_MG, sd_threshold: float = SD_THRESHOLD_G,
                    max_abs_mean: float = MAX_ABS_MEAN_G, max_iter: int = MAX_ITER,
                    param_tol: float = PARAM_TOL, device_key: Optional[str] = None,
                    data_start_ns: Optional[int] = None, data_end_ns: Optional[int] = None,
                    window_s: float = WINDOW_S,
                    windows_offered: Optional[int] = None,
                    start: Optional[CalibrationEstimate] = None, quantisation_step_g=None,
                    means_dequantised: bool = False,
                    temperature_fallback: bool = True) -> CalibrationEstimate:
    """Fit the calibration on a table of window features and judge the result.

    ``features``: all windows of a recording (``select=True`` picks the nonmovement windows) or
    windows already selected (``select=False``). ``data_start_ns``/``data_end_ns``: the data range
    the features cover (default: from the first window start to the end of the last window); it
    becomes the estimate's fit range and ``hours_used``.

    Outcomes (``status``): ``ok``; ``high_error`` (improved but still above ``target_error_mg``;
    applied); ``reverted`` (the fit did not lower the error: identity); ``no_nonmovement``;
    ``too_few_windows``; ``sphere_not_covered``; ``failed`` (the iteration broke down). Every
    non-applied outcome carries identity parameters; the rejected fit is kept in its diagnostics
    (``FitDiagnostics``, kept as the estimate's ``extra``).

    ``start``: an estimate to start the iteration from (re-referenced to these windows' mean
    temperature) instead of identity; same stopping rule, so the result is the same fixed point
    within ``param_tol``. Used by online refits, whose windows grow by a few percent per refit.

    An applied fit carries one standard error per coefficient (``uncertainty``, block-robust:
    engine/calibration/uncertainty.py) and the warnings of engine/calibration/trust.py in
    the diagnostics' ``warnings`` and ``flags`` and in the reason. With ``variant="auto"`` and
    ``temperature_fallback`` a temperature term whose standard error is above the limit and
    that cannot be told from zero (trust.py: ``temperature_undetermined``) is dropped and the
    model refitted without it (C1); the dropped fit is kept in ``temperature_dropped``.
    A term over the limit but clearly not zero is kept with ``temperature_imprecise``.

    ``quantisation_step_g``: the stored values' step (g). The window means are de-biased for it
    (engine/calibration/quantisation.py; not in GGIR-compatible mode) unless the caller did so
    already (``means_dequantised``, e.g. once per window as windows accumulate); it also feeds
    the quantisation warning.
    """
    call = dict(locals())
    if variant not in VARIANTS:
        raise ValueError(f"unknown variant {variant!r}; expected one of {', '.join(VARIANTS)}")
    if ggir_compatible and variant in ("offset", "scale"):
        raise ValueError("ggir_compatible fits offset and scale (variant auto, c1 or c2)")
    n_in = len(features) if windows_offered is None or select else int(windows_offered)
    if data_start_ns is None and len(features):
        data_start_ns = int(features.start_ns.min())
    if data_end_ns is None and len(features):
        data_end_ns = int(features.start_ns.max()) + int(round(window_s * 1e9))
    diag = FitDiagnostics(variant=variant, ggir_compatible=bool(ggir_compatible),
                          windows_offered=n_in, flags=[])
    if select:
        sel = select_calibration_windows(features, sd_threshold=sd_threshold,
                                         max_abs_mean=max_abs_mean)
        feats = sel.features
        diag.repeats_collapsed = sel.repeats_dropped
    else:
        feats = features
    span = dict(device_key=device_key, hours_used=_hours(data_start_ns, data_end_ns),
                fit_start_ns=data_start_ns, fit_end_ns=data_end_ns)

    def estimate(**fields) -> CalibrationEstimate:
        return CalibrationEstimate(**fields, **span, extra=diag.to_extra())

    mean = feats.mean
    usable = np.all(np.isfinite(mean), axis=1) & np.any(mean != 0.0, axis=1)
    if not np.all(usable):
        diag.windows_unusable = int((~usable).sum())
        feats = feats.select(usable)
        mean = feats.mean
    step = quantisation_step_g
    if step is not None and not ggir_compatible and len(feats):
        if not means_dequantised:
            feats = dequantised(feats, step)
            mean = feats.mean
        diag.means_dequantised = True
    n = len(feats)
    if n == 0:
        return estimate(
            status="no_nonmovement", method="identity", windows=0,
            reason=(f"no nonmovement windows (SD < {sd_threshold * 1000:g} mg and |mean| < "
                    f"{max_abs_mean:g} g on all axes) among {n_in} windows: not calibrated"))

    error_before_g = calibration_error_g(mean)
    err_before_mg = _mg(error_before_g, ggir_compatible)
    if n < min_windows:
        return estimate(
            status="too_few_windows", method="identity", windows=n, error_before_mg=err_before_mg,
            reason=f"only {n} nonmovement windows (< {min_windows}): not calibrated")
    cover = sphere_coverage(mean, sphere_crit)
    diag.sphere_min_g = [float(v) for v in cover.minimum]
    diag.sphere_max_g = [float(v) for v in cover.maximum]
    if not cover.covered:
        return estimate(
            status="sphere_not_covered", method="identity", windows=n,
            error_before_mg=err_before_mg,
            reason=f"{cover.describe()} in {n} windows: not calibrated (fit unconstrained)")

    # temperature term
    want_t = temperature and variant in ("auto", "c2")
    temps = feats.temperature
    t_ok, t_reason = temperature_check(temps) if want_t else (
        False, "temperature term off (requested)" if variant in ("auto", "c2") else
        f"temperature not part of variant {variant}")
    temp_centered, t_ref = None, 0.0
    if t_ok:
        finite_t = np.isfinite(temps)
        if not np.all(finite_t):
            diag.windows_without_temperature = int((~finite_t).sum())
            feats = feats.select(finite_t)
            mean, temps, n = feats.mean, feats.temperature, len(feats)
            error_before_g = calibration_error_g(mean)
            err_before_mg = _mg(error_before_g, ggir_compatible)
        t_ref = float(np.mean(temps))
        temp_centered = temps - t_ref
    diag.temperature_used = bool(t_ok)
    diag.temperature_reason = t_reason
    if variant == "c2" and not t_ok:
        diag.flag("temperature_unavailable")

    icp_start = None
    if start is not None:
        s0 = rereference(start, t_ref) if (t_ok and start.uses_temperature) else start
        icp_start = (s0.offset, s0.scale, s0.tempoffset)
        diag.warm_start = True
    r = icp_sphere_fit(mean, temp_centered, fit_offset=variant != "scale",
                       fit_scale=variant != "offset", ggir_compatible=ggir_compatible,
                       max_iter=max_iter, param_tol=param_tol, start=icp_start)
    method = {"offset": "autocal-offset", "scale": "autocal-scale"}.get(
        variant, "autocal-c2" if t_ok else "autocal-c1")
    diag.converged, diag.stop_rule = r.converged, r.stop_rule
    diag.res_final = r.res[-1] if r.res else None
    if not r.converged:
        diag.flag("not_converged")
    if r.failed:
        diag.rejected_fit = {"offset": r.offset.tolist(), "scale": r.scale.tolist(),
                             "tempoffset": r.tempoffset.tolist()}
        return estimate(
            status="failed", method="identity", windows=n, iterations=r.iterations,
            error_before_mg=err_before_mg, reason=f"fit failed ({r.failed}): not calibrated")
    cal = apply_model(mean, temp_centered, r.offset, r.scale, r.tempoffset,
                      ggir_arithmetic=ggir_compatible)
    error_after_g = calibration_error_g(cal)
    err_after_mg = _mg(error_after_g, ggir_compatible)
    if ggir_compatible:
        diag.error_before_g = round_ggir_error(error_before_g)
        diag.error_after_g = round_ggir_error(error_after_g)
        worse = diag.error_after_g > diag.error_before_g
    else:
        worse = not error_after_g < error_before_g
    conv = "" if r.converged else f", not converged after {r.iterations} iterations"
    t_note = "" if t_ok else f"; {t_reason}"
    if worse:
        diag.rejected_fit = {"offset": r.offset.tolist(), "scale": r.scale.tolist(),
                             "tempoffset": r.tempoffset.tolist(),
                             "temperature_ref": t_ref, "error_after_mg": err_after_mg}
        return estimate(
            status="reverted", method="identity", windows=n, iterations=r.iterations,
            error_before_mg=err_before_mg, error_after_mg=err_before_mg,
            reason=(f"fit did not lower the error ({err_before_mg:.2f} -> {err_after_mg:.2f} mg "
                    f"on {n} windows{conv}): identity used"))
    if err_after_mg < target_error_mg:
        status = "ok"
        reason = (f"calibrated: error {err_before_mg:.2f} -> {err_after_mg:.2f} mg on {n} "
                  f"windows, {method}{conv}{t_note}")
    else:
        status = "high_error"
        reason = (f"error {err_before_mg:.2f} -> {err_after_mg:.2f} mg on {n} windows is still "
                  f"above the {target_error_mg:g} mg target (applied){conv}{t_note}")
    est = estimate(
        offset=r.offset, scale=r.scale, tempoffset=r.tempoffset, temperature_ref=t_ref,
        status=status, reason=reason, method=method, error_before_mg=err_before_mg,
        error_after_mg=err_after_mg, windows=n, iterations=r.iterations)
    return _judge(est, feats, t_ok, call)


def _judge(est: CalibrationEstimate, feats: WindowFeatures, t_used: bool,
           call: dict) -> CalibrationEstimate:
    """Standard errors and warnings for an applied fit; the C1 fallback when the temperature
    term is not determined (see :func:`fit_calibration`)."""
    from .trust import FitWarning, add_warnings, assess, temperature_wald, temperature_warning
    from .uncertainty import BLOCK_GAP_S, MIN_BLOCKS, coefficient_uncertainty

    variant = call["variant"]
    u = coefficient_uncertainty(feats.mean, feats.temperature if t_used else None, est.offset,
                                est.scale, est.tempoffset, est.temperature_ref, feats.start_ns,
                                fit_offset=variant != "scale", fit_scale=variant != "offset")
    est.uncertainty = u.to_dict()
    diag = est.diagnostics
    diag.uncertainty_blocks = u.blocks
    est.diagnostics = diag
    warnings = []
    if u.blocks < MIN_BLOCKS:
        warnings.append(FitWarning("uncertainty_unknown", (
            f"standard errors not computable: the {len(feats)} windows form only {u.blocks} "
            f"independent block(s) (< {MIN_BLOCKS}; windows more than {BLOCK_GAP_S / 60:g} min "
            "apart start a new block)")))
    tw = temperature_warning(est.tempoffset, u.tempoffset, feats.temperature, u.blocks,
                             temperature_wald(est.tempoffset, u.covariance, u.names)) \
        if t_used and u.blocks >= MIN_BLOCKS else None
    if tw is not None and tw.code == "temperature_imprecise":
        warnings.append(tw)
    elif tw is not None:
        if variant == "auto" and call["temperature_fallback"] and not call["ggir_compatible"]:
            c1 = fit_calibration(**dict(call, variant="c1", start=None))
            d1 = c1.diagnostics
            d1.variant = variant
            d1.temperature_used = False
            d1.temperature_reason = tw.message
            d1.temperature_dropped = {
                "offset": est.offset.tolist(), "scale": est.scale.tolist(),
                "tempoffset": est.tempoffset.tolist(), "temperature_ref": est.temperature_ref,
                "uncertainty": est.uncertainty, "error_after_mg": est.error_after_mg}
            if c1.applied:
                # the fallback's own warnings are already in; the reason for it goes first
                d1.warnings = [tw.to_dict(), *(d1.warnings or ())]
                d1.flag(tw.code)
                c1.diagnostics = d1
                base, sep, rest = c1.reason.replace(
                    "; temperature not part of variant c1", "").partition("; warning: ")
                c1.reason = f"{base}; warning: {tw.message}{sep}{rest}"
                return c1
            diag.temperature_fallback_failed = c1.reason
            est.diagnostics = diag
        why = ("GGIR-compatible mode" if call["ggir_compatible"] else
               f"variant {variant} requested" if variant != "auto" else "fallback switched off")
        tw.message = tw.message.split(": fitted without it")[0] + f": kept ({why})"
        warnings.append(tw)
    warnings += assess(est.uncertainty, feats.mean, feats.sd,
                       quantisation_step_g=call["quantisation_step_g"],
                       dequantised=bool(diag.means_dequantised))
    add_warnings(est, warnings)
    return est


def estimate_error_mg(estimate: CalibrationEstimate, features: WindowFeatures) -> tuple[float, int]:
    """Calibration error (mg) of ``estimate`` applied to the window means of ``features``, and the
    number of windows it was computed on (windows without temperature are skipped when the
    estimate has a temperature term)."""
    mean, temps = features.mean, features.temperature
    if estimate.uses_temperature:
        ok = np.isfinite(temps)
        mean, temps = mean[ok], temps[ok]
        cal = estimate.apply(mean, temps)
    else:
        cal = estimate.apply(mean)
    return calibration_error_g(cal) * 1000.0, int(mean.shape[0])


def rereference(estimate: CalibrationEstimate, temperature_ref: float) -> CalibrationEstimate:
    """The same calibration expressed with another reference temperature.

    (raw + o) s + (T - R) t = (raw + o + (R' - R) t / s) s + (T - R') t, so only the offset moves.
    Needed to compare estimates fitted at different mean temperatures.
    """
    import copy

    est = copy.deepcopy(estimate)
    est.offset = estimate.offset + (temperature_ref - estimate.temperature_ref) * \
        estimate.tempoffset / estimate.scale
    est.temperature_ref = float(temperature_ref)
    return est
