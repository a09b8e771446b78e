"""Benchmark: align two 7-day 100 Hz AX3 recordings (simulated wrist + hip pair).

Each measurement runs in a fresh child under benchlib.measure (wall, CPU = user + system, peak
RSS of that child):
  1. baseline: decode both files completely (open_recording, every Block's accel_g) - the floor
     any aligner that reads the data must pay;
  2. `stillpoint align A B --json-out` (robust, the default): the estimate (pass 1 only);
  3. `stillpoint align A B --method brond --json-out`;
  4. `stillpoint align A B -o OUT.mcap`: estimate + resample OTHER onto the reference clock and
     write it (pass 2).
Prints figures and ratios to the baseline measured in the same run (machines are noisy).
Targets: estimate in < 30 s with peak RSS < 300 MB.

    /work/venv/bin/python tools/benchmarks/bench_align.py [--days 7] [--hz 100] [--dir DIR] [--keep]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time

from benchlib import measure

DECODE = r"""
import sys
from stillpoint.drivers import open_recording
n = 0
for p in sys.argv[1:]:
    for b in open_recording(p):
        b.accel_g()
        n += b.n
print(n)
"""


def timed(cmd: list) -> dict:
    """One run in a fresh child (benchlib.measure); exit code 3 ("cannot align") is an answer."""
    r = measure(cmd)
    r["out"] = r["out"].strip()
    if r["rc"] in (0, 3):
        r["err"] = ""
    return r


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--days", type=float, default=7.0)
    ap.add_argument("--hz", type=float, default=100.0)
    ap.add_argument("--dir", help="where the simulated pair is written (reused if present)")
    ap.add_argument("--keep", action="store_true", help="keep the files")
    a = ap.parse_args(argv)
    d = a.dir or tempfile.mkdtemp(prefix="bench_align_")
    os.makedirs(d, exist_ok=True)
    ref, oth = os.path.join(d, "wrist.cwa"), os.path.join(d, "hip.cwa")
    if not (os.path.exists(ref) and os.path.exists(oth)):
        t = time.perf_counter()
        from stillpoint.engine.sim.record import simulate_pair
        simulate_pair(ref, oth, site_a="wrist", site_b="hip", days=a.days, hz=a.hz, seed=7)
        print(f"simulated the pair in {time.perf_counter() - t:.0f} s -> {d}")
    size = (os.path.getsize(ref) + os.path.getsize(oth)) / 1e6
    py = sys.executable
    cli = [py, "-m", "stillpoint.tools.cli", "align", ref, oth]
    runs = [
        ("baseline: decode both files", [py, "-c", DECODE, ref, oth]),
        ("align --method robust (estimate)", cli + ["--json-out", os.path.join(d, "r.json")]),
        ("align --method brond (estimate)", cli + ["--method", "brond", "--json-out",
                                                   os.path.join(d, "b.json")]),
        ("align -o OUT.mcap (estimate + aligned stream)", cli + ["-o", os.path.join(d, "al.mcap")]),
    ]
    print(f"pair: {a.days:g} days at {a.hz:g} Hz, AX3 packed, {size:.0f} MB of .cwa")
    base = None
    for name, cmd in runs:
        r = timed(cmd)
        if r["err"]:
            print(f"{name}: FAILED\n{r['err'][-2000:]}")
            return 1
        if base is None:
            base = r
        print(f"{name:48s} wall {r['wall']:6.1f} s  cpu {r['cpu']:6.1f} s  peak RSS "
              f"{r['rss_mb']:6.0f} MB   x{r['wall'] / base['wall']:.2f} wall, "
              f"x{r['cpu'] / base['cpu']:.2f} cpu of baseline")
        if "align" in name and "-o" not in cmd:
            for line in r["out"].splitlines()[:4]:
                print(f"{'':6s}{line}")
    if not a.keep and not a.dir:
        for f in os.listdir(d):
            os.remove(os.path.join(d, f))
        os.rmdir(d)
    return 0


if __name__ == "__main__":
    sys.exit(main())
