"""Alignment figure: lag against time with the fitted model and the excluded blocks (Brønd et al.
2021, Fig. 3), and the normalised cross-correlation of the blocks used (their Fig. 2).

matplotlib is optional (``pip install stillpoint[plot]``) and imported only when plotting.
"""

from __future__ import annotations

import numpy as np

from stillpoint.drivers.errors import StillpointError

from .operator import AlignmentResult


def plot_alignment(result: AlignmentResult, path, max_correlograms: int = 40) -> str:
    """Write the two-panel figure to ``path`` (PNG, SVG or PDF by extension); returns path."""
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:  # pragma: no cover - depends on the environment
        raise StillpointError("--plot needs matplotlib: pip install 'stillpoint[plot]'") from None
    rate = result.config.rate
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(13, 4.8), gridspec_kw={"width_ratios": [3, 2]})
    valid = [b for b in result.blocks if b.valid]
    fit = result.fit
    excluded = set()
    if fit is not None:
        # the lags the fit saw (robust: the consensus-chosen peak of blocks passing its gates)
        inc = fit.included
        excluded = {int(i) for i, k in zip(fit.block_index, inc) if not k}
        t_used, y_used = fit.t[inc] / 3600, fit.y[inc] / rate
        t_exc, y_exc = fit.t[~inc] / 3600, fit.y[~inc] / rate
        seen = set(int(i) for i in fit.block_index)
        other = [b for b in valid if b.index not in seen]
        if other:
            ax1.plot([_t(b, result) / 3600 for b in other], [b.lag / rate for b in other], ".",
                     color="0.7", ms=3, label=f"not used (low correlation, {len(other)})")
    else:
        t_used = np.array([_t(b, result) / 3600 for b in valid])
        y_used = np.array([b.lag / rate for b in valid])
        t_exc = y_exc = np.zeros(0)
    ax1.plot(t_used, y_used, "o", ms=4, color="tab:blue", label=f"block lag ({t_used.size} used)")
    if t_exc.size:
        ax1.plot(t_exc, y_exc, "x", ms=6, color="tab:red", label=f"excluded ({t_exc.size})")
    if fit is not None:
        span = max(result.ref_span_s[1], 3600.0)
        tt = np.linspace(0, span, 2000)
        ax1.plot(tt / 3600, fit.offset_s(tt), "-", color="k", lw=1.2, label=f"fit ({fit.model})")
        for s in fit.steps:
            ax1.axvspan(s.window_s[0] / 3600, s.window_s[1] / 3600, color="orange", alpha=0.3,
                        label=f"step {s.size / rate:+.2f} s")
        lo_y = np.concatenate([y_used, fit.offset_s(tt)]) if y_used.size else fit.offset_s(tt)
        pad = 0.1 * max(np.ptp(lo_y), 1.0 / rate)
        ax1.set_ylim(lo_y.min() - pad, lo_y.max() + pad)
        title = (f"offset {fit.initial_offset_s:+.3f} s, drift {fit.drift_s_per_day:+.3f} s/day, "
                 f"day 7 {fit.drift_day7_s:+.2f} s")
    else:
        title = "not aligned: " + result.reason[:80]
    ax1.set_title(title, fontsize=10)
    ax1.set_xlabel("time since reference start (h)")
    ax1.set_ylabel("lag of other device (s)")
    ax1.grid(alpha=0.3)
    ax1.legend(fontsize=8, loc="best")
    # correlograms of the blocks used
    fitted = set(int(i) for i in fit.block_index) if fit is not None else {b.index for b in valid}
    used = [b for b in valid if b.correlogram is not None and b.index in fitted
            and b.index not in excluded]
    if len(used) > max_correlograms:
        used = [used[i] for i in np.linspace(0, len(used) - 1, max_correlograms).astype(int)]
    if used:
        M = (used[0].correlogram.size - 1) // 2
        step = used[0].correlogram_step
        lags = np.arange(-M, M + 1) * step / rate
        cmap = plt.get_cmap("viridis")
        for i, b in enumerate(used):
            ax2.plot(lags, b.correlogram, lw=0.7, color=cmap(i / max(len(used) - 1, 1)))
        peaks = np.array([b.lag / rate for b in used])
        ax2.set_xlim(max(-M * step / rate, peaks.min() - 15.0),
                     min(M * step / rate, peaks.max() + 15.0))
        ax2.set_xlabel("lag (s)")
        ax2.set_ylabel("normalised cross-correlation")
        ax2.set_title(f"{len(used)} blocks used (colour: time)", fontsize=10)
        ax2.grid(alpha=0.3)
    else:
        ax2.text(0.5, 0.5, "no correlograms", ha="center", va="center", transform=ax2.transAxes)
    fig.tight_layout()
    from ..plotfile import save_figure
    try:
        save_figure(fig, path, dpi=110)
    finally:
        plt.close(fig)
    return str(path)


def _t(b, result):
    if result.fit is not None and result.fit.diagnostics.get("block_time") == "start":
        return b.start_s
    if result.fit is not None and result.fit.diagnostics.get("block_time") == "centroid" \
            and np.isfinite(b.centroid_s):
        return b.centroid_s
    return b.centre_s
