"""What the activity outcomes cost `stillpoint process`, and that their memory stays flat.

    python tools/benchmarks/bench_outcomes.py [--days 1,3] [--hz 50] [--repeat 1] [--workdir DIR]

For each length, one simulated AX3 wrist recording (written once into --workdir and reused) is
processed by ``stillpoint process`` with the tables only and with the tables plus
``--cutpoints hildebrand_adults_geneactiv_wrist --steps --impute``, each in its own child
process, interleaved (tools/benchlib.best_of); prints wall, CPU, peak RSS, the ratio outcomes /
tables, and the peak RSS of the outcomes run per length (flat = bounded memory). The machine is
shared and noisy: read the ratios.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tools/benchmarks/benchlib.py

from benchlib import best_of  # noqa: E402

OUTCOMES = ["--cutpoints", "hildebrand_adults_geneactiv_wrist", "--steps", "--impute"]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--days", default="1,3")
    ap.add_argument("--hz", type=float, default=50.0)
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--workdir", default=None)
    args = ap.parse_args(argv)
    work = Path(args.workdir or tempfile.mkdtemp(prefix="bench-outcomes-"))
    work.mkdir(parents=True, exist_ok=True)
    from stillpoint.engine.sim import simulate_recording
    exe = [sys.executable, "-m", "stillpoint.tools", "process", "-q", "--overwrite"]
    rows = []
    for days in (float(d) for d in args.days.split(",")):
        rec = work / f"outcomes_{days:g}d_{args.hz:g}hz.cwa"
        if not rec.exists():
            simulate_recording(rec, days=days, hz=args.hz, seed=7, truth_path=False, labels_path=False)
        res = best_of({"tables": exe + [str(rec), "-o", str(work / "a.mcap")],
                       "outcomes": exe + [str(rec), "-o", str(work / "b.mcap")] + OUTCOMES},
                      args.repeat)
        for k, r in res.items():
            if r["rc"]:
                print(f"{k} failed: {r['err']}")
                return 1
        a, b = res["tables"], res["outcomes"]
        rows.append((days, a, b))
        print(f"{days:g} days at {args.hz:g} Hz: tables {a['wall']:.1f} s wall / {a['cpu']:.1f} s CPU / "
              f"{a['rss_mb']:.0f} MB; + outcomes {b['wall']:.1f} s / {b['cpu']:.1f} s / "
              f"{b['rss_mb']:.0f} MB; CPU ratio {b['cpu'] / a['cpu']:.2f}x, "
              f"RSS +{b['rss_mb'] - a['rss_mb']:.0f} MB")
    print("peak RSS with outcomes by length: " +
          ", ".join(f"{d:g} d {b['rss_mb']:.0f} MB" for d, _, b in rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
