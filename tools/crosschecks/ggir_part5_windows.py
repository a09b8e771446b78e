"""Print the agreement of our windows table with GGIR part 5's own code on the same epochs: the
windows (``g.part5.definedays`` looped as ``g.part5`` does) and every time-use column of every
window (``identify_levels`` on the whole series, then ``g.part5_analyseSegment`` per window).

    python tools/crosschecks/ggir_part5_windows.py --ggir PATH/TO/GGIR [--real DIR]

R needs ``zoo`` (``apt-get install r-cran-zoo``). Scenarios: the rhythm crosscheck's simulated
weeks (tools/crosschecks/ggir_rhythm_fixtures.py: a default wearer, a shift worker sleeping by
day, a recording cut mid-night, a spring DST week), our sleep periods and SIBs on them. GGIR's
part 5 reads part 2's imputed series (nonwear epochs carry their slot's mean over the other days),
so GGIR is given our imputed series (engine/outcomes/impute.py, as ``--impute`` does) and compared
with our table computed with ``imputed=True``; the same windows without ``--impute`` (epochs that
are not clean left out) are then compared with GGIR's to show what imputation changes.
Each scenario is given waking activity (light, MVPA and running stretches: ``active_per_day``)
and an afternoon of nonwear (``nonwear_days``) so every bout class and the imputation are used.
``--write``: also keep GGIR's figures as tests/data/ggir_part5/<scenario>.json (the fixtures of
tests/engine/timeuse/test_timeuse_ggir.py). ``--real DIR``: also each real recording there through ``process``
(UTC, sleep on; the rhythm crosscheck's ``real_series``): GGIR's part 5 on its epoch table's
series against its windows table.
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
OUT = HERE.parents[1] / "tests" / "data" / "ggir_part5"
EPOCH_S = 5.0


def scenarios() -> dict:
    """The rhythm crosscheck's weeks with waking activity and an afternoon off the wrist."""
    import dataclasses
    sys.path.insert(0, str(HERE))
    import ggir_rhythm_fixtures as rf
    return {name: dataclasses.replace(spec, active_per_day=8.0, nonwear_days=(2,))
            for name, spec in rf.scenarios().items()}


def scenario_inputs(spec):
    """(series, SIBs, sleep periods, nights, clean, imputed ENMO) of a scenario."""
    sys.path.insert(0, str(HERE))
    import ggir_rhythm_fixtures as rf
    from stillpoint.engine.outcomes.impute import AverageDay
    from stillpoint.engine.sleep import SleepStage
    from stillpoint.engine.tables.epochs import EpochRows
    s, sib, spt = rf.scenario_series(spec)
    st = SleepStage(s.zone, EPOCH_S)  # the nights again (scenario_series keeps only the flags)
    n = s.t_ns.shape[0]
    for i in range(0, n, 4000):
        j = min(n, i + 4000)
        z = np.zeros(j - i, bool)
        st.push(EpochRows(s.t_ns[i:j], np.full(j - i, 500), s.enmo[i:j], z * 0.0, z * 0.0,
                          s.anglez[i:j], z * 0.0, s.nonwear[i:j], z.copy(), z.copy(),
                          z.copy(), z.copy()))
    st.flush()
    clean = ~s.nonwear
    av = AverageDay(EPOCH_S)
    av.push({"enmo_mg": s.enmo, "mad_mg": s.enmo}, clean, np.zeros(n, np.int64))
    return s, sib.astype(bool), spt.astype(bool), st.nights, clean, av.fill("enmo_mg", s.enmo, clean)


def ggir_windows(ggir: Path, p: Path, tz: str, t_s, diur, acc, sib, nonwear) -> list:
    with open(p, "w") as f:
        f.write("time_s,diur,acc,sib,nonwear\n")
        for row in zip(np.asarray(t_s).tolist(), np.asarray(diur, int).tolist(), np.asarray(acc).tolist(),
                       np.asarray(sib, int).tolist(), np.asarray(nonwear, int).tolist()):
            f.write("%d,%d,%r,%d,%d\n" % row)
    r = subprocess.run(["Rscript", str(HERE / "ggir_part5_windows.R"), str(ggir / "R"), str(p), tz,
                        str(p) + ".out"], capture_output=True, text=True)
    if r.returncode:
        sys.exit(f"Rscript failed: {r.stderr.strip().splitlines()[-3:]}")
    return list(csv.DictReader(open(str(p) + ".out")))


def _num(v):
    if v in (None, "", "NA", "NaN"):
        return None
    return float(v)


