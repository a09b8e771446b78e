"""What sleep costs in ``process``: CPU with and without it, and the sleep stage's memory from 1
to 14 days.

    python tools/benchmarks/bench_sleep.py [--days 3] [--hz 100] [--repeat 3] [--workdir DIR]

* ``stillpoint process FILE --timezone UTC`` (sleep on: spt/sib columns, nights table, MCAP
  topics) against the same with ``--no-sleep``, on a simulated AX3 wrist recording (``stillpoint
  simulate``), run interleaved ``--repeat`` times, best CPU time of each (``benchlib.best_of``);
  target: sleep adds at most 5 %.
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
except ImportError:  # tools/benchlib.py beside the parent folder
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from benchlib import best_of


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
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
