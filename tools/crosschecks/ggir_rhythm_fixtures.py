"""Regenerate tests/data/ggir_rhythm/: GGIR's own rhythm functions run on our epoch series.

    python tools/crosschecks/ggir_rhythm_fixtures.py --ggir PATH/TO/GGIR --actcr ActCR.R [--check]

``--ggir``: a checkout of wadpac/GGIR (its R/ folder is sourced; the fixtures record the commit).
``--actcr``: an R file defining ActCR 0.3.0's ``ActCosinor`` and ``ActExtendCosinor`` (with
cosinor's ``cosinor.lm`` and cosinor2's ``correct.acrophase``), which GGIR calls as ``ActCR::``.
R needs ``zoo`` and ``minpack.lm`` (``apt-get install r-cran-zoo r-cran-minpack.lm``).
Per scenario (engine/sim/sleep.py weeks: a default wearer, a shift worker sleeping by day, a
recording cut mid-night, a spring DST week with nonwear nights) the series (ENMO, invalid flags,
local midnights, our SIBs and sleep periods) goes to ``ggir_rhythm_fixtures.R``
(``apply_cosinor_IS_IV_Analyses`` as GGIR part 2 calls it, ``CalcSleepRegularityIndex`` as part
3, ``g.fragmentation`` as part 6) and GGIR's figures are kept as ``<scenario>.json``.
``--check``: print our agreement with the new figures instead of writing. ``--real DIR``: also
each real recording there, through ``process`` (UTC, sleep on): GGIR's functions on our epoch
table's series, the agreement printed (recordings of a few hours: GGIR fits no cosinor and no SRI
on less than a day, and neither do we).
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import json
import subprocess
import sys
import tempfile
from dataclasses import asdict
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
OUT = ROOT / "tests" / "data" / "ggir_rhythm"
EPOCH_S = 5.0
# our rhythm column -> GGIR's figure in the .cosinor.csv row
COSINOR_FIELDS = {
    "time_offset_h": "timeOffsetHours", "cosinor_mesor": "mes", "cosinor_amplitude": "amp",
    "cosinor_acrophase_rad": "acr", "cosinor_acrophase_h": "acrotime", "cosinor_days": "ndays",
    "cosinor_r2": "R2", "ext_minimum": "ext_minimum", "ext_amplitude": "ext_amp",
    "ext_alpha": "ext_alpha", "ext_beta": "ext_beta", "ext_acrophase_h": "ext_acrotime",
    "ext_f_pseudo": "ext_F_pseudo", "ext_up_mesor_h": "ext_UpMesor",
    "ext_down_mesor_h": "ext_DownMesor", "ext_mesor": "ext_MESOR", "ext_r2": "ext_R2",
    "is": "IS", "iv": "IV", "phi": "phi"}


def scenarios():
    from stillpoint.engine.sim.sleep import SleepSpec
    return {
        "default_week": SleepSpec("2026-05-04T10:00:00", "Europe/London", 7.0, seed=31),
        "shift_worker": SleepSpec("2026-05-04T10:00:00", "Europe/London", 7.0, seed=32,
                                  daysleeper_nights=(1, 2, 3, 4, 5)),
        "cut_mid_night": SleepSpec("2026-05-04T10:00:00", "Europe/London", 4 + 17 / 24, seed=33,
                                   nonwear_nights=(2,)),
        "spring_dst_week": SleepSpec("2026-03-25T10:00:00", "Europe/London", 7.0, seed=34,
                                     nonwear_nights=(1, 4)),
    }


def scenario_series(spec):
    """The simulated week and our sleep operators' SIBs and sleep periods on it."""
    from stillpoint.engine.sim.sleep import sleep_scenario
    from stillpoint.engine.sleep import SleepStage
    from stillpoint.engine.tables.epochs import EpochRows
    s = sleep_scenario(spec)
    st = SleepStage(s.zone, EPOCH_S)
    n = s.t_ns.shape[0]
    sib, spt = [], []
    for a in range(0, n + 1, 4000):
        b = min(n, a + 4000)
        z = np.zeros(b - a, bool)
        out = st.push(EpochRows(s.t_ns[a:b], np.full(b - a, 500), s.enmo[a:b], z * 0.0, z * 0.0,
                                s.anglez[a:b], z * 0.0, s.nonwear[a:b], z.copy(), z.copy(),
                                z.copy(), z.copy())) if b > a else []
        for _, p, q in out:
            spt.append(p)
            sib.append(q)
    for _, p, q in st.flush():
        spt.append(p)
        sib.append(q)
    return s, np.concatenate(sib), np.concatenate(spt)


