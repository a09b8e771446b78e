"""Figure of a six-orientation calibration: the recording (three axes, in g) with the six face
windows shaded and labelled, and each face's gravity-axis reading before and after the
correction (ideal ±1 g). matplotlib is an optional extra, imported only here.
"""

from __future__ import annotations

import numpy as np

from .plot import _pyplot
from .sixface import FACES
from .static import StaticCalibration


def plot_static_calibration(time_ns: np.ndarray, acc_g: np.ndarray, cal: StaticCalibration, path) -> None:
    """Write the figure as PNG to ``path`` (atomically)."""
    from stillpoint.engine.core.figures import save_figure
    plt = _pyplot()
    t = (np.asarray(time_ns, np.int64) - int(time_ns[0])) / 1e9 if len(time_ns) else np.zeros(0)
    fig, (ax, bx) = plt.subplots(2, 1, figsize=(11, 7), gridspec_kw={"height_ratios": [2, 1]})
    for k, (name, col) in enumerate(zip("xyz", ("tab:red", "tab:green", "tab:blue"))):
        ax.plot(t, acc_g[:, k], color=col, lw=0.8, label=name)
    before, after = [], []
    corrected = cal.apply(acc_g)
    for f in FACES:
        info = cal.faces.get(f, {})
        k = "xyz".index(f[1])
        if not info.get("samples"):
            before.append(np.nan)
            after.append(np.nan)
            continue
        a, b = int(info["start_index"]), int(info["end_index"])
        ax.axvspan(t[a], t[b], color="0.85", zorder=0)
        ax.text((t[a] + t[b]) / 2, 1.25, f, ha="center", fontsize=9)
        before.append(float(np.mean(acc_g[a:b + 1, k])))
        after.append(float(np.mean(corrected[a:b + 1, k])))
    ax.set_ylim(-1.5, 1.5)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("acceleration (g)")
    ax.legend(loc="lower right", ncol=3, fontsize=8)
    ax.set_title(f"{cal.device_key or 'device'}: six-orientation calibration ({cal.mode} mode, "
                 f"{cal.status})")
    x = np.arange(len(FACES))
    ideal = np.array([1.0 if f[0] == "+" else -1.0 for f in FACES])
    bx.bar(x - 0.2, (np.array(before) - ideal) * 1000, 0.4, label="before")
    bx.bar(x + 0.2, (np.array(after) - ideal) * 1000, 0.4, label="after")
    bx.axhline(0, color="k", lw=0.6)
    bx.set_xticks(x, FACES)
    bx.set_ylabel("gravity-axis reading - (±1 g) (mg)")
    bx.legend(fontsize=8)
    fig.tight_layout()
    save_figure(fig, path, dpi=90, fmt="png")
    plt.close(fig)
