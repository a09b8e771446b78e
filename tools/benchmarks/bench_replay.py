"""Peak RSS of `stillpoint replay` and `replay --check` by log length (must be flat).

    python tools/benchmarks/bench_replay.py [--days 1,7,14] [--hz 100] [--workdir DIR]

For each length: a recording simulated by engine/sim (AX3 packed, adult wrist, typical errors),
processed once (`process --mode batch`), then `replay` and `replay --check` each run in its own
child process (wall, CPU and peak RSS via ``getrusage(RUSAGE_CHILDREN)``, tools/benchmarks/benchlib.py).
Files are kept in the workdir and reused. The machine is shared: read the RSS column, which does
not depend on load.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

from benchlib import measure


def recording(wd: Path, days: float, hz: float) -> Path:
    p = wd / f"replay_{days:g}d_{hz:g}hz.cwa"
    if not p.is_file():
        from stillpoint.engine.sim import simulate_recording
        tmp = p.with_name(p.stem + ".tmp.cwa")
        simulate_recording(tmp, days=days, hz=hz, seed=5, truth_path=False)
        os.replace(tmp, p)
    return p


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--days", default="1,7,14")
    ap.add_argument("--hz", type=float, default=100.0)
    ap.add_argument("--workdir", default=os.path.join(tempfile.gettempdir(), "stillpoint_bench"))
    args = ap.parse_args(argv)
    wd = Path(args.workdir)
    wd.mkdir(parents=True, exist_ok=True)
    sp = [sys.executable, "-m", "stillpoint.tools"]
    print(f"{'days':>5s} {'MCAP MB':>8s} | {'process':>22s} | {'replay':>22s} | {'replay --check':>22s}")
    print(f"{'':>5s} {'':>8s} | {'wall s  cpu s  RSS MB':>22s} | {'wall s  cpu s  RSS MB':>22s} | "
          f"{'wall s  cpu s  RSS MB':>22s}")
    for d in [float(x) for x in args.days.split(",") if x.strip()]:
        rec = recording(wd, d, args.hz)
        log = wd / f"replay_{d:g}d.mcap"
        again = wd / f"replay_{d:g}d.replay.mcap"
        rows = [measure(sp + ["process", rec, "-o", log, "-q", "--overwrite"]),
                measure(sp + ["replay", log, "-o", again, "-q"]),
                measure(sp + ["replay", log, "-o", again, "-q", "--check"])]
        for r in rows:
            if r["rc"] != 0:
                raise SystemExit(f"failed: {r['err']}")
        cells = " | ".join(f"{r['wall']:6.1f} {r['cpu']:6.1f} {r['rss_mb']:8.0f}" for r in rows)
        print(f"{d:5g} {log.stat().st_size / 1e6:8.0f} | {cells}", flush=True)
        for p in (log, again):
            p.unlink(missing_ok=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
