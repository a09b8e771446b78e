"""Calibration report figure: the nonmovement windows' distance to the 1 g sphere (||a|| - 1, mg)
before and after calibration against each axis, against temperature, and as a histogram, with the
estimate's numbers. matplotlib is an optional extra (``pip install
stillpoint[plot]``), imported only when a plot is requested.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from stillpoint.engine.core.errors import StillpointError

from ..features import WindowFeatures
from .estimate import CalibrationEstimate


class PlotUnavailableError(StillpointError):
    """matplotlib is not installed."""


def _pyplot():
    try:
        import matplotlib
    except ImportError:
        raise PlotUnavailableError(
            "--plot needs matplotlib, an optional extra: pip install 'stillpoint[plot]'") from None
    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


def _calibrated(windows: WindowFeatures, est: CalibrationEstimate) -> np.ndarray:
    if est.uses_temperature:
        t = np.where(np.isfinite(windows.temperature), windows.temperature, est.temperature_ref)
        return est.apply(windows.mean, t)
    return est.apply(windows.mean)


def plot_calibration(windows: WindowFeatures, estimate: CalibrationEstimate, path,
                     title: str = "", max_points: int = 20000, hist_range_mg: float = 30.0) -> Path:
    """Write the figure to ``path`` (PNG, or any format matplotlib infers from the suffix).

    The sphere is shown where the calibration acts, at mg scale: the residual ``||a|| - 1``
    against each axis's mean value (one panel per axis; at g scale before and after look the
    same), against temperature, and as a histogram whose end bins hold every window beyond
    ``hist_range_mg`` (their number is in the legend: nothing is dropped)."""
    import textwrap

    from stillpoint.engine.core.figures import save_figure
    from stillpoint.engine.core.outputs import check_output_path
    plt = _pyplot()
    path = check_output_path(path, what="plot")
    w = windows
    thinned = len(w) > max_points
    if thinned:  # a readable figure; thin deterministically
        w = w.select(np.linspace(0, len(w) - 1, max_points).astype(np.int64))
    before = w.mean
    applied = estimate.applied
    after = _calibrated(w, estimate) if len(w) else before
    rb = (np.linalg.norm(before, axis=1) - 1) * 1000 if len(w) else np.zeros(0)
    ra = (np.linalg.norm(after, axis=1) - 1) * 1000 if len(w) else np.zeros(0)
    lab_a = "after" if applied else f"with the fit (not applied: {estimate.status})"
    fig = plt.figure(figsize=(13, 8.5))
    head = title or (estimate.device_key or "calibration")
    fig.suptitle("\n".join(textwrap.wrap(f"{head}: {estimate.status} - {estimate.reason}", 150)[:3]),
                 fontsize=9)
    kw_b = dict(s=5, c="0.55", alpha=0.5, lw=0, label="before")
    kw_a = dict(s=5, c="tab:blue", alpha=0.6, lw=0, label=lab_a)
    lim = max(15.0, float(np.percentile(np.abs(np.concatenate([rb, ra])), 99.5)) * 1.1) if len(w) else 30.0
    for j, name in enumerate("xyz"):
        ax = fig.add_subplot(2, 3, 1 + j)
        if len(w):
            ax.scatter(before[:, j], rb, **kw_b)
            ax.scatter(after[:, j], ra, **kw_a)
        ax.axhline(0, color="k", linewidth=0.6)
        ax.set_xlim(-1.15, 1.15)
        ax.set_ylim(-lim, lim)
        ax.set_xlabel(f"mean {name} of the window (g)")
        ax.set_ylabel("||a|| - 1 (mg)")
        ax.set_title(f"distance to the 1 g sphere against {name}", fontsize=9)
        if j == 0 and len(w):
            ax.legend(fontsize=7.5, markerscale=2.5, loc="lower left")
    # residual vs temperature
    ax = fig.add_subplot(2, 3, 4)
    if len(w) and np.any(np.isfinite(w.temperature)):
        ax.scatter(w.temperature, rb, **kw_b)
        ax.scatter(w.temperature, ra, **kw_a)
        ax.set_xlabel("temperature (degC)")
        ax.set_ylim(-lim, lim)
    else:
        ax.text(0.5, 0.5, "no temperature", ha="center", va="center", transform=ax.transAxes)
    ax.axhline(0, color="k", linewidth=0.6)
    ax.set_ylabel("||a|| - 1 (mg)")
    ax.set_title("residual against temperature", fontsize=9)
    # histogram: values beyond the range go to the end bins and are counted
    ax = fig.add_subplot(2, 3, 5)
    r = float(hist_range_mg)
    bins = np.linspace(-r, r, 61)
    for vals, color, lab in ((rb, "0.6", "before"), (ra, "tab:blue", lab_a)):
        if not len(vals):
            continue
        off = int((np.abs(vals) > r).sum())
        ax.hist(np.clip(vals, -r, r), bins=bins, color=color, alpha=0.6,
                label=f"{lab}: RMS {np.sqrt(np.mean(vals ** 2)):.2f} mg"
                      + (f"; {off} beyond +-{r:g} mg, in the end bins" if off else ""))
    ax.set_xlabel("||a|| - 1 (mg)")
    ax.set_ylabel("windows")
    ax.set_ylim(top=ax.get_ylim()[1] * 1.3)  # room for the legend above the bars
    ax.set_title(f"distance to the 1 g sphere ({len(w):,} windows"
                 + (f", thinned from {len(windows):,}" if thinned else "") + ")", fontsize=9)
    if len(w):
        ax.legend(fontsize=7, loc="upper left")
    # numbers
    ax = fig.add_subplot(2, 3, 6)
    ax.axis("off")
    lines = [f"status: {estimate.status} ({'applied' if applied else 'not applied'})",
             f"method: {estimate.method}", f"windows: {estimate.windows}",
             f"error: {_fmt(estimate.error_before_mg)} -> {_fmt(estimate.error_after_mg)} mg"]
    for k, ax_name in enumerate("xyz"):
        line = f"{ax_name}: offset {estimate.offset[k] * 1000:+.2f} mg, scale {estimate.scale[k]:.5f}"
        if estimate.uses_temperature:
            line += f", {estimate.tempoffset[k] * 1000:+.3f} mg/degC"
        lines.append(line)
    if estimate.uses_temperature:
        lines.append(f"T_ref {estimate.temperature_ref:.2f} degC")
    else:
        lines.append("no temperature term")
    ax.text(0, 1, "\n".join(lines), va="top", family="monospace", fontsize=8.5)
    fig.tight_layout(rect=(0, 0, 1, 0.94))
    save_figure(fig, path, dpi=110)
    plt.close(fig)
    return path


def _fmt(v) -> str:
    return "n/a" if v is None else f"{v:.2f}"
