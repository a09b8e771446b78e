"""Peak memory of the rhythm and windows tables against the recording's length.

    python tools/benchmarks/bench_rhythm_memory.py [--days 7,30] [--repeat 1]

For each length, a simulated wearer's epoch series (engine/sim/sleep.py at 5 s epochs, with
waking activity and nonwear) goes through the output pass's rhythm side in a fresh child process:
the sleep operators, the rhythm tap fed slice by slice as the table writer feeds it, then the
rhythm and windows tables written at the end (``rhythm``); the same child without the tap and the
tables (``base``: the series and the sleep operators alone) is the baseline. Prints wall, CPU and
peak RSS of both and the difference per length: bounded memory means the difference stays flat
as the recording grows. The machine is shared and noisy: read the differences.
"""

from __future__ import annotations

import argparse
import sys

from benchlib import best_of

CHILD = r"""
import sys, tempfile
from pathlib import Path
import numpy as np
from stillpoint.engine.sim.sleep import SleepSpec, sleep_scenario
from stillpoint.engine.sleep import SleepStage
from stillpoint.engine.tables.epochs import EpochRows
days, mode = float(sys.argv[1]), sys.argv[2]
s = sleep_scenario(SleepSpec("2026-05-04T10:00:00", "Europe/London", days, seed=7,
                             active_per_day=8.0, nonwear_days=(2,), nonwear_nights=(4,)))
st = SleepStage(s.zone, 5.0)
tap = None
if mode == "rhythm":
    from stillpoint.engine.rhythm.table import RhythmTap
    out = Path(tempfile.mkdtemp())
    tap = RhythmTap(out / "r.rhythm.csv", s.zone, 5.0, sleep=True)
n = s.t_ns.shape[0]
for a in range(0, n, 4000):
    b = min(n, a + 4000)
    z = np.zeros(b - a, bool)
    rows = EpochRows(s.t_ns[a:b], np.full(b - a, 62), s.enmo[a:b], z * 0.0, s.enmo[a:b],
                     s.anglez[a:b], z * 0.0, s.nonwear[a:b], z.copy(), z.copy(), z.copy(), z.copy())
    for r, spt, sib in st.push(rows):
        if tap is not None:
            tap.push(r, spt, sib)
for r, spt, sib in st.flush():
    if tap is not None:
        tap.push(r, spt, sib)
if tap is not None:
    from stillpoint.engine.timeuse.table import write_windows
    rec = tap.load()
    tap.close([], rec)
    rows = write_windows(out / "r.windows.csv", rec, st.nights, s.zone, 5.0)
    print(len(rows), "windows")
"""


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--days", default="7,30")
    ap.add_argument("--repeat", type=int, default=1)
    a = ap.parse_args(argv)
    print(f"{'days':>5} {'base s':>7} {'rhythm s':>8} {'base MB':>8} {'rhythm MB':>9} {'diff MB':>8}")
    for d in [float(x) for x in a.days.split(",")]:
        r = best_of({m: [sys.executable, "-c", CHILD, str(d), m] for m in ("base", "rhythm")}, a.repeat)
        for m, v in r.items():
            if v["rc"]:
                sys.exit(f"{m} {d} days failed: {v['err']}")
        b, h = r["base"], r["rhythm"]
        print(f"{d:5g} {b['wall']:7.1f} {h['wall']:8.1f} {b['rss_mb']:8.1f} {h['rss_mb']:9.1f} "
              f"{h['rss_mb'] - b['rss_mb']:8.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
