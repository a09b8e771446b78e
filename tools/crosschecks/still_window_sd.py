"""Still-window SDs of recordings: how much a device at rest varies within a 10 s window.

    python tools/crosschecks/still_window_sd.py FILE [FILE ...]

For each file: the quantisation step of the stored counts and the percentiles (5, 25, 50, 75, 95)
per axis of the SD of the still windows (SD < 13 mg on every axis, |mean| < 2 g: the windows the
autocalibration uses). For a simulated file with its ``<name>.labels.csv`` beside it, the still
windows are split into worn (sleep, lying, sitting, standing) and nonwear (table, drawer) by the
truth labels. This is the check of the simulator's still-segment micro-motion
(``WearerParams.still_micromotion_mg``) against real recordings (shared/data/real): the SD of a
quantised window is what decides whether its mean is biased by the step.
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import numpy as np

from stillpoint.drivers import open_recording
from stillpoint.engine.calibration.trust import CountStep
from stillpoint.engine.features import WindowFeatures
from stillpoint.engine.operators.windows import WindowFeaturesOperator
from stillpoint.engine.sim.wearer import A

WORN = (A["sleep"], A["lying"], A["sitting"], A["standing"])
PCT = (5, 25, 50, 75, 95)


def features(path: str):
    with open_recording(path) as src:
        op = WindowFeaturesOperator(src.info.sample_rate_nominal)
        step = CountStep()
        parts = []
        for block in src:
            step.push(block)
            parts.append(op.push(block))
        parts.append(op.flush())
    return WindowFeatures.concat(parts), step.step_g


def worn_labels(path: str, w: WindowFeatures):
    """(k,) True worn / False nonwear / None unknown per window, from the truth labels."""
    stem = str(path)
    for ext in (".gz", ".cwa", ".bin", ".CWA"):
        stem = stem[: -len(ext)] if stem.endswith(ext) else stem
    lab = Path(stem + ".labels.csv")
    if not lab.is_file():
        return None
    with open(lab, newline="") as f:
        rows = list(csv.DictReader(f))
    start = np.array([int(r["device_start_ns"]) for r in rows], np.int64)
    act = np.array([int(r["activity"]) for r in rows])
    k = np.clip(np.searchsorted(start, w.start_ns), 0, len(start) - 1)
    k1 = np.clip(k - 1, 0, len(start) - 1)
    k = np.where(np.abs(start[k1] - w.start_ns) < np.abs(start[k] - w.start_ns), k1, k)
    return np.isin(act[k], WORN)


def report(name: str, sd_mg: np.ndarray) -> None:
    if sd_mg.shape[0] == 0:
        print(f"  {name}: no still windows")
        return
    q = np.percentile(sd_mg, PCT, axis=0)
    cells = "  ".join(f"p{p} {'/'.join(f'{v:.1f}' for v in row)}" for p, row in zip(PCT, q))
    print(f"  {name} ({sd_mg.shape[0]} windows), SD x/y/z mg: {cells}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("files", nargs="+")
    a = ap.parse_args(argv)
    for path in a.files:
        w, step = features(path)
        still = np.all(w.sd < 0.013, axis=1) & np.all(np.abs(w.mean) < 2.0, axis=1)
        step_txt = "unknown" if step is None else "/".join(f"{v * 1000:.1f}" for v in step)
        print(f"{Path(path).name}: {len(w)} windows, {int(still.sum())} still, step {step_txt} mg")
        sd = w.sd * 1000.0
        worn = worn_labels(path, w)
        if worn is None:
            report("still", sd[still])
        else:
            report("worn still", sd[still & worn])
            report("nonwear still", sd[still & ~worn])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
