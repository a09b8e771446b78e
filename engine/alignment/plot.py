"""Alignment figure: lag against time with the fitted model, its 95 % confidence band, the excluded
blocks, lag steps and sampling halts (Brønd et al. 2021, Fig. 3), and the normalised
cross-correlation of the blocks used (their Fig. 2). Points outside the drawn lag range are
counted as off-scale in the legend; the drift is reported over the recording's own span (never
extrapolated past it).

matplotlib is optional (``pip install stillpoint[plot]``) and imported only when plotting.
"""

from __future__ import annotations

import numpy as np

from stillpoint.engine.core.errors import StillpointError

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
    else:
        t_used = np.array([_t(b, result) / 3600 for b in valid])
        y_used = np.array([b.lag / rate for b in valid])
        t_exc = y_exc = np.zeros(0)
    ylim = None
    if fit is not None:
        span = max(result.ref_span_s[1], 3600.0)
        tt = np.linspace(0, span, 2000)
        lo_y = np.concatenate([y_used, fit.offset_s(tt)]) if y_used.size else fit.offset_s(tt)
        pad = 0.1 * max(np.ptp(lo_y), 1.0 / rate)
        ylim = (lo_y.min() - pad, lo_y.max() + pad)

    def off(y):
        return 0 if ylim is None else int(((y < ylim[0]) | (y > ylim[1])).sum())

    def label(text, y):
        k = off(np.asarray(y))
        return f"{text} ({len(y)}{f', {k} off-scale' if k else ''})"

    if fit is not None and other:
        y_oth = np.array([b.lag / rate for b in other])
        ax1.plot([_t(b, result) / 3600 for b in other], y_oth, ".", color="0.7", ms=3,
                 label=label("not used, low correlation", y_oth))
    ax1.plot(t_used, y_used, "o", ms=4, color="tab:blue", label=label("block lag, used", y_used))
    if t_exc.size:
        ax1.plot(t_exc, y_exc, "x", ms=6, color="tab:red", label=label("excluded", y_exc))
    if fit is not None:
        ax1.plot(tt / 3600, fit.offset_s(tt), "-", color="k", lw=1.2, label=f"fit ({fit.model})")
        band = _band(fit, tt)
        if band is not None:
            ax1.fill_between(tt / 3600, fit.offset_s(tt) - band, fit.offset_s(tt) + band,
                             color="k", alpha=0.15, lw=0, label="95 % confidence band")
        for s in fit.steps:
            ax1.axvspan(s.window_s[0] / 3600, s.window_s[1] / 3600, color="orange", alpha=0.3,
                        label=f"lag step {s.size / rate:+.2f} s (clock stopped)")
        ax1.set_ylim(*ylim)
        days = span / 86400.0
        change = float(fit.offset_s(span) - fit.offset_s(0.0))
        title = (f"offset {fit.initial_offset_s:+.3f} s, drift {fit.drift_s_per_day:+.3f} s/day, "
                 f"change over the {days:.1f}-day record {change:+.2f} s")
    else:
        title = "not aligned: " + result.reason[:80]
    first = True
    for dev, gaps in (result.gaps or {}).items():
        for a, b in gaps:
            if dev == "other" and fit is not None:
                a, b = a - float(fit.offset_s(a)), b - float(fit.offset_s(b))
            who = "reference" if dev == "ref" else "other device"
            ax1.axvspan(a / 3600, max(b, a + 60.0) / 3600, color="tab:purple", alpha=0.35,
                        label=(f"sampling halt / gap ({who})" if first else None))
            first = False
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
    from stillpoint.engine.core.figures import save_figure
    save_figure(fig, path, dpi=110)
    plt.close(fig)
    return str(path)


def _band(fit, tt, level: float = 0.95):
    """Half-width (s) of the confidence band of the linear part of the clock model (the same
    rule as the fit's intervals: ``ClockFit.halfwidth``)."""
    if fit.cov is None or fit.dof <= 0:
        return None
    g = np.zeros(fit.cov.shape[0])
    out = np.empty(len(tt))
    for i, x in enumerate(tt):
        g[0], g[1] = 1.0, float(x)
        out[i] = fit.halfwidth(g, level)
    return out / fit.rate


def _t(b, result):
    if result.fit is not None and result.fit.diagnostics.get("block_time") == "start":
        return b.start_s
    if result.fit is not None and result.fit.diagnostics.get("block_time") == "centroid" \
            and np.isfinite(b.centroid_s):
        return b.centroid_s
    return b.centre_s
