"""Regenerate tests/data/ggir_night_flags.json: GGIR's fraction of each night invalid
(``g.sib.det`` then ``g.sib.sum``, as part 3) on simulated series, against our nights table's
``fraction_night_invalid`` (the figure ``cleaningcode`` 2 and ``night_valid`` are decided by).

    python tools/crosschecks/ggir_night_flags.py --ggir PATH/TO/GGIR [--check]

Scenarios: a recording cut mid-night (ends 03:00), one starting at 02:00, nonwear nights, and a
spring DST week (engine/sim/sleep.py). R needs ``zoo``.
"""

from __future__ import annotations

import argparse
import csv
import json
import subprocess
import sys
import tempfile
from dataclasses import asdict
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
OUT = ROOT / "tests" / "data" / "ggir_night_flags.json"


def scenarios():
    from stillpoint.engine.sim.sleep import SleepSpec
    return {
        "cut_mid_night": SleepSpec("2026-05-04T10:00:00", "UTC", 3 + 17 / 24, seed=21),
        "early_start": SleepSpec("2026-06-10T02:00:00", "UTC", 3.0, seed=24),
        "nonwear_nights": SleepSpec("2026-05-04T10:00:00", "UTC", 4.0, seed=23, nonwear_nights=(1, 2)),
        "spring_dst_week": SleepSpec("2026-03-25T10:00:00", "Europe/London", 7.0, seed=34,
                                     nonwear_nights=(1, 4)),
    }


def ours(spec) -> list:
    """(night date, fraction_night_invalid) of our nights."""
    from stillpoint.engine.sim.sleep import sleep_scenario
    from stillpoint.engine.sleep import SleepStage
    from stillpoint.engine.tables.epochs import EpochRows
    s = sleep_scenario(spec)
    st = SleepStage(s.zone, 5.0)
    n = s.t_ns.shape[0]
    for a in range(0, n, 4000):
        b = min(n, a + 4000)
        z = np.zeros(b - a, bool)
        st.push(EpochRows(s.t_ns[a:b], np.full(b - a, 500), s.enmo[a:b], z * 0.0, z * 0.0,
                          s.anglez[a:b], z * 0.0, s.nonwear[a:b], z.copy(), z.copy(), z.copy(),
                          z.copy()))
    st.flush()
    return s, [(x.date.isoformat(), x.fraction_invalid) for x in st.nights]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ggir", type=Path, required=True)
    ap.add_argument("--check", action="store_true")
    a = ap.parse_args(argv)
    sys.path.insert(0, str(HERE))
    from ggir_sleep_fixtures import ggir_commit, write_series
    out = {"ggir_commit": ggir_commit(a.ggir), "scenarios": {}}
    with tempfile.TemporaryDirectory() as td:
        for name, spec in scenarios().items():
            s, mine = ours(spec)
            p = Path(td) / f"{name}.csv"
            write_series(p, s.t_ns, s.zone, s.anglez, s.nonwear)
            r = subprocess.run(["Rscript", str(HERE / "ggir_night_flags.R"), str(a.ggir / "R"), str(p),
                                spec.timezone, str(p) + ".out"], capture_output=True, text=True)
            if r.returncode:
                sys.exit(f"Rscript failed: {r.stderr.strip().splitlines()[-3:]}")
            # GGIR's night starts at its window's first epoch: the evening's date (a partial first
            # night of a recording started after midnight starts on the night's morning)
            theirs = {x["start"][:10]: float(x["fraction_night_invalid"])
                      for x in csv.DictReader(open(str(p) + ".out"))}
            mine_d = dict(mine)
            common = [k for k in theirs if k in mine_d]
            d = max(abs(mine_d[k] - theirs[k]) for k in common)
            print(f"{name}: {len(mine)} nights ours, {len(theirs)} GGIR's, {len(common)} in both; "
                  f"max |diff| of fraction_night_invalid {d:.2e}; ours only: "
                  f"{sorted(set(mine_d) - set(theirs))}")
            out["scenarios"][name] = {"spec": asdict(spec), "fraction_night_invalid": theirs}
    if not a.check:
        OUT.write_text(json.dumps(out, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