def series_digest(enmo, invalid, sib) -> str:
    return hashlib.sha256(np.asarray(enmo, np.float64).tobytes() + np.asarray(invalid, bool).tobytes()
                          + np.asarray(sib, np.int8).tobytes()).hexdigest()


def write_series(path: Path, s, sib, spt) -> None:
    from stillpoint.engine.rhythm.series import local_midnights, part5_classes
    off = s.zone.offsets_s(s.t_ns)
    local = np.datetime_as_string((s.t_ns + off * 10**9).astype("datetime64[ns]").astype("datetime64[s]"))
    mid = np.zeros(s.t_ns.shape[0], bool)
    mid[local_midnights(s.t_ns, s.zone)] = True
    lv, _ = part5_classes(s.enmo, s.nonwear, sib, spt, EPOCH_S)
    with open(path, "w") as f:
        f.write("time_s,local,enmo_g,invalid,midnight,sib,level,spt\n")
        for t, lt, o, e, nw, m, sb, c, sp in zip((s.t_ns // 10**9).tolist(), local.tolist(), off.tolist(),
                                                 (s.enmo / 1000.0).tolist(), s.nonwear.tolist(),
                                                 mid.tolist(), sib.tolist(), lv.level.tolist(),
                                                 np.asarray(spt, bool).tolist()):
            sign = "-" if o < 0 else "+"
            mm = abs(int(o)) // 60
            cc = "NA" if c < 0 else str(int(c))
            f.write(f"{t},{lt}{sign}{mm // 60:02d}{mm % 60:02d},{e!r},{int(nw)},{int(m)},{int(sb)},{cc},"
                    f"{int(sp)}\n")


def run_ggir(ggir: Path, actcr: Path, series: Path, tz: str, prefix: Path) -> dict:
    cmd = ["Rscript", str(HERE / "ggir_rhythm_fixtures.R"), str(ggir / "R"), str(actcr), str(series),
           tz, str(prefix)]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode:
        sys.exit(f"Rscript failed: {r.stderr.strip().splitlines()[-3:]}")

    def rows(name):
        p = Path(f"{prefix}.{name}.csv")
        return list(csv.DictReader(open(p))) if p.exists() else []

    def num(v):
        return None if v in ("NA", "NaN", "") else float(v)
    cos = rows("cosinor")
    return {"cosinor": {k: num(v) for k, v in cos[0].items()} if cos else None,
            "sri": [{"date": r["date"], "sri": num(r["sri"]), "frac_valid": num(r["frac_valid"])}
                    for r in rows("sri")],
            "frag": {k: num(v) for k, v in rows("frag")[0].items()}}


def ours(s, sib, spt) -> dict:
    from stillpoint.engine.rhythm import metrics
    from stillpoint.engine.rhythm.series import rhythm_row
    row = rhythm_row(s.t_ns, s.enmo, s.nonwear, s.zone, EPOCH_S, sib=sib, spt=spt)
    pairs = metrics.sleep_regularity(sib, s.nonwear, s.t_ns // 10**9, s.zone.offsets_s(s.t_ns), EPOCH_S)
    return {"row": row, "sri": pairs}


def frag_pairs(row: dict, frag: dict) -> dict:
    """our column -> (ours, GGIR's) of every g.fragmentation figure."""
    from stillpoint.engine.rhythm import metrics
    from stillpoint.engine.rhythm.series import frag_column
    out = {}
    for mode, names in (("day", metrics.FRAG_DAY), ("spt", metrics.FRAG_SPT)):
        for k in names:
            out[frag_column(k, mode)] = (row.get(frag_column(k, mode)), frag.get(f"{k}_{mode}"))
    return out


def frag_agreement(row: dict, frag: dict) -> str:
    pairs = frag_pairs(row, frag)
    same = [c for c, (a, b) in pairs.items()
            if (a is None and b is None) or (a is not None and b is not None
                                             and abs(a - b) <= 1e-9 * max(1.0, abs(b)))]
    diff = [c for c in pairs if c not in same]
    defined = sum(1 for a, b in pairs.values() if b is not None)
    worst = max((abs(pairs[c][0] - pairs[c][1]) for c in same if pairs[c][1] is not None), default=0.0)
    return (f"fragmentation {len(same)}/{len(pairs)} figures equal ({defined} defined by GGIR, "
            f"max |diff| {worst:.2e})" + (f", differ: {diff}" if diff else ""))


def report(name: str, fx: dict, got: dict) -> None:
    """Print the largest differences from GGIR's figures."""
    row = got["row"]
    parts = []
    if fx["cosinor"]:
        diffs = {k: abs(row[k] - fx["cosinor"][v]) for k, v in COSINOR_FIELDS.items()
                 if row[k] is not None and fx["cosinor"][v] is not None}
        exact = [k for k in diffs if not k.startswith("ext_") and k != "phi"]
        parts.append(f"IS/IV/cosinor max |diff| {max(diffs[k] for k in exact):.2e}")
        parts.append(f"phi {diffs['phi']:.2e}")
        parts.append(f"extended cosinor max |diff| {max(v for k, v in diffs.items() if k.startswith('ext_')):.2e}")
    else:
        parts.append("no cosinor (GGIR: not enough data)" if row["is"] is None else "GGIR fitted nothing, we did")
    sri = {d: (v, f) for d, v, f in got["sri"]}
    same = sum(sri.get(r["date"]) == (r["sri"], r["frac_valid"]) for r in fx["sri"])
    parts.append(f"SRI day pairs {same}/{len(fx['sri'])} equal")
    parts.append(frag_agreement(row, fx["frag"]))
    print(f"{name}: " + "; ".join(parts))


class _Series:
    """An epoch table read back as the simulated series' fields (t_ns, enmo, nonwear, zone)."""

    def __init__(self, t_ns, enmo, nonwear, zone):
        self.t_ns, self.enmo, self.nonwear, self.zone = t_ns, enmo, nonwear, zone


def real_series(path: Path, tmp: Path):
    """``process`` on a real recording (UTC, sleep on) and its epoch table's series: (series,
    sib, spt), invalid = not clean; None when it cannot be processed or has no epochs."""
    import gzip
    from stillpoint.engine.timezones import parse_zone
    out = tmp / (path.name + ".mcap")
    exe = Path(sys.executable).with_name("stillpoint")
    extra = ["--timezone-override"] if path.suffix == ".bin" else []  # GENEActiv: header zone
    r = subprocess.run([str(exe), "process", str(path), "-o", str(out), "--timezone", "UTC", "-q",
                        "--overwrite"] + extra, capture_output=True, text=True)
    if r.returncode:
        return None
    stem = out.name[:-5]
    rows = list(csv.DictReader(gzip.open(out.with_name(stem + ".epochs.csv.gz"), "rt")))
    if not rows or "sib" not in rows[0]:
        return None
    t = np.array([np.datetime64(x["time_utc"][:-1], "ns").astype(np.int64) for x in rows])
    enmo = np.array([float(x["enmo_mg"]) if x["enmo_mg"] else np.nan for x in rows])
    flags = ("nonwear", "clipping", "gap", "qc", "filter_warmup")
    inv = np.array([any(x[f] == "1" for f in flags) for x in rows])
    sib = np.array([x["sib"] == "1" for x in rows], np.int8)
    spt = np.array([x["spt"] == "1" for x in rows])
    return _Series(t, np.where(inv, 0.0, enmo), inv, parse_zone("UTC")), sib, spt


def ggir_commit(ggir: Path) -> str:
    r = subprocess.run(["git", "-C", str(ggir), "rev-parse", "HEAD"], capture_output=True, text=True)
    return r.stdout.strip() or "unknown"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ggir", type=Path, required=True, help="wadpac/GGIR checkout")
    ap.add_argument("--actcr", type=Path, required=True, help="R file with ActCR's functions")
    ap.add_argument("--check", action="store_true", help="print agreement, write nothing")
    ap.add_argument("--only", help="one scenario")
    ap.add_argument("--real", type=Path, help="folder of real recordings (printed, not stored)")
    a = ap.parse_args(argv)
    commit = ggir_commit(a.ggir)
    OUT.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as td:
        tmp = Path(td)
        for name, spec in scenarios().items():
            if a.only and name != a.only:
                continue
            s, sib, spt = scenario_series(spec)
            write_series(tmp / f"{name}.csv", s, sib, spt)
            res = run_ggir(a.ggir, a.actcr, tmp / f"{name}.csv", spec.timezone, tmp / name)
            fx = {"ggir_commit": commit, "actcr": "0.3.0", "spec": asdict(spec),
                  "series_sha256": series_digest(s.enmo, s.nonwear, sib), **res}
            report(name, fx, ours(s, sib, spt))
            if not a.check:
                (OUT / f"{name}.json").write_text(json.dumps(fx, indent=1) + "\n")
        for p in sorted(a.real.iterdir()) if a.real else []:
            if p.suffix not in (".cwa", ".bin", ".gz", ".gt3x"):
                continue
            got = real_series(p, tmp)
            if got is None:
                continue
            s, sib, spt = got
            write_series(tmp / "real.csv", s, sib, spt)
            res = run_ggir(a.ggir, a.actcr, tmp / "real.csv", "UTC", tmp / "real")
            report(f"{p.name} ({s.t_ns.shape[0]} epochs)", res, ours(s, sib, spt))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
