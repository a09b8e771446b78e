"""Our anglez (engine/operators/anglez.py) against GGIR's own g.applymetrics on the same raw samples.

    python tools/crosschecks/ggir_anglez.py --ggir PATH/TO/GGIR [--hz 100] [--minutes 60]

Raw samples of a moving and resting wrist (sines, steps between postures, noise; the first sample
on the 5 s grid so both cut the same epochs) are given to GGIR in the blocks its part 1 hands to
g.applymetrics (a whole number of 15-min windows, ``use`` in R/g.getmeta.R:305: 900 x rate
samples), once as GGIR is and once with the line of its rolling median that returns the raw
samples when the block is not a whole number of subsampling steps (R/g.applymetrics.R:122,
``xm = x[1:LX]``) reading ``xm[1:LX]``; and to our ``AnglezOperator`` as one segment. Prints, per case, the epochs compared and the largest
difference, away from the block edges and overall. R needs the ``zoo`` package.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent


def raw(hz: float, minutes: float, seed: int = 3):
    rng = np.random.default_rng(seed)
    n = int(minutes * 60 * hz)
    t = np.arange(n) / hz
    pose = np.repeat(rng.uniform(-1, 1, (int(minutes) + 1, 3)), int(60 * hz), axis=0)[:n]
    move = 0.3 * np.sin(2 * np.pi * 0.7 * t)[:, None] * (rng.random((n, 1)) < 2)
    active = (np.floor(t / 120) % 2 == 0)[:, None]
    a = pose + active * move + rng.normal(0, 0.01, (n, 3))
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    return np.round(a, 4)


def ours(acc: np.ndarray, hz: float) -> np.ndarray:
    from stillpoint.engine.operators.anglez import AnglezOperator
    from stillpoint.engine.operators.correction import CorrectedBatch
    op = AnglezOperator(hz, 5.0)
    t0 = 1_700_000_000 * 10**9  # on the 5 s grid
    t = t0 + np.round(np.arange(acc.shape[0]) * 1e9 / hz).astype(np.int64)
    _, _, v1 = op.push(CorrectedBatch(t, acc, np.zeros(acc.shape[0]), 0))
    _, _, v2 = op.flush()
    return np.concatenate([v1, v2])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ggir", type=Path, required=True, help="wadpac/GGIR checkout (its R/ is read)")
    ap.add_argument("--hz", type=float, default=100.0)
    ap.add_argument("--minutes", type=float, default=60.0)
    a = ap.parse_args(argv)
    acc = raw(a.hz, a.minutes)
    mine = ours(acc, a.hz)
    step = max(int(np.floor(a.hz / 10)), 1)
    block = int(round(900 * a.hz))  # GGIR part 1's blocks: whole 15-min windows
    with tempfile.TemporaryDirectory() as td:
        src = Path(td) / "raw.csv"
        np.savetxt(src, acc, delimiter=",", header="x,y,z", comments="", fmt="%.4f")
        for fix in ("", "fix"):
            b = block
            out = Path(td) / f"g{fix}.csv"
            r = subprocess.run(["Rscript", str(HERE / "ggir_anglez.R"), str(a.ggir / "R"), str(src),
                                str(a.hz), str(b), str(out), fix], capture_output=True, text=True)
            if r.returncode:
                sys.exit(r.stderr.strip().splitlines()[-1])
            theirs = np.loadtxt(out, delimiter=",", skiprows=1, converters={0: lambda s: float(s.strip('"'))})
            k = min(theirs.shape[0], mine.shape[0])
            d = np.abs(theirs[:k] - mine[:k])
            edges = np.zeros(k, bool)
            per = int(round(5 * a.hz))
            for s in range(0, acc.shape[0], b):  # epochs touching a block edge (2.5 s median)
                e = s // per
                edges[max(e - 1, 0):min(e + 1, k)] = True
            edges[-1] = True
            whole = "whole" if b % step == 0 else "not whole"
            what = "line 122 corrected" if fix else "as is"
            print(f"{a.hz:g} Hz, GGIR {what}, blocks of {b} samples ({whole} steps of {step}): {k} epochs; max |diff| "
                  f"{d[~edges].max():.3g} deg away from block edges, {d.max():.3g} deg overall "
                  f"({int((d > 1e-6).sum())} epochs differ by more than 1e-6 deg)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
