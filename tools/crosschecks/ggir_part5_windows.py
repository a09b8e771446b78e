"""Print the agreement of our windows table's windows with GGIR part 5's (``g.part5.definedays``
looped as ``g.part5`` does) on the same sleep periods.

    python tools/crosschecks/ggir_part5_windows.py --ggir PATH/TO/GGIR

Scenarios: the rhythm crosscheck's simulated weeks (tools/crosschecks/ggir_rhythm_fixtures.py).
"""

from __future__ import annotations

import argparse
import csv
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ggir", type=Path, required=True)
    a = ap.parse_args(argv)
    sys.path.insert(0, str(HERE))
    import ggir_rhythm_fixtures as rf
    from stillpoint.engine.timeuse import time_use
    from stillpoint.engine.sleep import SleepStage
    from stillpoint.engine.tables.epochs import EpochRows
    with tempfile.TemporaryDirectory() as td:
        for name, spec in rf.scenarios().items():
            s, sib, spt = rf.scenario_series(spec)
            st = SleepStage(s.zone, 5.0)  # the nights again (scenario_series keeps only the flags)
            n = s.t_ns.shape[0]
            for i in range(0, n, 4000):
                j = min(n, i + 4000)
                z = np.zeros(j - i, bool)
                st.push(EpochRows(s.t_ns[i:j], np.full(j - i, 500), s.enmo[i:j], z * 0.0, z * 0.0,
                                  s.anglez[i:j], z * 0.0, s.nonwear[i:j], z.copy(), z.copy(),
                                  z.copy(), z.copy()))
            st.flush()
            rows = time_use(s.t_ns, s.enmo, ~s.nonwear, s.nonwear, sib.astype(bool), spt.astype(bool),
                            st.nights, s.zone, 5.0)
            p = Path(td) / f"{name}.csv"
            with open(p, "w") as f:
                f.write("time_s,diur\n")
                for t, d in zip((s.t_ns // 10**9).tolist(), spt.astype(int).tolist()):
                    f.write(f"{t},{d}\n")
            r = subprocess.run(["Rscript", str(HERE / "ggir_part5_windows.R"), str(a.ggir / "R"), str(p),
                                spec.timezone, str(p) + ".out"], capture_output=True, text=True)
            if r.returncode:
                sys.exit(f"Rscript failed: {r.stderr.strip().splitlines()[-3:]}")
            theirs = [(x["type"], int(float(x["first"])) - 1, int(float(x["last"])))
                      for x in csv.DictReader(open(str(p) + ".out"))]
            from stillpoint.engine.timezones import local_text
            per = {}
            for kind, first, stop in theirs:
                per.setdefault(kind, []).append((first, stop))
            out = []
            for kind in ("WW", "MM", "OO"):
                mine = [x for x in rows if x["window_type"] == kind]
                g = per.get(kind, [])
                same = sum(1 for x, (f0, f1) in zip(mine, g)  # same first epoch and length
                           if abs(x["duration_h"] - (f1 - f0) * 5 / 3600) < 1e-9
                           and x["start_local"] == local_text(int(s.t_ns[f0]), s.zone))
                out.append(f"{kind} {same}/{len(g)} GGIR windows equal ({len(mine)} ours)")
            print(f"{name}: " + "; ".join(out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
