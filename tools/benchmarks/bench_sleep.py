"""What sleep costs in ``process``: CPU with and without it, and the sleep stage's memory from 1
to 14 days.

    python tools/benchmarks/bench_sleep.py [--days 3] [--hz 100] [--repeat 3] [--workdir DIR]

* ``stillpoint process FILE --timezone UTC`` (sleep on: spt/sib columns, nights table, MCAP
  topics) against the same with ``--no-sleep``, on a simulated AX3 wrist recording (``stillpoint
  simulate``), run interleaved ``--repeat`` times, best CPU time of each (``benchlib.best_of``);
  target: sleep adds at most 5 %.
* the same run in one process with the sleep work timed where it happens (the epoch rows through
  the sleep stage, the nights table and MCAP records; ``time.process_time`` around the sleep
  tap's calls): its share of the run's CPU. On a busy shared machine this in-run share is the
  steadier figure; the A/B difference above swings by +-10 % from run to run.
* the sleep stage alone on simulated 5 s epochs (engine/sim/sleep.py) of 1, 7 and 14 days: the
  most epochs it held at once and the peak of the memory Python allocated while it ran
  (tracemalloc): both must not grow with the recording's length.

The machine is shared and noisy: read the ratios, not the seconds.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import tracemalloc
from pathlib import Path

try:
    from benchlib import best_of
except ImportError:  # tools/benchmarks/benchlib.py beside the parent folder
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from benchlib import best_of


PROBE = r"""
import json, sys, time
from pathlib import Path
from stillpoint.engine.run import RunSettings, process_file
from stillpoint.engine.sleep import SleepOptions, nights_path
from stillpoint.engine.sleep import tap as T
from stillpoint.engine.tables import TablesSettings, table_paths
spent = [0.0]
rows0, close0 = T.SleepTap.rows, T.SleepTap.close
def rows(self, slices, final):
    slices = iter(slices)
    while True:  # the assembler's own work (pulling slices) is not sleep's
        try:
            sl = next(slices)
        except StopIteration:
            break
        t = time.process_time()
        out = list(rows0(self, [sl], False))
        spent[0] += time.process_time() - t
        yield from out
    if final:
        t = time.process_time()
        out = list(rows0(self, [], True))
        spent[0] += time.process_time() - t
        yield from out
def close(self, *a):
    t = time.process_time()
    try:
        return close0(self, *a)
    finally:
        spent[0] += time.process_time() - t
T.SleepTap.rows, T.SleepTap.close = rows, close
out = Path(sys.argv[2])
ts = TablesSettings(*table_paths(out), sleep=SleepOptions(), nights_path=nights_path(out))
t0 = time.process_time()
process_file(sys.argv[1], out, RunSettings(timezone="UTC"), tables=ts)
print(json.dumps({"sleep_cpu_s": spent[0], "run_cpu_s": time.process_time() - t0}))
"""


def stage_memory(days: float) -> dict:
    import numpy as np
    from stillpoint.engine.sim.sleep import SleepSpec, sleep_scenario
    from stillpoint.engine.sleep import SleepStage
    from stillpoint.engine.tables.epochs import EpochRows
    s = sleep_scenario(SleepSpec("2026-01-05T10:00:00", "Europe/London", days, seed=2))
    n = s.t_ns.shape[0]
    tracemalloc.start()
    st = SleepStage(s.zone, 5.0)
    held = 0
    base = tracemalloc.get_traced_memory()[0]
    tracemalloc.reset_peak()
    for a in range(0, n, 720):
        b = min(n, a + 720)
        z = np.zeros(b - a, bool)
        st.push(EpochRows(s.t_ns[a:b], np.full(b - a, 500), s.enmo[a:b], z * 0.0, z * 0.0,
                          s.anglez[a:b], z * 0.0, s.nonwear[a:b], z.copy(), z.copy(), z.copy(),
                          z.copy()))
        held = max(held, st.n - st.base)
    st.flush()
    peak = tracemalloc.get_traced_memory()[1] - base
    tracemalloc.stop()
    return {"days": days, "nights": len(st.nights), "max_held_epochs": held,
            "max_held_hours": round(held * 5 / 3600, 2), "peak_alloc_mb": round(peak / 2**20, 2)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--days", type=float, default=3.0)
    ap.add_argument("--hz", type=float, default=100.0)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--workdir", type=Path)
    a = ap.parse_args(argv)
    exe = str(Path(sys.executable).with_name("stillpoint"))
    out = {"memory": [stage_memory(d) for d in (1.0, 7.0, 14.0)]}
    with tempfile.TemporaryDirectory() as td:
        wd = a.workdir or Path(td)
        f = wd / f"sleep_bench_{a.days:g}d_{a.hz:g}hz.cwa"
        if not f.exists():
            subprocess.run([exe, "simulate", "-o", str(f), "--days", str(a.days), "--hz", str(a.hz),
                            "--seed", "7"], check=True, capture_output=True)
        base = [exe, "process", str(f), "--timezone", "UTC", "-q", "--overwrite"]
        r = best_of({"sleep": base + ["-o", str(wd / "with.mcap")],
                     "no_sleep": base + ["-o", str(wd / "without.mcap"), "--no-sleep"]}, a.repeat)
        for k in r:
            if r[k]["rc"]:
                raise SystemExit(f"{k}: process failed: {r[k]['err']}")
        out["process"] = {k: {"cpu_s": round(v["cpu"], 2), "wall_s": round(v["wall"], 2),
                              "rss_mb": round(v["rss_mb"], 1)} for k, v in r.items()}
        out["sleep_cpu_added_pct"] = round(100 * (r["sleep"]["cpu"] / r["no_sleep"]["cpu"] - 1), 2)
        out["file"] = {"days": a.days, "hz": a.hz}
        shares = []
        for _ in range(max(1, a.repeat)):
            for p in wd.glob("probe*"):
                p.unlink()
            r = subprocess.run([sys.executable, "-c", PROBE, str(f), str(wd / "probe.mcap")],
                               capture_output=True, text=True, check=True)
            shares.append(json.loads(r.stdout.strip().splitlines()[-1]))
        best = min(shares, key=lambda d: d["sleep_cpu_s"])
        out["in_run"] = {"sleep_cpu_s": round(best["sleep_cpu_s"], 3),
                         "run_cpu_s": round(best["run_cpu_s"], 2),
                         "sleep_share_pct": round(100 * best["sleep_cpu_s"] / best["run_cpu_s"], 2)}
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
