"""Regenerate tests/data/ggir_bouts/cases.txt: random marked-epoch sequences and what GGIR's bout
rule returns for them.

    python tools/crosschecks/ggir_bouts_reference.py --reference PATH/g.getbout.R

The reference is wadpac/GGIR ``R/g.getbout.R`` @388064b707df4fcfb7f9b755c5a43a477d371092, run with
R and the zoo package (``apt-get install r-cran-zoo``). Each line of the fixture:
``<bout epochs> <epoch s> <marked epochs as 0/1> <GGIR's bout epochs as 0/1>``; the tests compare
``engine.outcomes.bouts.ggir_bouts`` with the last field (tests/engine/outcomes/test_outcomes_bands.py).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

import numpy as np

OUT = Path(__file__).resolve().parents[2] / "tests" / "data" / "ggir_bouts" / "cases.txt"
R = """
suppressMessages(library(zoo)); source(commandArgs(trailingOnly = TRUE)[1])
for (line in readLines(commandArgs(trailingOnly = TRUE)[2])) {
  p = strsplit(line, " ")[[1]]
  x = as.numeric(strsplit(p[3], "")[[1]])
  cat(paste(g.getbout(x, as.numeric(p[1]), 0.8, as.numeric(p[2])), collapse = ""), "\\n")
}
"""


def cases(seed: int = 34, count: int = 80) -> list:
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(count):
        n = int(rng.integers(30, 600))
        p = rng.uniform(0.2, 0.95)
        x = np.zeros(n, int)
        pos = 0
        while pos < n:
            k = int(rng.integers(1, 80))
            seg = (rng.random(k) < (p if rng.random() < 0.5 else 0.05)).astype(int)
            x[pos:pos + k] = seg[:n - pos]
            pos += k
        epm = int(rng.choice([12, 6, 4, 2, 1]))
        out.append((int(rng.choice([1, 5, 10])) * epm, 60 // epm, "".join(map(str, x))))
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--reference", type=Path, required=True, help="GGIR's g.getbout.R")
    args = ap.parse_args()
    cs = cases()
    OUT.parent.mkdir(parents=True, exist_ok=True)
    tmp = OUT.with_suffix(".in")
    tmp.write_text("".join(f"{L} {ws3} {x}\n" for L, ws3, x in cs))
    try:
        r = subprocess.run(["Rscript", "-e", R, str(args.reference), str(tmp)], check=True,
                           capture_output=True, text=True)
    finally:
        tmp.unlink()
    got = [line.strip() for line in r.stdout.splitlines()]
    assert len(got) == len(cs)
    OUT.write_text("".join(f"{L} {ws3} {x} {g}\n" for (L, ws3, x), g in zip(cs, got)))
    print(f"{len(cs)} cases -> {OUT}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
