"""Calibration report figure (van Hees 2014 Fig. 1 style): the nonmovement window means before and
after calibration in 3-D and in the three 2-D projections with the 1 g circle, plus the residual
(||cal|| - 1) against temperature. matplotlib is an optional extra (``pip install
stillpoint[plot]``), imported only when a plot is requested.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from stillpoint.drivers.errors import StillpointError

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
                     title: str = "", max_points: int = 20000) -> Path:
    """Write the figure to ``path`` (PNG, or any format matplotlib infers from the suffix)."""
    plt = _pyplot()
    path = Path(path)
    w = windows
    if len(w) > max_points:  # a readable figure; thin deterministically
        w = w.select(np.linspace(0, len(w) - 1, max_points).astype(np.int64))
    before = w.mean
    after = _calibrated(w, estimate) if len(w) else before
    fig = plt.figure(figsize=(15, 9.5))
    head = title or (estimate.device_key or "calibration")
    fig.suptitle(f"{head}: {estimate.status} - {estimate.reason}", fontsize=9, wrap=True)
    kw_b = dict(s=4, c="0.6", alpha=0.5, label="before")
    kw_a = dict(s=4, c="tab:blue", alpha=0.6, label="after")
    # 3-D views
    u, v = np.mgrid[0:2 * np.pi:40j, 0:np.pi:20j]
    for i, (pts, name) in enumerate(((before, "before"), (after, "after"))):
        ax = fig.add_subplot(2, 4, 1 + i, projection="3d")
        ax.plot_wireframe(np.cos(u) * np.sin(v), np.sin(u) * np.sin(v), np.cos(v), color="0.85",
                          linewidth=0.4)
        if len(pts):
            ax.scatter(pts[:, 0], pts[:, 1], pts[:, 2], s=2,
                       c="0.4" if name == "before" else "tab:blue")
        ax.set_title(f"{name} (3-D)", fontsize=9)
        ax.set_xlabel("x (g)")
        ax.set_ylabel("y (g)")
        ax.set_zlabel("z (g)")
    # residual vs temperature
    ax = fig.add_subplot(2, 4, 3)
    if len(w) and np.any(np.isfinite(w.temperature)):
        ax.scatter(w.temperature, (np.linalg.norm(before, axis=1) - 1) * 1000, **kw_b)
        ax.scatter(w.temperature, (np.linalg.norm(after, axis=1) - 1) * 1000, **kw_a)
        ax.set_xlabel("temperature (degC)")
    else:
        ax.text(0.5, 0.5, "no temperature", ha="center", va="center", transform=ax.transAxes)
    ax.axhline(0, color="k", linewidth=0.6)
    ax.set_ylabel("||a|| - 1 (mg)")
    ax.set_title("residual vs temperature", fontsize=9)
    ax.legend(fontsize=8, markerscale=3)
    # numbers
    ax = fig.add_subplot(2, 4, 4)
    ax.axis("off")
    lines = [f"status: {estimate.status}", f"method: {estimate.method}",
             f"windows: {estimate.windows}",
             f"error: {_fmt(estimate.error_before_mg)} -> {_fmt(estimate.error_after_mg)} mg"]
    for k, ax_name in enumerate("xyz"):
        lines.append(f"{ax_name}: offset {estimate.offset[k] * 1000:+.2f} mg, "
                     f"scale {estimate.scale[k]:.5f}, "
                     f"T {estimate.tempoffset[k] * 1000:+.3f} mg/degC")
    lines.append(f"T_ref {estimate.temperature_ref:.2f} degC")
    ax.text(0, 1, "\n".join(lines), va="top", family="monospace", fontsize=8)
    # 2-D projections with the 1 g circle
    th = np.linspace(0, 2 * np.pi, 361)
    for j, (a, b) in enumerate(((0, 1), (0, 2), (1, 2))):
        ax = fig.add_subplot(2, 4, 5 + j)
        ax.plot(np.cos(th), np.sin(th), color="k", linewidth=0.6)
        ax.scatter(before[:, a], before[:, b], **kw_b)
        ax.scatter(after[:, a], after[:, b], **kw_a)
        ax.set_aspect("equal")
        ax.set_xlim(-1.2, 1.2)
        ax.set_ylim(-1.2, 1.2)
        ax.set_xlabel(f"{'xyz'[a]} (g)")
        ax.set_ylabel(f"{'xyz'[b]} (g)")
        ax.set_title(f"{'xyz'[a]}-{'xyz'[b]} projection", fontsize=9)
    ax = fig.add_subplot(2, 4, 8)
    if len(w):
        bins = np.linspace(-30, 30, 61)
        ax.hist((np.linalg.norm(before, axis=1) - 1) * 1000, bins=bins, color="0.6", alpha=0.6,
                label="before")
        ax.hist((np.linalg.norm(after, axis=1) - 1) * 1000, bins=bins, color="tab:blue",
                alpha=0.6, label="after")
    ax.set_xlabel("||a|| - 1 (mg)")
    ax.set_title("distance to the 1 g sphere", fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout(rect=(0, 0, 1, 0.95))
    from ..plotfile import save_figure
    try:
        save_figure(fig, path, dpi=110)
    finally:
        plt.close(fig)
    return path


def _fmt(v) -> str:
    return "n/a" if v is None else f"{v:.2f}"
