"""The discrepancy report: a JSON document (the CLI's ``--json`` output), a plain-text summary and
PNG figures (residual against the naming covariate before/after each step; the initial residual
against every covariate). matplotlib is an optional extra, imported only when figures are drawn.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import List, Optional

import numpy as np

from stillpoint.engine.core.figures import save_figure
from stillpoint.engine.core.outputs import OutputError, atomic_output, check_output_path, describe_os_error
from stillpoint.engine.sim import model as sim

from .discrepancy import BIC_THRESHOLD, DiscrepancyResult
from .simmodel import to_sim

METRIC = ("mean | ||a|| - 1 | in mg over held-out nonmovement windows (a: window mean corrected by "
          "the model); held out by blocked cross-validation over {folds} contiguous time blocks")
RULE = (f"a candidate is named only if dBIC < {BIC_THRESHOLD:g} (n = independent windows) and the "
        "held-out gap falls; the lowest dBIC among those is named; repeat until none passes")

QUANTISATION_WARN_MG = 0.5  # warn when the step can bias still-window means by this much


def _clean(x):
    if isinstance(x, dict):
        return {str(k): _clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_clean(v) for v in x]
    if isinstance(x, (np.floating,)):
        return float(x)
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    if isinstance(x, np.ndarray):
        return _clean(x.tolist())
    if isinstance(x, float) and not np.isfinite(x):
        return None
    return x


def final_model(res: DiscrepancyResult, carry: Optional[sim.SensorModel] = None,
                source: str = "") -> sim.SensorModel:
    note = f"fitted by stillpoint discrepancy on {source}" if source else "fitted by stillpoint discrepancy"
    return to_sim(res.final_fit.model, res.final_fit.stderr, carry=carry, note=note)


def summary_lines(res: DiscrepancyResult) -> List[str]:
    out = []
    if not res.steps:
        out.append("No candidate effect passed (dBIC < -10 and a lower held-out gap): the model "
                   "explains the nonmovement windows as well as the library can tell.")
    for i, s in enumerate(res.steps, 1):
        out.append(f"step {i}: {s.sentence()}")
    out.append(f"held-out gap {res.gap_initial_mg:.3f} mg -> {res.gap_final_mg:.3f} mg"
               + (f" (true model: {res.noise_floor_mg:.3f} mg)" if res.noise_floor_mg is not None else ""))
    return out


def to_dict(res: DiscrepancyResult, carry: Optional[sim.SensorModel] = None, source: str = "",
            truth: Optional[sim.SensorModel] = None) -> dict:
    start = to_sim(res.start_model, None, carry=carry)
    d = {
        "input": res.input_info,
        "metric": METRIC.format(folds=res.folds),
        "selection_rule": RULE,
        "start_model": start.to_dict(),
        "gap_initial_mg": round(res.gap_initial_mg, 4),
        "gap_final_mg": round(res.gap_final_mg, 4),
        "gap_insample_initial_mg": round(res.gap_insample_initial_mg, 4),
        "gap_insample_final_mg": round(res.gap_insample_final_mg, 4),
        "noise_floor_mg": None if res.noise_floor_mg is None else round(res.noise_floor_mg, 4),
        "noise_floor_note": ("gap of the true model (truth given) on the same windows"
                             if res.noise_floor_mg is not None else "no truth given"),
        "steps": [s.to_dict() for s in res.steps],
        "final_model": final_model(res, carry, source).to_dict(),
        "summary": summary_lines(res),
        "locate_initial": res.locate_initial,
        "locate_final": res.locate_final,
        "distributions": res.distributions,
        "candidates_last_round": [s.to_dict() for s in res.last_scores],
        "candidates_skipped": res.skipped,
    }
    if truth is not None:
        d["truth_model"] = truth.to_dict()
    return _clean(d)


def text(d: dict) -> str:
    """Plain-text report for humans (what the CLI prints without --json)."""
    L = []
    inp = d["input"]
    L.append(f"stillpoint discrepancy: {inp['source']}")
    L.append(f"  {inp['windows_nonmovement']} nonmovement windows of {inp['windows_total']} "
             f"({inp['hours']:.1f} h); temperature {'yes' if inp['temperature_available'] else 'no'}")
    sph = inp.get("sphere")
    if sph:
        L.append("  sphere coverage (min/max g per axis): " + ", ".join(
            f"{a} {lo:+.2f}/{hi:+.2f}" for a, lo, hi in zip("xyz", sph["min_g"], sph["max_g"]))
                 + ("" if sph["covered"] else "  -- NOT covered (+-0.3 g): parameters poorly constrained"))
    eff = ", ".join(d["start_model"]["effects"]) or "(none)"
    L.append(f"  start model: {eff}")
    L.append(f"  metric: {d['metric']}")
    L.append("")
    L.append("Where the start model and the data disagree (share of residual variance by covariate):")
    for row in d["locate_initial"][:6]:
        L.append(f"  {row['covariate']:<34} eta2 {row['eta2']:.3f}  corr {row['corr']:+.3f}")
    L.append("")
    if not d["steps"]:
        L.append("No effect named: no candidate reached dBIC < -10 with a lower held-out gap.")
    for i, s in enumerate(d["steps"], 1):
        L.append(f"Step {i}: {s['description']}" + ("" if s["axis"] == "all" else f" on {s['axis']}"))
        for name, p in s["parameters"].items():
            L.append(f"  {name} = {p['value']:.4g} +- {p['stderr']:.2g} {p['unit']}")
        L.append(f"  held-out gap {s['gap_before_mg']:.3f} -> {s['gap_after_mg']:.3f} mg, "
                 f"dBIC {s['delta_bic']:.1f} (n = {s['n_windows']} windows, "
                 f"{s['n_independent']:.0f} independent)")
        rb, ra = s["residual_vs_covariate_before"], s["residual_vs_covariate_after"]
        if rb["y_mean"]:
            L.append(f"  residual vs {s['covariate']}: bins {_span(rb)} mg before, {_span(ra)} mg after")
    L.append("")
    L.append(f"Held-out gap: {d['gap_initial_mg']:.3f} mg -> {d['gap_final_mg']:.3f} mg "
             f"(in-sample {d['gap_insample_initial_mg']:.3f} -> {d['gap_insample_final_mg']:.3f} mg)")
    if d.get("noise_floor_mg") is not None:
        L.append(f"Gap of the true model: {d['noise_floor_mg']:.3f} mg "
                 f"(final / true = {d['gap_final_mg'] / d['noise_floor_mg']:.3f})")
    sd = d["distributions"].get("still_window_sd_mg")
    if sd:
        L.append("Still-window SD (mg), p5 / median / p95: " + "; ".join(
            f"{ax} {v['p5']:.2f} / {v['median']:.2f} / {v['p95']:.2f}"
            + (f" (model noise {v['model_noise_mg']:.2f}: {v['verdict']})" if "verdict" in v else
               " (quantisation dominates)" if v.get("quantisation_dominates") else "")
            for ax, v in sd.items()))
        qb = {ax: v["quantisation_bias_max_mg"] for ax, v in sd.items() if "quantisation_bias_max_mg" in v}
        if qb and max(qb.values()) >= QUANTISATION_WARN_MG:
            L.append("WARNING: quantisation step " + ", ".join(
                f"{ax} {sd[ax]['quantisation_step_mg']:.1f}" for ax in qb) + " mg is not dithered by the "
                "model noise: a still window's mean can be biased by up to " + ", ".join(
                f"{ax} {b:.2f}" for ax, b in qb.items()) + " mg (depending on its orientation), which "
                "the effect library cannot name; effects named here may be quantisation artefacts "
                "(simulated AX3 packed +-8 g: the null control named an effect in 3 of 20 seeds)")
    L.append("")
    L.append("Final model: " + ", ".join(
        f"{k}" for k in d["final_model"]["effects"]))
    return "\n".join(L)


def _span(b):
    y = b["y_mean"]
    return f"{min(y):+.2f}..{max(y):+.2f}" if y else "-"


def write(res: DiscrepancyResult, out_dir, carry: Optional[sim.SensorModel] = None, source: str = "",
          truth: Optional[sim.SensorModel] = None, plots: bool = True) -> dict:
    """Write report.json, report.txt, final_model.json, windows.csv (per-window measured vs
    predicted) and the PNGs into ``out_dir``."""
    out = prepare_report_dir(out_dir)
    d = to_dict(res, carry, source, truth)
    figures = []
    if plots:
        try:
            figures = draw(res, out)
        except ImportError:
            d["figures_note"] = "matplotlib is not installed (pip install 'stillpoint[plot]'): no PNGs"
    d["figures"] = figures
    if res.data is not None:
        write_windows(res, out / "windows.csv")
        d["windows_csv"] = "windows.csv"
    for name, body in (("report.json", json.dumps(d, indent=1)),
                       ("final_model.json", json.dumps(d["final_model"], indent=2)),
                       ("report.txt", text(d))):
        with atomic_output(out / name, binary=False, what="report") as f:
            f.write(body + "\n")
    return d


def prepare_report_dir(out_dir) -> Path:
    """The report folder, created if needed; an ``OutputError`` naming it when it cannot be
    (a file in the way, read-only parent, full disk). Call before the work starts."""
    out = Path(out_dir)
    try:
        os.fsencode(str(out))
        out.mkdir(parents=True, exist_ok=True)
    except UnicodeError:
        raise OutputError(out, "report folder name cannot be encoded on this system") from None
    except OSError as e:
        raise OutputError(out, f"cannot create the report folder: {describe_os_error(e)}") from None
    check_output_path(out / "report.json", what="report")
    return out


def write_windows(res: DiscrepancyResult, path) -> None:
    """Per nonmovement window: measured mean, what the start and final models say the sensor
    should have read, and the norm residual under each (g, mg)."""
    from .discrepancy import per_window
    w = per_window(res)
    cols = [w["t_days"], w["temperature"], *w["measured"].T, *w["predicted_start"].T,
            *w["predicted_final"].T, w["residual_start_mg"], w["residual_final_mg"]]
    header = ("t_days,temperature,meanx,meany,meanz,start_x,start_y,start_z,final_x,final_y,"
              "final_z,residual_start_mg,residual_final_mg")
    with atomic_output(path, binary=False, what="report") as f:
        np.savetxt(f, np.column_stack(cols), delimiter=",", header=header, comments="", fmt="%.7g")


def _covariate_label(name: str) -> str:
    """Axis label with units for a locate covariate (``u_*``: components of the unit gravity
    vector, unitless)."""
    if "(" in name:
        return name
    u = name.split(" ")[0]
    if "temperature" in name:
        return f"{u} * (T - T_ref) (degC)"
    if "time" in name:
        return f"{u} * time (days)"
    return f"{name} (unitless)"


def draw(res: DiscrepancyResult, out: Path) -> List[str]:
    """PNG per step (residual vs the naming covariate, before and after) and one overview."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = []
    for i, s in enumerate(res.steps, 1):
        fig, axes = plt.subplots(1, 2, figsize=(10, 4), sharey=True)
        for ax, pts, curve, title in ((axes[0], s.plot_before, s.curve_before, "before"),
                                      (axes[1], s.plot_after, s.curve_after, "after")):
            ax.plot(pts["x"], pts["y"], ".", ms=1.5, alpha=0.3, color="0.5")
            if curve["y_mean"]:
                ax.errorbar(curve["x_mid"], curve["y_mean"], yerr=np.array(curve["y_se"]) * 2,
                            fmt="o-", color="C3", ms=4, capsize=2,
                            label="mean of 10 equal-count bins, +- 2 standard errors")
            ax.axhline(0, color="k", lw=0.8)
            ax.set_xlabel(pts["xlabel"])
            ax.set_title(f"{title}: held-out gap "
                         f"{s.gap_before_mg if title == 'before' else s.gap_after_mg:.3f} mg")
            ax.legend(loc="best", fontsize=8)
        axes[0].set_ylabel(s.plot_before["ylabel"])
        lo, hi = np.percentile(np.concatenate([s.plot_before["y"], s.plot_after["y"]]), [1, 99])
        axes[0].set_ylim(lo - 0.2 * (hi - lo), hi + 0.2 * (hi - lo))
        c = s.candidate
        fig.suptitle(f"step {i}: {c.effect}" + ("" if c.component == "all" else f" [{c.component}]"))
        fig.tight_layout()
        name = f"step{i}_{c.effect}_{c.component}.png"
        save_figure(fig, out / name, dpi=90, fmt="png")
        plt.close(fig)
        names.append(name)
    rows = [r for r in res.locate_initial if r["bins"]["y_mean"]][:9]
    if rows:
        fig, axes = plt.subplots(3, 3, figsize=(11, 9.5), sharey=True)
        for ax, r in zip(axes.ravel(), rows):
            b = r["bins"]
            ax.errorbar(b["x_mid"], b["y_mean"], yerr=np.array(b["y_se"]) * 2, fmt="o-", ms=3,
                        capsize=2)
            ax.axhline(0, color="k", lw=0.8)
            ax.set_title(f"{r['covariate']}: eta2 {r['eta2']:.2f}", fontsize=9)
            ax.set_xlabel(_covariate_label(r["covariate"]), fontsize=8)
            ax.tick_params(labelsize=7)
        for ax in axes.ravel()[len(rows):]:
            ax.axis("off")
        for i in range(3):
            axes[i, 0].set_ylabel("mean ||a|| - 1 (mg)", fontsize=8)
        fig.suptitle("Where the start model misses: residual of the nonmovement windows (start model) "
                     "against each covariate.\nPoints: mean residual in 10 equal-count bins of the "
                     "covariate; bars: +- 2 standard errors of that mean; eta2: share of the residual's "
                     "variance the bin means explain.\nu_x, u_y, u_z: components of the unit gravity vector.",
                     fontsize=9)
        fig.tight_layout(rect=(0, 0, 1, 0.91))
        save_figure(fig, out / "locate_initial.png", dpi=80, fmt="png")
        plt.close(fig)
        names.append("locate_initial.png")
    return names
