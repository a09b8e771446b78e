"""Benchmark `stillpoint process --mode online` against `--mode batch` on 1-, 7- and 14-day files.

    python tools/benchmarks/bench_online.py [--days 1,7,14] [--workdir DIR] [--cold]

For each length, batch and online run in their own child processes (benchlib.measure: wall,
CPU = user + system, peak RSS) one after the other, and the CPU ratio online / batch is printed
(target <= 1.1x at every length: online refits must not grow faster than the file), with the
number of estimates the online run published. ``--cold`` adds an online run whose refits
start from identity (the fit as it runs alone), for the before/after of the warm start.

Recordings: first the realistic ``stillpoint simulate`` files with the default wearer
(``benchlib.realistic_recording``: AX3 wrist, 100 Hz, seed 3; ``--wearers default,still`` adds
the wearer with long still periods), then (unless ``--no-pattern``) the
calibration generator's packed AX3 test pattern at 100 Hz (tools/benchmarks/bench_process.py writes and
reuses the same names in the same --workdir). Each mode runs ``--repeat`` times (default 2) and
the least CPU is kept: the machine is shared, and the ratio is taken within the same run.
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import sys
import tempfile
from pathlib import Path

from benchlib import measure, realistic_recording
from bench_process import recording

ONLINE_COLD = r"""
import json, sys
from stillpoint.engine.calibration import online
from stillpoint.engine.run import RunSettings, process_file
_init = online.OnlineCalibrator.__init__
def cold_init(self, *a, **k):
    k["warm_start"] = False
    _init(self, *a, **k)
online.OnlineCalibrator.__init__ = cold_init
s = process_file(sys.argv[1], sys.argv[2], RunSettings(mode="online"))
print(json.dumps({"estimates": len(s.get("estimates", []))}))
"""


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--days", default="1,7,14")
    ap.add_argument("--rate", type=float, default=100.0)
    ap.add_argument("--workdir", default=os.path.join(tempfile.gettempdir(), "stillpoint_bench"))
    ap.add_argument("--cold", action="store_true", help="also run online with refits from identity")
    ap.add_argument("--repeat", type=int, default=2, help="runs of each mode (least CPU kept)")
    ap.add_argument("--no-pattern", action="store_true", help="realistic files only")
    ap.add_argument("--wearers", default="default",
                    help="simulated wearers of the realistic files (e.g. default,still)")
    a = ap.parse_args(argv)
    wd = Path(a.workdir)
    wd.mkdir(parents=True, exist_ok=True)
    sp = [sys.executable, "-m", "stillpoint.tools"]
    rows = []
    wearers = [w.strip() for w in a.wearers.split(",") if w.strip()]
    kinds = [("realistic" if w == "default" else f"{w} wearer",
              functools.partial(realistic_recording, wearer=w)) for w in wearers]
    kinds += [] if a.no_pattern else [("test pattern", recording)]
    todo = [(kind, make, float(x)) for kind, make in kinds for x in a.days.split(",") if x.strip()]
    for kind, make, d in todo:
        path = make(wd, d, a.rate)
        out = wd / f"bench_online_{d:g}d.mcap"
        summ = wd / f"bench_online_{d:g}d.json"
        res = {}
        for _ in range(max(1, a.repeat)):  # interleaved: a slow phase of the machine hits both
            for mode in ("batch", "online"):
                r = measure(sp + ["process", path, "-o", out, "--mode", mode, "-q", "--summary", summ,
                                  "--overwrite"])
                if r["rc"] != 0:
                    raise SystemExit(f"process --mode {mode} failed on {path}:\n{r['err']}")
                if mode not in res or r["cpu"] < res[mode]["cpu"]:
                    res[mode] = r
                if mode == "online":
                    s = json.loads(summ.read_text())
        if a.cold:
            res["cold"] = measure([sys.executable, "-c", ONLINE_COLD, path, out])
        out.unlink(missing_ok=True)
        rows.append((d, path, res, s))
        b, o = res["batch"], res["online"]
        line = (f"{kind:13s} {d:5g} days: batch {b['cpu']:7.2f} s CPU ({b['wall']:6.1f} s wall, "
                f"{b['rss_mb']:4.0f} MB) | online {o['cpu']:7.2f} s CPU ({o['wall']:6.1f} s wall, "
                f"{o['rss_mb']:4.0f} MB) | online/batch {o['cpu'] / b['cpu']:.3f}x CPU "
                f"(target <= 1.1x), {len(s.get('estimates', []))} estimates")
        if a.cold:
            c = res["cold"]
            line += f" | online, refits from identity: {c['cpu']:7.2f} s CPU ({c['cpu'] / b['cpu']:.3f}x)"
        print(line, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
