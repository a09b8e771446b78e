"""Regenerate tests/data/ggir_sleep/: GGIR's own sleep functions run on the same 5 s series.

    python tools/crosschecks/ggir_sleep_fixtures.py --ggir PATH/TO/GGIR [--real DIR] [--check]

``--ggir``: a checkout of wadpac/GGIR (its R/ folder is sourced; the fixtures record the commit).
R must have the ``zoo`` package (``apt-get install r-cran-zoo``, or ``R_LIBS`` pointing at one).
Per scenario (engine/sim/sleep.py, a simulated week: DST nights, a daysleeper, nonwear at
night, a recording starting at 02:00, each HASPT.ignore.invalid option) the series goes to
``ggir_sleep_fixtures.R`` (g.sib.det with HASIB vanHees2015 and HASPT HDCZA, GGIR's defaults) and
GGIR's decisions are kept as ``<scenario>.json``: every HASPT call (window, SPTE_start, SPTE_end,
threshold, guider), the nights' hours and the SIB runs. ``--real DIR``: the anglez and nonwear of
our epoch table for each real recording there are kept with GGIR's SIBs on them (recordings
shorter than GGIR's 0.2-day minimum have no night). ``--check``: print the agreement of our
operators with the new fixtures (what tests/engine/sleep/test_sleep_ggir.py asserts) instead of writing.
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
OUT = ROOT / "tests" / "data" / "ggir_sleep"
GGIR_FILES = ("HASIB.R", "HASPT.R", "g.sib.det.R", "g.detecmidnight.R", "iso8601chartime2POSIX.R",
              "load_params.R")


def scenarios():
    from stillpoint.engine.sim.sleep import SleepSpec
    return {
        "spring_dst_week": (SleepSpec("2026-03-25T10:00:00", "Europe/London", 7.0, seed=11,
                                      daysleeper_nights=(1,), nonwear_nights=(4,)), "FALSE"),
        "autumn_dst_week": (SleepSpec("2026-10-21T10:00:00", "Europe/London", 7.0, seed=12,
                                      daysleeper_nights=(5,), nonwear_nights=(2,)), "FALSE"),
        "early_start": (SleepSpec("2026-06-10T02:00:00", "America/New_York", 3.5, seed=13), "FALSE"),
        "nonwear_as_nomovement": (SleepSpec("2026-05-04T09:00:00", "UTC", 4.0, seed=14,
                                            nonwear_nights=(1, 2)), "NA"),
        "nonwear_as_movement": (SleepSpec("2026-05-04T09:00:00", "UTC", 4.0, seed=15,
                                          nonwear_nights=(1,)), "TRUE"),
    }


def write_series(path: Path, t_ns, zone, anglez, invalid) -> None:
    off = zone.offsets_s(t_ns)
    local = np.datetime_as_string((t_ns + off * 10**9).astype("datetime64[ns]").astype("datetime64[s]"))
    with open(path, "w") as f:
        f.write("timestamp,anglez,ENMO,invalid\n")
        for i, (tt, o, a, nw) in enumerate(zip(local.tolist(), off.tolist(), anglez.tolist(),
                                               invalid.tolist())):
            sign = "-" if o < 0 else "+"
            m = abs(int(o)) // 60
            f.write(f"{tt}{sign}{m // 60:02d}{m % 60:02d},{float(a)!r},{i + 1},{int(nw)}\n")


def series_digest(anglez, invalid) -> str:
    """SHA-256 of the series GGIR was given (anglez as float64, then the invalid flags as bytes):
    the tests rebuild the series from the spec and check it is the same."""
    import hashlib
    return hashlib.sha256(np.asarray(anglez, np.float64).tobytes()
                          + np.asarray(invalid, bool).tobytes()).hexdigest()


def run_ggir(ggir: Path, series: Path, tz: str, ignore: str, prefix: Path) -> dict:
    cmd = ["Rscript", str(HERE / "ggir_sleep_fixtures.R"), str(ggir / "R"), str(series), tz, ignore,
           str(prefix)]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode:
        sys.exit(f"Rscript failed: {r.stderr.strip().splitlines()[-1:]}")

    def rows(name):
        p = Path(f"{prefix}.{name}.csv")
        return list(csv.DictReader(open(p))) if p.exists() else []
    calls = [{"first": int(float(c["first"])), "n": int(c["n"]),
              "start": None if c["start"] == "NA" else int(float(c["start"])),
              "end": None if c["end"] == "NA" else int(float(c["end"])),
              "threshold": float(c["threshold"]), "guider": c["guider"]} for c in rows("calls")]
    nights = [{"spte_start_h": None if n["spte_start_h"] == "NA" else float(n["spte_start_h"]),
               "spte_end_h": None if n["spte_end_h"] == "NA" else float(n["spte_end_h"]),
               "guider": n["guider"]} for n in rows("nights")]
    sib = [[int(s["first"]), int(s["stop"])] for s in rows("sib")]
    return {"calls": calls, "nights": nights, "sib": sib}


def ggir_commit(ggir: Path) -> str:
    r = subprocess.run(["git", "-C", str(ggir), "rev-parse", "HEAD"], capture_output=True, text=True)
    return r.stdout.strip() or "unknown"


def real_series(path: Path, tmp: Path):
    """Our epoch table's anglez and nonwear for one real recording (UTC)."""
    import gzip
    out = tmp / (path.name + ".mcap")
    exe = Path(sys.executable).with_name("stillpoint")
    r = subprocess.run([str(exe), "process", str(path), "-o", str(out),
                        "--timezone", "UTC", "--no-sleep", "-q"], capture_output=True, text=True)
    if r.returncode:
        return None
    stem = out.name[:-5]
    rows = list(csv.DictReader(gzip.open(out.with_name(stem + ".epochs.csv.gz"), "rt")))
    t = np.array([np.datetime64(r["time_utc"][:-1], "ns").astype(np.int64) for r in rows])
    ang = np.array([float(r["anglez_deg"]) if r["anglez_deg"] else np.nan for r in rows])
    inv = np.array([r["nonwear"] == "1" or r["gap"] == "1" for r in rows])
    return t, ang, inv


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ggir", type=Path, required=True, help="wadpac/GGIR checkout")
    ap.add_argument("--ggir-commit", help="the GGIR commit (default: git rev-parse in --ggir)")
    ap.add_argument("--real", type=Path, help="folder of real recordings")
    ap.add_argument("--real-only", action="store_true", help="only the real recordings")
    ap.add_argument("--check", action="store_true", help="print agreement, write nothing")
    a = ap.parse_args(argv)
    from stillpoint.engine.sim.sleep import sleep_scenario
    from stillpoint.engine.timezones import parse_zone
    commit = a.ggir_commit or ggir_commit(a.ggir)
    OUT.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as td:
        tmp = Path(td)
        for name, (spec, ignore) in ({} if a.real_only else scenarios()).items():
            s = sleep_scenario(spec)
            write_series(tmp / f"{name}.csv", s.t_ns, s.zone, s.anglez, s.nonwear)
            res = run_ggir(a.ggir, tmp / f"{name}.csv", spec.timezone, ignore, tmp / name)
            fx = {"ggir_commit": commit, "spec": asdict(spec), "ignore_invalid": ignore,
                  "series_sha256": series_digest(s.anglez, s.nonwear), **res}
            report(name, fx, s.anglez, s.nonwear, s.t_ns, s.zone)
            if not a.check:
                (OUT / f"{name}.json").write_text(json.dumps(fx, indent=1) + "\n")
        if a.real:
            for p in sorted(a.real.iterdir()):
                if p.suffix not in (".cwa", ".bin", ".gz"):
                    continue
                got = real_series(p, tmp)
                if got is None or got[0].shape[0] < 120:
                    continue
                t, ang, inv = got
                z = parse_zone("UTC")
                write_series(tmp / "real.csv", t, z, np.nan_to_num(ang, nan=0.0), inv)
                res = run_ggir(a.ggir, tmp / "real.csv", "UTC", "FALSE", tmp / "real")
                fx = {"ggir_commit": commit, "file": p.name, "t0_ns": int(t[0]),
                      "anglez": [None if not np.isfinite(x) else round(float(x), 3) for x in ang],
                      "invalid": inv.astype(int).tolist(), **res}
                report(p.name, fx, np.nan_to_num(ang, nan=0.0), inv, t, z)
                if not a.check:
                    (OUT / f"real_{p.name.split('.')[0]}.json").write_text(json.dumps(fx) + "\n")
    return 0


def report(name, fx, anglez, invalid, t_ns, zone) -> None:
    """Print our operators' agreement with GGIR's decisions on this series."""
    from stillpoint.engine.sleep import HdczaOptions, SibStream, hdcza
    ign = {"FALSE": False, "TRUE": True, "NA": None}[fx.get("ignore_invalid", "FALSE")]
    s = SibStream()
    ours = np.concatenate([s.push(anglez), s.flush()])
    theirs = np.zeros(anglez.shape[0], np.int8)
    for a, b in fx["sib"]:
        theirs[a:b] = 1
    same = sum(hdcza(anglez[c["first"]:c["first"] + c["n"]], invalid[c["first"]:c["first"] + c["n"]],
                     HdczaOptions(ignore_invalid=ign)).start == c["start"] for c in fx["calls"])
    print(f"{name}: SIB per epoch {100 * np.mean(ours == theirs):.3f} % equal "
          f"({anglez.shape[0]} epochs); HDCZA windows {same}/{len(fx['calls'])} start identical")


if __name__ == "__main__":
    raise SystemExit(main())
