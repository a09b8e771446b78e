"""Benchmark of `stillpoint discrepancy`: wall time and child peak RSS against baselines measured in
the same run (this machine is shared and noisy; ratios are what to compare).

1. A simulated AX3 recording (default 2 days at 100 Hz, packed): `stillpoint discrepancy REC`
   against `stillpoint calibrate REC --read-all` (the same streaming read + window features of
   the whole file, one fit: the workflow's feature pass), so the ratio is the cost of the
   workflow's search on top of reading the file; wall and peak RSS, then CPU time of one more
   run of each.
2. The real 84 h GGIR feature set: `stillpoint discrepancy CSV` against `stillpoint
   calibrate-features CSV` (one van Hees fit on the same table).

    /work/venv/bin/python tools/benchmarks/bench_discrepancy.py [--days 2] [--keep DIR]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REAL_CSV = Path("/work/shared/data/real/calib_features_ggir_data_calibrate_spheredata_84h.csv")


def child(cmd) -> tuple[float, float]:
    """(wall s, peak RSS MB) of one child process (RSS via wait4 of that child alone)."""
    t = time.perf_counter()
    p = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, ru = os.wait4(p.pid, 0)
    wall = time.perf_counter() - t
    if status != 0:
        raise SystemExit(f"failed ({status}): {' '.join(map(str, cmd))}\n{p.stderr.read().decode()}")
    return wall, ru.ru_maxrss / 1024.0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--days", type=float, default=2.0)
    ap.add_argument("--keep", help="directory for the simulated file (default: a temp dir)")
    a = ap.parse_args(argv)
    sp = [sys.executable, "-m", "stillpoint.tools"]
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(a.keep or tmp)
        d.mkdir(parents=True, exist_ok=True)
        rec = d / "bench_disc.cwa"
        if not rec.exists():
            subprocess.run(sp + ["simulate", "--device", "ax3", "--days", str(a.days), "--hz", "100",
                                 "--effects", "default,temperature_gain", "--seed", "11", "-o", str(rec)],
                           check=True, stdout=subprocess.DEVNULL)
        rows = []
        base = child(sp + ["calibrate", str(rec), "--json", "--read-all"])
        disc = child(sp + ["discrepancy", str(rec), "--no-plots", "--json"])
        rows.append((f"simulated AX3 {a.days:g} d 100 Hz ({rec.stat().st_size / 1e6:.0f} MB)",
                     "calibrate --read-all", base, disc))
        from benchlib import measure  # CPU time too (wall is inflated on a busy machine)
        fb = measure(sp + ["calibrate", str(rec), "--json", "--read-all"])
        fd = measure(sp + ["discrepancy", str(rec), "--no-plots", "--json"])
        cpu_row = (fb["cpu"], fd["cpu"])
        if REAL_CSV.exists():
            base = child(sp + ["calibrate-features", str(REAL_CSV), "--json"])
            disc = child(sp + ["discrepancy", str(REAL_CSV), "--no-plots", "--json"])
            rows.append(("real 84 h GGIR feature set (10,958 windows)", "calibrate-features", base, disc))
    print(f"{'input':<46}{'baseline':<20}{'base s':>8}{'disc s':>8}{'ratio':>7}"
          f"{'base MB':>9}{'disc MB':>9}{'ratio':>7}")
    for name, bname, (bw, bm), (dw, dm) in rows:
        print(f"{name:<46}{bname:<20}{bw:>8.2f}{dw:>8.2f}{dw / bw:>7.2f}{bm:>9.0f}{dm:>9.0f}{dm / bm:>7.2f}")
    print(f"CPU (one more run each): feature pass (calibrate --read-all: decode, window features, one "
          f"fit) {cpu_row[0]:.2f} s, discrepancy {cpu_row[1]:.2f} s: "
          f"{cpu_row[1] / cpu_row[0]:.2f}x (target <= 3x)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
