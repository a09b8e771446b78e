"""Print the agreement of the day table's imputed M10 / L5 (``--impute``: ``m10_mg_imputed``,
``m10_start_imputed``, ``l5_mg_imputed``, ``l5_start_imputed``, ``ra_imputed``) with GGIR's
part 2 on the same imputed days: g.analyse.perday's own lines that bring a day to 24 h, then
g.getM5L5 with its window end (tools/crosschecks/ggir_m5l5.R).

    python tools/crosschecks/ggir_m5l5.py --ggir PATH/TO/GGIR

Scenarios: the windows crosscheck's simulated weeks (tools/crosschecks/ggir_part5_windows.py:
waking activity, an afternoon and some nights of nonwear; a recording cut mid-night and a spring
DST week with its 23-h day). Every local day is compared, valid or not (the day table keeps the
valid ones). ``--write``: keep GGIR's figures as tests/data/ggir_m5l5/<scenario>.json (the
fixtures of tests/engine/outcomes/test_outcomes_impute.py).
"""

from __future__ import annotations

import argparse
import csv
import subprocess
import sys
import tempfile
from pathlib import Path


HERE = Path(__file__).resolve().parent
OUT = HERE.parents[1] / "tests" / "data" / "ggir_m5l5"
EPOCH_S = 5.0


def _hhmm(h: float) -> str:
    """GGIR's decimal hour (+24 below 12, R/g.getM5L5.R:55-60) as HH:MM."""
    m = int(round(h * 60)) % 1440
    return f"{m // 60:02d}:{m % 60:02d}"


def check(ggir: Path, td: Path, name: str, spec, write: bool = False) -> tuple:
    sys.path.insert(0, str(HERE))
    import ggir_part5_windows as p5
    from stillpoint.engine.outcomes.impute import AverageDay, imputed_days
    s, sib, spt, nights, clean, imp = p5.scenario_inputs(spec)
    local = s.zone.local_ns(s.t_ns)
    day = local // (86400 * 10**9)
    av = AverageDay(EPOCH_S)
    av.push({"enmo_mg": s.enmo, "mad_mg": s.enmo}, clean, day, local)
    ours = imputed_days(av)
    av.close()
    with open(td / "days.csv", "w") as f:
        f.write("day,enmo_g\n")
        for d, v in zip((day - day[0]).tolist(), (imp / 1000.0).tolist()):
            f.write(f"{d},{v!r}\n")
    with open(td / "avday.csv", "w") as f:
        f.write("enmo_g\n")
        for v in (av.profile("enmo_mg") / 1000.0).tolist():
            f.write(f"{v!r}\n")
    r = subprocess.run(["Rscript", str(HERE / "ggir_m5l5.R"), str(ggir / "R"), str(td / "days.csv"),
                        str(td / "avday.csv"), str(td / "out.csv")], capture_output=True, text=True)
    if r.returncode:
        sys.exit(f"Rscript failed: {r.stderr.strip().splitlines()[-3:]}")
    theirs = list(csv.DictReader(open(td / "out.csv")))
    dates = sorted(ours)
    if write:
        import dataclasses
        import json
        OUT.mkdir(parents=True, exist_ok=True)
        fx = {"spec": dataclasses.asdict(spec), "ggir_commit": p5._commit(ggir),
              "days": [{"date": dates[int(g["day"])], **{k: (None if g.get(k) in (None, "", "NA") else float(g[k]))
                                                          for k in ("L5hr", "L5", "M10hr", "M10")}}
                       for g in theirs]}
        (OUT / f"{name}.json").write_text(json.dumps(fx, indent=1) + "\n")
    same = total = 0
    worst = 0.0
    for g in theirs:
        o = ours[dates[int(g["day"])]]
        for key, col, hr in (("m10", "M10", "M10hr"), ("l5", "L5", "L5hr")):
            gv = None if g.get(col) in (None, "", "NA") else float(g[col])
            ov = o[f"{key}_mg_imputed"]
            total += 1
            if gv is None or ov is None:
                same += gv is None and ov is None
                continue
            worst = max(worst, abs(ov - gv))
            same += abs(ov - gv) <= 1e-9 * max(1.0, abs(gv)) and o[f"{key}_start_imputed"] == _hhmm(float(g[hr]))
    return same, total, worst, len(theirs)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ggir", type=Path, required=True)
    ap.add_argument("--write", action="store_true", help="keep GGIR's figures as the test fixtures")
    a = ap.parse_args(argv)
    sys.path.insert(0, str(HERE))
    import ggir_part5_windows as p5
    with tempfile.TemporaryDirectory() as td:
        for name, spec in p5.scenarios().items():
            same, total, worst, days = check(a.ggir, Path(td), name, spec, a.write)
            print(f"{name}: {days} days, M10/L5 value and start equal {same}/{total} "
                  f"(max |diff| {worst:.2e} mg)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
