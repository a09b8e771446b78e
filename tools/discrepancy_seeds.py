"""The 20-seed table of the discrepancy workflow's hidden-effect tests (issue 6).

For every scenario of engine.workflows.scenarios (one hidden effect each, the null control with
nothing hidden, and two hidden effects) and every seed: simulate a wrist recording at the window
level through the simulator's sensor model, run the workflow from a starting model lacking the
effect, and check that it (1) names exactly the hidden effect(s) and axis, larger first, (2)
recovers the parameter within tolerance, (3) brings the held-out gap within 1.2x of the true model's.

    /work/venv/bin/python tools/discrepancy_seeds.py [--seeds 20] [--days 7] [--only thermal_lag,none]
        [--jobs 2] [--packed]

Prints one row per scenario (counts out of the seeds, parameter error, gap ratio, time per seed)
and exits 1 when a scenario falls short of 19/20 (scaled to the seed count).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np


def _one(args):
    name, seed, days, lsb = args
    from stillpoint.engine.workflows import scenarios
    t = time.perf_counter()
    o = scenarios.run(name, seed, days=days, lsb_g=lsb)
    return o, time.perf_counter() - t


def main(argv=None) -> int:
    from stillpoint.engine.workflows import scenarios

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--days", type=float, default=7.0)
    ap.add_argument("--only", help="comma-separated scenarios (default: all)")
    ap.add_argument("--jobs", type=int, default=1, help="worker processes")
    ap.add_argument("--packed", action="store_true",
                    help="quantise to the AX3 packed +-8 g step (4/256 g) instead of 1/256 g")
    ap.add_argument("-v", "--verbose", action="store_true", help="print every failing seed")
    a = ap.parse_args(argv)
    names = a.only.split(",") if a.only else list(scenarios.SCENARIOS)
    need = math.ceil(19 / 20 * a.seeds)
    lsb = scenarios.LSB_PACKED_8G_G if a.packed else scenarios.LSB_UNPACKED_G
    work = [(n, s, a.days, lsb) for n in names for s in range(a.seeds)]
    t0 = time.perf_counter()
    if a.jobs > 1:
        with ProcessPoolExecutor(a.jobs) as ex:
            results = list(ex.map(_one, work))
    else:
        results = [_one(w) for w in work]
    print(f"discrepancy workflow, hidden-effect table: {a.seeds} seeds x {a.days:g}-day wrist "
          f"recordings (window level, simulator's sensor model, quantisation step "
          f"{lsb * 1000:.1f} mg); pass needs >= {need}/{a.seeds}")
    hdr = (f"{'scenario':<19}{'named':>7}{'param':>7}{'gap':>7}{'all':>7}  "
           f"{'param err (median, max)':<28}{'gap/true (max)':>15}{'windows':>9}{'s/seed':>8}")
    print(hdr)
    print("-" * len(hdr))
    short = []
    for name in names:
        rows = [(o, dt) for o, dt in results if o.scenario == name]
        outs = [o for o, _ in rows]
        named = sum(o.named_ok for o in outs)
        par = sum(o.params_ok for o in outs)
        gap = sum(o.gap_ok for o in outs)
        allok = sum(o.ok for o in outs)
        errs = [abs(r - t) for o in outs for r, t in zip(o.recovered, o.true_values) if r is not None]
        unit = {"temperature_offset": "mg/C", "temperature_gain": "%/C", "misalignment": "%",
                "thermal_lag": "s", "offset_drift": "mg/day", "nonlinearity": "mg/g2",
                "two": "", "none": ""}.get(name, "")
        e = f"{np.median(errs):.3g}, {max(errs):.3g} {unit}" if errs else "-"
        ratio = max(o.gap_ratio for o in outs)
        print(f"{name:<19}{named:>5}/{a.seeds:<1}{par:>5}/{a.seeds:<1}{gap:>5}/{a.seeds:<1}"
              f"{allok:>5}/{a.seeds:<1}  {e:<28}{ratio:>15.3f}{int(np.mean([o.windows for o in outs])):>9}"
              f"{np.mean([dt for _, dt in rows]):>8.2f}")
        if allok < need:
            short.append(name)
        if a.verbose:
            for o in outs:
                if not o.ok:
                    print(f"    seed {o.seed}: named {o.named} (expected {o.expected}), "
                          f"recovered {o.recovered} (true {o.true_values}), gap ratio {o.gap_ratio:.3f}")
    print(f"total {time.perf_counter() - t0:.1f} s")
    if short:
        print(f"below {need}/{a.seeds}: {', '.join(short)}")
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
