"""What the online calibrator's refits cost, and what the fit set changes, on simulated wear.

    python tools/benchmarks/bench_refits.py [--days 7] [--wearers default,still] [--per-cell 16]

For each wearer (``benchlib.realistic_recording``: ``stillpoint simulate --wearer NAME``, AX3
wrist, 100 Hz, seed 3) the window features are computed once, as ``process --mode online``
computes them (the window-features operator with the run's defaults, the counts' quantisation
step included), and then
fed to ``OnlineCalibrator`` twice, in this process: with every nonmovement window in every refit
(``per_cell=None``, the rule before the fit set) and with the fit set (``--per-cell``, default
``online.FIT_PER_CELL``). Printed per run: the CPU of the refits (``time.process_time``, least
of ``--repeat``), the fit set's size, and per estimate the largest difference of the corrected
acceleration between the two runs (mg, over 2,000 directions at the recording's window
temperatures) and each estimate's RMS error against the simulator's truth (gain, offset and
temperature offset of the truth JSON).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from benchlib import realistic_recording


def window_features(path: Path) -> list:
    """[(features, counts' step or None)] in stream order, as an online run hands them to its
    calibrator: the window-features operator over the reader's blocks, with the run's default
    settings, and the counts' step known so far."""
    from stillpoint.drivers import open_recording
    from stillpoint.engine.calibration.trust import CountStep
    from stillpoint.engine.operators.windows import WindowFeaturesOperator
    from stillpoint.engine.settings import RunSettings

    s = RunSettings(mode="online")
    out: list = []
    step = CountStep()
    with open_recording(path) as src:
        op = WindowFeaturesOperator(float(src.info.sample_rate_nominal), s.window_s, s.min_fill)
        for block in src:
            step.push(block)
            f = op.push(block)
            if len(f):
                out.append((f, step.step_g))
        f = op.flush()
        if len(f):
            out.append((f, step.step_g))
    return out


class _Step:
    step_g = None


def replay(stream: list, per_cell) -> tuple:
    """(estimates, refit CPU s, fit set size, windows) of one calibrator over the stream."""
    from stillpoint.engine.calibration.online import OnlineCalibrator

    step = _Step()
    cal = OnlineCalibrator(None, per_cell=per_cell, count_step=step)
    inner = cal._refit
    spent = [0.0]

    def timed(*a, **k):
        t = time.process_time()
        try:
            return inner(*a, **k)
        finally:
            spent[0] += time.process_time() - t

    cal._refit = timed
    ests = []
    for f, s in stream:
        step.step_g = s
        ests += cal.add(f)
    ests += cal.finish()
    return ests, spent[0], len(cal.fit_windows), len(cal.windows), cal.windows.temperature


def _directions(temps: np.ndarray, seed: int):
    rng = np.random.default_rng(seed)
    u = rng.normal(size=(2000, 3))
    u /= np.linalg.norm(u, axis=1)[:, None]
    t = temps[np.isfinite(temps)]
    return u, (rng.choice(t, 2000) if t.size else np.full(2000, 25.0))


def corrected(est, x: np.ndarray, temps: np.ndarray) -> np.ndarray:
    from stillpoint.engine.calibration.fit import apply_model
    tc = temps - est.temperature_ref if est.uses_temperature else None
    return apply_model(x, tc, est.offset, est.scale, est.tempoffset)


def truth_rms_mg(est, truth: dict, u: np.ndarray, temps: np.ndarray) -> float:
    """RMS of corrected - true over the directions, raw made by the truth's gain, offset and
    temperature offset (the default sensor model's calibration errors)."""
    m = truth["sensor_model"]["effects"]
    g = np.array([m["gain"][f"{a}_pct"] for a in "xyz"]) / 100.0
    o = np.array([m["offset"][f"{a}_mg"] for a in "xyz"]) / 1000.0
    k = np.array([m["temperature_offset"][f"{a}_mg_per_c"] for a in "xyz"]) / 1000.0
    raw = u * (1.0 + g) + o + k * (temps - m["temperature_offset"]["reference_c"])[:, None]
    return float(np.sqrt(np.mean(np.sum((corrected(est, raw, temps) - u) ** 2, axis=1))) * 1000)


def main(argv=None) -> int:
    from stillpoint.engine.calibration.online import FIT_PER_CELL

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--days", default="7", help="lengths in days, comma-separated")
    ap.add_argument("--rate", type=float, default=100.0)
    ap.add_argument("--wearers", default="default,still")
    ap.add_argument("--per-cell", type=int, default=FIT_PER_CELL)
    ap.add_argument("--repeat", type=int, default=2, help="replays of each rule (least CPU kept)")
    ap.add_argument("--workdir", default=os.path.join(tempfile.gettempdir(), "stillpoint_bench"))
    a = ap.parse_args(argv)
    wd = Path(a.workdir)
    wd.mkdir(parents=True, exist_ok=True)
    for w in [x.strip() for x in a.wearers.split(",") if x.strip()]:
        for d in [float(x) for x in a.days.split(",") if x.strip()]:
            path = realistic_recording(wd, d, a.rate, wearer=w)
            truth = json.loads(path.with_suffix(".truth.json").read_text())
            stream = window_features(path)
            runs = {}
            for rule in (None, a.per_cell):
                best = None
                for _ in range(max(1, a.repeat)):
                    r = replay(stream, rule)
                    if best is None or r[1] < best[1]:
                        best = r
                runs[rule] = best
            every, capped = runs[None], runs[a.per_cell]
            u, temps = _directions(every[4], 0)
            print(f"{w} wearer, {d:g} days ({path.name}): {every[3]:,} nonmovement windows, "
                  f"{len(every[0])} estimates")
            print(f"  refits, every window:        {every[1]:6.2f} CPU-s")
            print(f"  refits, fit set ({a.per_cell} a cell):   {capped[1]:6.2f} CPU-s "
                  f"({capped[1] / max(every[1], 1e-9):.2f}x), fit set {capped[2]:,} windows "
                  f"({capped[2] / max(capped[3], 1):.1%})")
            diffs = [float(np.abs(corrected(x, u, temps) - corrected(y, u, temps)).max() * 1000)
                     for x, y in zip(every[0], capped[0])]
            print("  |corrected, fit set - every window| max per estimate (mg): "
                  + " ".join(f"{v:.3f}" for v in diffs))
            for label, run in (("every window", every), ("fit set", capped)):
                print(f"  RMS error against the truth, {label:12s} (mg): "
                      + " ".join(f"{truth_rms_mg(e, truth, u, temps):.3f}" for e in run[0]))
            acc = [sum(bool(e.extra.get("accepted")) for e in r[0]) for r in (every, capped)]
            print(f"  accepted: {acc[0]} of {len(every[0])} (every window), "
                  f"{acc[1]} of {len(capped[0])} (fit set)", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
