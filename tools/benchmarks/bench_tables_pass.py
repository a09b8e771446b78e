"""The tables' own pass (an online run's tables after its pass, tables from a log) at several step
lengths: what its step costs.

    python tools/benchmarks/bench_tables_pass.py [--days 7] [--steps 500:600,2000:2400]
                                                 [--repeat 3] [--workdir DIR]

The pass alone (``engine.tables.estimate_pass.tables_with_estimate``: decode, correction with a
temperature estimate from the first sample, epoch metrics and BFEN, the epoch, day, sleep and
rhythm tables; no log), over the simulator's default wearer (``benchlib.realistic_recording``),
each run in its own child process, the step lengths alternating, the least CPU and wall of
``--repeat`` rounds and the largest peak RSS. A step ``SECTORS:SECONDS`` is the .cwa sectors
the reader decodes at a time (``tuning.TABLES_PASS_SECTORS``) and the longest run of blocks the
pass joins (``tuning.TABLES_PASS_STEP_S``; the sample cap ``tuning.TABLES_PASS_SAMPLES`` is
lifted, so a step is the seconds given at any rate). Every step writes the same tables, byte
for byte, and the same tables summary, full-precision means included (checked: the script
exits 1 otherwise).
"""

from __future__ import annotations

import argparse
import hashlib
import sys
import tempfile
from pathlib import Path

from benchlib import measure, realistic_recording

PASS = r"""
import json, sys
from dataclasses import replace
from pathlib import Path
import numpy as np
from stillpoint.engine.run import RunSettings, tuning
from stillpoint.engine.run.inputs import open_input
from stillpoint.engine.calibration.estimate import CalibrationEstimate
from stillpoint.engine.tables import TablesSettings, table_paths
from stillpoint.engine.tables.estimate_pass import tables_with_estimate
path, sectors, step_s, out = Path(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3]), Path(sys.argv[4])
tuning.TABLES_PASS_SECTORS, tuning.TABLES_PASS_STEP_S = sectors, step_s
tuning.TABLES_PASS_SAMPLES = 1 << 62  # the step is the seconds given
s = RunSettings(mode="online")
opened = open_input(path, s)
opened.source.close()
# a fitted estimate's shape: offsets, gains and a temperature term, applied from the first sample
est = CalibrationEstimate(offset=np.array([0.012, -0.021, 0.006]), scale=np.array([1.011, 0.992, 1.003]),
                          tempoffset=np.array([0.0011, -0.0004, -0.0009]), temperature_ref=24.0,
                          status="ok", reason="benchmark", method="autocal-c2")
ts = replace(TablesSettings(*table_paths(out / "t.mcap")), zone=opened.clock.zone)
src = opened.input.open(follow=False, tables=True)
try:
    summary = tables_with_estimate(src, est, s, ts)
finally:
    src.close()
print(json.dumps(summary, sort_keys=True, default=str).replace(str(out), "OUT"))
"""


def _digest(folder: Path, summary: str) -> str:
    h = hashlib.sha256(summary.encode())
    for p in sorted(folder.iterdir()):
        h.update(p.name.encode())
        h.update(p.read_bytes())
    return h.hexdigest()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--days", type=float, default=7.0)
    ap.add_argument("--steps", default="500:600,1000:1200,2000:2400,3000:3600",
                    help="SECTORS:SECONDS,... (the first is the baseline of the ratios)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--workdir", default=None)
    a = ap.parse_args(argv)
    work = Path(a.workdir or tempfile.mkdtemp(prefix="bench-tables-pass-"))
    work.mkdir(parents=True, exist_ok=True)
    rec = realistic_recording(work, a.days)
    steps = [tuple(x.split(":")) for x in a.steps.split(",") if x.strip()]
    runs: dict = {st: [] for st in steps}
    digests: dict = {}
    for _ in range(max(1, a.repeat)):
        for st in steps:
            with tempfile.TemporaryDirectory(dir=work) as tmp:
                r = measure([sys.executable, "-c", PASS, str(rec), st[0], st[1], tmp])
                if r["rc"] != 0:
                    print(f"the pass failed at step {st}: {r['err'].strip().splitlines()[-1:]}")
                    return 2
                digests.setdefault(st, set()).add(_digest(Path(tmp), r["out"]))
            runs[st].append(r)
    print(f"{rec.name}: the tables' own pass alone, least of {a.repeat} rounds (CPU and wall "
          "separately), the largest peak RSS")
    print(f"{'sectors : step s':>18s} | {'wall s':>7s} {'CPU s':>7s} {'RSS MB':>7s} | CPU / first")
    base = None
    for st in steps:
        rs = runs[st]
        wall, cpu = min(r["wall"] for r in rs), min(r["cpu"] for r in rs)
        rss = max(r["rss_mb"] for r in rs)
        base = cpu if base is None else base
        print(f"{st[0] + ' : ' + st[1]:>18s} | {wall:7.2f} {cpu:7.2f} {rss:7.0f} | {cpu / base:.2f}x")
    same = len(set().union(*digests.values())) == 1
    print("tables the same at every step:", "yes" if same else "NO")
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