def compare(rows: list, theirs: list, t_ns, zone) -> tuple:
    """(per-type window agreement lines, per-column {column: (equal, compared, max |diff|)}), the
    windows paired by type, first epoch and length."""
    from stillpoint.engine.timeuse.windows import TIMEUSE_COLUMNS
    from stillpoint.engine.timezones import local_text
    def val(v):
        return None if v in (None, "") else float(v)
    lines, cols = [], {c: [0, 0, 0.0] for c in TIMEUSE_COLUMNS + ["nonwear_perc_day", "nonwear_perc_spt",
                                                                  "nonwear_perc_day_spt"]}
    for kind in ("WW", "MM", "OO"):
        mine = {(x["start_local"], round(float(x["duration_h"]) * 3600 / EPOCH_S)): x
                for x in rows if x["window_type"] == kind}
        g = [x for x in theirs if x["type"] == kind]
        same = 0
        for x in g:
            f0, f1 = int(float(x["first"])) - 1, int(float(x["last"]))
            m = mine.get((local_text(int(t_ns[f0]), zone), f1 - f0))
            if m is None:
                continue
            same += 1
            for c, acc in cols.items():
                a, b = val(m.get(c)), _num(x.get(c))
                if a is None and b is None:
                    acc[0] += 1
                    acc[1] += 1
                    continue
                if a is None or b is None:
                    acc[1] += 1
                    continue
                d = abs(float(a) - b)
                acc[0] += d <= 1e-9 * max(1.0, abs(b))
                acc[1] += 1
                acc[2] = max(acc[2], d)
        lines.append(f"{kind} {same}/{len(g)} GGIR windows equal ({len(mine)} ours)")
    return lines, cols


def summary(cols: dict) -> str:
    n_eq = sum(1 for v in cols.values() if v[0] == v[1])
    cells = sum(v[1] for v in cols.values())
    eq = sum(v[0] for v in cols.values())
    worst = sorted(((v[2], c) for c, v in cols.items() if v[0] != v[1]), reverse=True)[:4]
    w = "; ".join(f"{c} max |diff| {d:.6g}" for d, c in worst)
    return f"{n_eq}/{len(cols)} columns equal in every window, {eq}/{cells} cells" + (f"; differ: {w}" if w else "")


def scenario_check(ggir: Path, td: Path, name: str, spec, write: bool = False) -> None:
    from stillpoint.engine.timeuse import time_use
    from stillpoint.engine.timeuse.windows import TIMEUSE_COLUMNS
    s, sib, spt, nights, clean, imp = scenario_inputs(spec)
    theirs = ggir_windows(ggir, td / f"{name}.csv", spec.timezone, s.t_ns // 10**9, spt, imp, sib, s.nonwear)
    for label, value, imputed in (("--impute", imp, True), ("no --impute", s.enmo, False)):
        rows = time_use(s.t_ns, value, clean, s.nonwear, sib, spt, nights, s.zone, EPOCH_S,
                        imputed=imputed)
        lines, cols = compare(rows, theirs, s.t_ns, s.zone)
        if imputed:
            print(f"{name}: " + "; ".join(lines))
        print(f"  {label}: {summary(cols)}")
    if write:
        import dataclasses
        import json
        keep = ["type", "first", "last"] + TIMEUSE_COLUMNS + ["nonwear_perc_day", "nonwear_perc_spt",
                                                             "nonwear_perc_day_spt"]
        OUT.mkdir(parents=True, exist_ok=True)
        fx = {"spec": dataclasses.asdict(spec), "ggir_commit": _commit(ggir),
              "windows": [{k: _num(x.get(k)) if k != "type" else x[k] for k in keep} for x in theirs]}
        (OUT / f"{name}.json").write_text(json.dumps(fx, indent=1) + "\n")


def _commit(ggir: Path) -> str:
    r = subprocess.run(["git", "-C", str(ggir), "rev-parse", "HEAD"], capture_output=True, text=True)
    return r.stdout.strip()


def real_check(ggir: Path, td: Path, real: Path) -> None:
    """process on each real recording; GGIR's part 5 on its epoch table's series."""
    import ggir_rhythm_fixtures as rf
    for p in sorted(real.iterdir()):
        if p.suffix not in (".cwa", ".bin", ".gz", ".gt3x"):
            continue
        got = rf.real_series(p, td)
        if got is None:
            print(f"{p.name}: not processed")
            continue
        s, sib, spt = got
        ours = list(csv.DictReader(open(td / (p.name + ".windows.csv"))))
        theirs = ggir_windows(ggir, td / "real.csv", "UTC", s.t_ns // 10**9, spt, s.enmo, sib, s.nonwear)
        lines, cols = compare(ours, theirs, s.t_ns, s.zone)
        print(f"{p.name} ({s.t_ns.shape[0]} epochs, {int(np.sum(spt))} in sleep periods): {len(theirs)} "
              f"GGIR windows, {len(ours)} ours; " + "; ".join(lines) + f"; {summary(cols)}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ggir", type=Path, required=True)
    ap.add_argument("--only", default=None, help="one scenario by name")
    ap.add_argument("--write", action="store_true", help="keep GGIR's figures as the test fixtures")
    ap.add_argument("--real", type=Path, help="folder of real recordings (printed, not stored)")
    a = ap.parse_args(argv)
    sys.path.insert(0, str(HERE))
    with tempfile.TemporaryDirectory() as td:
        if a.real:
            real_check(a.ggir, Path(td), a.real)
        for name, spec in scenarios().items():
            if a.only and name != a.only:
                continue
            scenario_check(a.ggir, Path(td), name, spec, a.write)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
