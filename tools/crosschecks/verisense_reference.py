"""Regenerate the Verisense reference fixtures in tests/data/verisense/ with the reference R code.

    python tools/crosschecks/verisense_reference.py --reference PATH/verisense_count_steps.R [--real DIR]

The reference is GGIR's copy of the Verisense step function (wadpac/GGIR
``user-scripts/verisense_count_steps.R`` @388064b707df4fcfb7f9b755c5a43a477d371092; R from
``apt-get install r-base-core``). For each input (15 Hz x, y, z in g, written with 6 decimals: the
fixture is the CSV, read the same way by R and by the tests):

* ``walk610``: the real counted walk (STILLPOINT_REAL_DATA or --real:
  ax3_openmovement_example_610_steps_fw30_nofrac.cwa), uncalibrated g resampled to 15 Hz with
  ``engine.outcomes.steps.Resampler15``;
* ``simwalk``: 10 min of a simulated wrist (engine.sim) around a walk, rendered at 15 Hz;
* ``bouts``: a synthetic signal (fixed seed) of walking bouts of 2 to 60 s with pauses, changing
  step amplitude (the similarity rule) and quiet stretches (the continuity rule).

R writes, per input and parameter set, the steps per second its function returns:
``<input>.steps.csv`` with columns ``original`` and ``rowlands2022``. The tests compare our
operator with these exactly (tests/engine/outcomes/test_outcomes_steps.py); CI needs no R.
"""

from __future__ import annotations

import argparse
import gzip
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
OUT = ROOT / "tests" / "data" / "verisense"
COEFFS = {"original": "c(3, 5, 15, -0.5, 3, 4, 0.001, 1.2)",
          "rowlands2022": "c(4, 4, 20, -1.0, 4, 4, 0.01, 1.25)"}

R_DRIVER = """
args <- commandArgs(trailingOnly = TRUE)
source(args[1])
x <- as.matrix(read.csv(args[2]))
orig <- verisense_count_steps(x, %(original)s)
rev <- verisense_count_steps(x, %(rowlands2022)s)
n <- max(length(orig), length(rev))
length(orig) <- n; length(rev) <- n
orig[is.na(orig)] <- 0; rev[is.na(rev)] <- 0
write.csv(data.frame(original = orig, rowlands2022 = rev), args[3], row.names = FALSE)
""" % COEFFS


def walk610(real: Path) -> np.ndarray:
    from stillpoint.drivers import open_recording
    from stillpoint.engine.outcomes.steps import Resampler15
    src = open_recording(real / "ax3_openmovement_example_610_steps_fw30_nofrac.cwa")
    rs, out = None, []
    for b in src:
        if rs is None:
            rs = Resampler15(int(b.time_ns[0]))
        out.append(rs.push(b.time_ns, b.accel_g()))
    src.close()
    return np.concatenate(out)


def simwalk() -> np.ndarray:
    from stillpoint.engine.sim.wearer import SiteModel, WearerParams, make_schedule
    sch = make_schedule(WearerParams(), 86400.0, seed=7)
    gait = np.flatnonzero(sch.step_hz > 0)
    i = gait[np.argmax(sch.end[gait] - sch.start[gait] > 120)]
    t0 = sch.start[i] - 120.0
    t = t0 + np.arange(15 * 600) / 15.0
    f, _ = SiteModel(sch, "wrist", seed=7).render(t)
    return f


def bouts() -> np.ndarray:
    rng = np.random.default_rng(34)
    parts = []
    for dur, pause, amp in ((2, 5, 0.5), (4, 8, 0.6), (60, 10, 0.55), (20, 3, 0.9),
                            (8, 30, 0.3), (45, 6, 0.7), (3, 4, 0.5)):
        hz = rng.uniform(1.6, 2.2)
        t = np.arange(int(dur * 15)) / 15.0
        a = amp * (1 + 0.4 * rng.standard_normal()) * np.maximum(0, np.sin(2 * np.pi * hz * t)) ** 3
        parts.append(np.stack([0.1 + 0.05 * rng.standard_normal(t.size),
                               0.2 + 0.05 * rng.standard_normal(t.size),
                               1 + a + 0.04 * rng.standard_normal(t.size)], axis=1))
        q = np.arange(int(pause * 15))
        parts.append(np.stack([np.full(q.size, 0.1), np.full(q.size, 0.2),
                               1 + 0.003 * rng.standard_normal(q.size)], axis=1))
    return np.concatenate(parts)


def write_input(path: Path, xyz: np.ndarray) -> None:
    with gzip.open(path, "wt", compresslevel=9) as f:
        f.write("x,y,z\n")
        np.savetxt(f, xyz, fmt="%.6f", delimiter=",")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--reference", type=Path, required=True, help="verisense_count_steps.R")
    ap.add_argument("--real", type=Path, default=os.environ.get("STILLPOINT_REAL_DATA"))
    args = ap.parse_args()
    inputs = {"simwalk": simwalk(), "bouts": bouts()}
    if args.real:
        inputs["walk610"] = walk610(Path(args.real))
    OUT.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        drv = Path(tmp) / "driver.R"
        drv.write_text(R_DRIVER)
        for name, xyz in inputs.items():
            inp = OUT / f"{name}.input.csv.gz"
            write_input(inp, xyz)
            plain = Path(tmp) / f"{name}.csv"
            with gzip.open(inp, "rt") as f:
                plain.write_text(f.read())
            res = OUT / f"{name}.steps.csv"
            subprocess.run(["Rscript", str(drv), str(args.reference), str(plain), str(res)],
                           check=True)
            s = np.loadtxt(res, delimiter=",", skiprows=1)
            print(f"{name}: {xyz.shape[0]} samples; steps original {int(s[:, 0].sum())}, "
                  f"rowlands2022 {int(s[:, 1].sum())}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
