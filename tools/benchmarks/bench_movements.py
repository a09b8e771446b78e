"""Speed and memory of `movements` on long simulated infant recordings (AX6, 25 Hz): writes
6-h, 24-h and 72-h recordings, then counts each in a fresh process and prints wall time and peak
RSS. Memory grows with the recording by about 24 bytes a sample (time, |a|, |w|: the median needs
the whole series), not with the six channels.

    python tools/benchmarks/bench_movements.py [--hours 6,24,72] [--dir /tmp]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

CHILD = r"""
import json, resource, sys, time
from stillpoint.engine.movements import count_leg
t = time.perf_counter()
r = count_leg(sys.argv[1])
print(json.dumps({"wall_s": time.perf_counter() - t, "count": r.count, "samples": r.samples,
                  "rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", default="6,24,72")
    ap.add_argument("--dir", default=None)
    a = ap.parse_args(argv)
    from stillpoint.engine.sim.infant import make_infant, write_infant
    from stillpoint.engine.sim.static_errors import StaticErrors
    d = Path(a.dir or tempfile.mkdtemp(prefix="bench_movements_"))
    base = None
    print(f"{'hours':>6} {'samples':>10} {'write s':>8} {'count s':>8} {'peak RSS MB':>12} "
          f"{'movements':>10} {'time x':>7} {'RSS x':>6}")
    for h in (float(x) for x in a.hours.split(",")):
        p = d / f"infant_{h:g}h.cwa"
        t = time.perf_counter()
        sim = make_infant(minutes=h * 60, seed=1, errors=StaticErrors(
            offset_g=[0.06, -0.07, 0.03], noise_g=[0.002] * 3), sleep_blocks=[(60, 90)])
        write_infant(p, sim)
        w = time.perf_counter() - t
        out = subprocess.run([sys.executable, "-c", CHILD, str(p)], capture_output=True, text=True,
                             check=True)
        r = json.loads(out.stdout)
        base = base or r
        print(f"{h:6g} {r['samples']:10d} {w:8.1f} {r['wall_s']:8.1f} {r['rss_mb']:12.0f} "
              f"{r['count']:10d} {r['wall_s'] / base['wall_s']:7.1f} {r['rss_mb'] / base['rss_mb']:6.2f}")
        p.unlink()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
