"""Figure of one or two legs' movement detection: the detrended acceleration norm with both
thresholds and the detected movements shaded (a window of the recording, default the first
60 s with movements). matplotlib is an optional extra, imported only here.
"""

from __future__ import annotations


def plot_movements(legs, path, *, seconds: float = 60.0) -> None:
    """``legs``: [(label, LegResult, LegSignals, detector output dict)]; PNG to ``path``."""
    from stillpoint.engine.core.figures import save_figure
    from stillpoint.engine.calibration.plot import _pyplot
    plt = _pyplot()
    fig, axes = plt.subplots(len(legs), 1, figsize=(11, 3.6 * len(legs)), squeeze=False)
    for ax, (label, res, sig, det) in zip(axes[:, 0], legs):
        a = det["a"]
        t = (sig.time_ns - sig.time_ns[0]) / 1e9
        t0 = t[res.movements[0, 0]] - 2.0 if res.count else 0.0
        sel = (t >= t0) & (t < t0 + seconds)
        ax.plot(t[sel], a[sel], lw=0.7, color="tab:purple", label="detrended |a| (m/s²)")
        if det.get("w") is not None:
            ax.plot(t[sel], det["w"][sel], lw=0.5, color="tab:cyan", alpha=0.7,
                    label="detrended |ω| (rad/s)")
        ax.axhline(res.thresholds["positive"], color="k", ls=":", lw=0.8, label="thresholds")
        ax.axhline(res.thresholds["negative"], color="k", ls=":", lw=0.8)
        ax.axhline(0, color="r", lw=0.5)
        for s, _, e in res.movements:
            if t[s] >= t0 and t[e] < t0 + seconds:
                ax.axvspan(t[s], t[e], color="tab:green", alpha=0.25, lw=0)
        ax.set_title(f"{label}: {res.device_key}, {res.count} movements, "
                     f"{res.rate.per_hour_awake if res.rate.per_hour_awake is not None else float('nan'):.0f}"
                     f" per hour awake (variant {res.variant}, filter {res.filter})", fontsize=10)
        ax.set_xlabel("time from start (s)")
        ax.legend(loc="upper right", fontsize=7)
    fig.tight_layout()
    save_figure(fig, path, dpi=90, fmt="png")
    plt.close(fig)
