"""Step counts against counted steps: the real 610-step walk and simulated walks with known steps.

    python tools/crosschecks/verisense_walks.py [--real DIR] [--seeds 6] [--hz 50] [--site wrist]

1. The real walk (STILLPOINT_REAL_DATA or --real: ax3_openmovement_example_610_steps_fw30_nofrac.cwa,
   610 steps counted by the person walking): its corrected stream (uncalibrated here: 12 min hold
   too few still windows) through ``engine.outcomes.steps.StepOperator``, as ``stillpoint process
   --steps`` does; the count of each Verisense parameter set and its error.
2. Simulated walks (engine.sim): every walking and running bout of at least 60 s in ``--seeds``
   simulated 3-day wearers, the specific force at the body site rendered at ``--hz`` (no sensor
   errors: the algorithm's error, not the device's), 10 s of the neighbouring activity either side;
   true steps are the schedule's heel strikes inside the bout, counted steps the operator's inside
   it. Per set: bouts, true and counted steps, bias (counted - true, % of true), mean absolute
   percentage error per bout, for walking and running apart.

Prints a table; not a test (the figures are quoted in docs/activity-outcomes.md).
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np

TRUE_STEPS = 610


def real_walk(real: Path) -> dict:
    from stillpoint.drivers import open_recording
    from stillpoint.engine.outcomes.steps import StepOperator
    src = open_recording(real / "ax3_openmovement_example_610_steps_fw30_nofrac.cwa")
    op = StepOperator()
    for b in src:
        op.push(SimpleNamespace(time_ns=b.time_ns, accel=b.accel_g(), segment=b.segment))
    src.close()
    op.flush()
    return {s: int(t.shape[0]) for s, t in op.take().items()}


def simulated(seeds: int, hz: float, site: str) -> dict:
    from stillpoint.engine.outcomes.steps import StepOperator
    from stillpoint.engine.sim.wearer import ACTIVITIES, SiteModel, WearerParams, make_schedule
    out = {}  # (activity, set) -> list of (true, counted)
    for seed in range(1, seeds + 1):
        sch = make_schedule(WearerParams(), 3 * 86400.0, seed=seed)
        model = SiteModel(sch, site, seed=seed)
        for i in np.flatnonzero(sch.step_hz > 0):
            a, b = float(sch.start[i]), float(sch.end[i])
            if b - a < 60.0:
                continue
            act = ACTIVITIES[int(sch.activity[i])]
            t = np.arange(a - 10.0, b + 10.0, 1.0 / hz)
            f, _ = model.render(t)
            op = StepOperator()
            op.push(SimpleNamespace(time_ns=np.round(t * 1e9).astype(np.int64), accel=f, segment=0))
            op.flush()
            true = int(((sch.steps >= a) & (sch.steps < b)).sum())
            for s, st in op.take().items():
                n = int(((st >= a * 1e9) & (st < b * 1e9)).sum())
                out.setdefault((act, s), []).append((true, n))
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--real", type=Path, default=os.environ.get("STILLPOINT_REAL_DATA"))
    ap.add_argument("--seeds", type=int, default=6)
    ap.add_argument("--hz", type=float, default=50.0)
    ap.add_argument("--site", default="wrist")
    args = ap.parse_args()
    if args.real:
        counts = real_walk(Path(args.real))
        for s, n in counts.items():
            print(f"real walk ({TRUE_STEPS} counted steps): {s}: {n} steps "
                  f"({100.0 * (n - TRUE_STEPS) / TRUE_STEPS:+.1f} %)")
    res = simulated(args.seeds, args.hz, args.site)
    print(f"\nsimulated {args.site}, {args.seeds} wearers x 3 days, bouts >= 60 s, {args.hz:g} Hz")
    print(f"{'activity':9} {'set':13} {'bouts':>5} {'true':>7} {'counted':>7} {'bias %':>7} "
          f"{'MAPE %':>7}")
    for (act, s), pairs in sorted(res.items()):
        p = np.array(pairs, float)
        bias = 100.0 * (p[:, 1].sum() - p[:, 0].sum()) / p[:, 0].sum()
        mape = 100.0 * np.mean(np.abs(p[:, 1] - p[:, 0]) / p[:, 0])
        print(f"{act:9} {s:13} {p.shape[0]:5d} {int(p[:, 0].sum()):7d} {int(p[:, 1].sum()):7d} "
              f"{bias:+7.1f} {mape:7.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
