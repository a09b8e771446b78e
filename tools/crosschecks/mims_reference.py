"""Dev script: MIMS-units (engine/operators/mims.py) against the reference implementation, the R
package MIMSunit (mHealthGroup/MIMSunit, MIT), run by tools/crosschecks/mims_reference.R from a
checkout of its R files (``fetch`` github:mHealthGroup/MIMSunit; never copied here). R needs the
Debian packages r-base-core, r-cran-plyr, r-cran-dplyr, r-cran-magrittr, r-cran-lubridate,
r-cran-stringr, r-cran-tibble, r-cran-catools and the CRAN package ``signal`` (not packaged by
Debian: built from github:cran/signal with ``R CMD INSTALL -l DIR``; ``STILLPOINT_R_LIBS=DIR``).

For every real recording of ``STILLPOINT_REAL_DATA`` listed in ``FILES`` (and ActiLife's raw CSV
export of the ActiGraph NEO, its samples timed from the header's start at 30 Hz), and for a
synthetic recording that sits at its range (``clipped_signal``), the raw g of each segment with
the samples' own times go to R's ``mims_unit(epoch = "1 sec")`` and to our ``MimsOperator`` in
blocks of random length; 1 s epochs. Columns: epochs R gives a value for and the largest
|ours - R| over them; the same over the epochs without near-range samples (``clean``) and over
those 30 s or more from any (``>=30s``); epochs differing by more than 1e-3; epochs R leaves
undefined and how many of them ours leaves undefined too; our near-range epochs (extrapolated)
and those left as recorded (``asis``).

    --regenerate [FILE...]   run R (on FILEs only, if named) and write its MIMS-units to
                   tests/data/mims/<file>.csv
    (default)      compare ours with those committed fixtures and print the agreement

    STILLPOINT_REAL_DATA=/work/shared/data/real MIMSUNIT_R=/path/to/MIMSunit/R \\
        STILLPOINT_R_LIBS=/path/to/Rlib python tools/crosschecks/mims_reference.py [--regenerate]
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

FIXTURES = Path(__file__).resolve().parents[2] / "tests" / "data" / "mims"
R_SCRIPT = Path(__file__).with_name("mims_reference.R")
ACTILIFE_CSV = "actigraph_pygt3x_neo_30hz_legacy.actilife.csv"
FILES = [
    ACTILIFE_CSV,
    "actigraph_pygt3x_neo_30hz_legacy.gt3x",
    "actigraph_actfast_mos_60hz_81s.gt3x",
    "actigraph_pygt3x_tas_30hz_ism_disabled.gt3x",
    "ax3_ggirread_testfile_100hz_145blocks.cwa",
    "ax6_ggirread_testfile_100hz_16g_gyro250dps.cwa",
    "ax3_skdh_sample_200hz_490blocks.cwa",
    "geneactiv_sleeppy_test_100hz_64pages.bin",
    "geneactiv_ggirread_testfile_85p7hz_truncated64k.bin",
    "geneactiv_skdh_gait_back_50hz_22pages.bin",
    "geneactiv_actfast_cmi_60hz_20pages_LF_fw0617.bin",
    "geneactiv_romeosajina_left_ankle_20hz_truncated.bin",
]
SYNTHETIC = "synthetic_clipped_50hz"  # clipped_signal(): runs at both segment edges and mid-signal
FAR_S = 30  # epochs this far from any near-range epoch: the extrapolation's effect has decayed
ACTILIFE_RANGE_G = 6.0  # the NEO's dynamic range (+-6 g)


def actilife_csv(path: Path):
    """(times ns, raw g) of ActiLife's raw CSV export: header start date and time, 30 Hz."""
    head = path.read_text().splitlines()[:11]
    start = next(x for x in head if x.startswith("Start Time")).split()[-1]
    date = next(x for x in head if x.startswith("Start Date")).split()[-1]
    t0 = datetime.strptime(f"{date} {start}", "%m/%d/%Y %H:%M:%S").replace(tzinfo=timezone.utc)
    a = np.loadtxt(path, delimiter=",", skiprows=11, dtype=np.float64).reshape(-1, 3)
    t = int(t0.timestamp()) * 10**9 + (np.arange(a.shape[0]) * (1e9 / 30)).round().astype(np.int64)
    return t, a


def clipped_signal(rate: int = 50, seconds: int = 90, range_g: float = 8.0):
    """(times ns, g, range) of a synthetic +-8 g recording that sits at its range: x stuck at +8 g
    for its first 6 s (a start run longer than the reference's 5 s) and a 9.5 g, 1 Hz movement
    clipped to +-8 g from 10 to 40 s (60 runs); y at -8 g for its last 7 s (an end run); z at
    +8 g for its first 2 s (a start run shorter than 5 s) and three single near-range samples."""
    n = int(rate * seconds)
    t = np.arange(n) / rate
    rng = np.random.default_rng(43)
    x = 0.2 * np.sin(2 * np.pi * 0.9 * t) + 9.5 * np.sin(2 * np.pi * 1.0 * t) * ((t > 10) & (t < 40))
    x[t < 6] = 8.0
    y = 1 + 0.4 * np.sin(2 * np.pi * 1.7 * t) + 0.01 * rng.standard_normal(n)
    y[t > seconds - 7] = -8.0
    z = 0.3 * np.sin(2 * np.pi * 2.2 * t)
    z[t < 2] = 8.0
    z[[2000, 2001, 3000]] = [7.95, 7.99, -7.97]
    a = np.clip(np.stack([x, y, z], axis=1), -range_g, range_g)
    tn = (1_700_000_000 * 10**9 + 250_000_000 + np.round(t * 1e9)).astype(np.int64)
    return tn, a, range_g


def segments(path: Path):
    """(dynamic range g, [(times ns, raw g) of each segment])."""
    if path.name == SYNTHETIC:
        t, a, range_g = clipped_signal()
        return range_g, [(t, a)]
    if path.name.endswith(".csv"):
        return ACTILIFE_RANGE_G, [actilife_csv(path)]
    from stillpoint.drivers import open_recording
    src = open_recording(path)
    rng = float(src.info.accel_range_g or 8.0)
    segs: dict = {}
    try:
        for b in src:
            segs.setdefault(b.segment, []).append((b.time_ns.copy(), b.accel_g()))
    finally:
        src.close()
    return rng, [(np.concatenate([p[0] for p in v]), np.concatenate([p[1] for p in v]))
                 for _, v in sorted(segs.items())]


def ours(t: np.ndarray, a: np.ndarray, range_g: float, seed: int = 0):
    """Our 1 s MIMS-units of one segment, pushed in blocks of random length."""
    from stillpoint.engine.operators.correction import CorrectedBatch
    from stillpoint.engine.operators.mims import EpochMims, MimsOperator
    op = MimsOperator(0.0, 1, range_g)
    n = t.shape[0]
    rng = np.random.default_rng(seed)
    cuts = np.unique(np.concatenate([rng.integers(1, n, 25), [n]]))
    out, s = [], 0
    for c in cuts.tolist():
        out.append(op.push(CorrectedBatch(t[s:c], a[s:c], np.zeros(c - s), 0)))
        s = c
    out.append(op.flush())
    return EpochMims.concat(out), op.near_range_epochs, op.unextrapolated_epochs


def reference(t: np.ndarray, a: np.ndarray, range_g: float) -> np.ndarray:
    """R MIMSunit's rows: epoch start (s), MIMS, x, y, z (-0.01: undefined)."""
    rdir = os.environ.get("MIMSUNIT_R")
    if not rdir:
        raise SystemExit("set MIMSUNIT_R to the R/ folder of a MIMSunit checkout")
    with tempfile.TemporaryDirectory() as d:
        with open(f"{d}/s.csv", "w") as f:
            f.write("t_ns,x,y,z\n")
            for ti, r in zip(t.tolist(), a.tolist()):
                f.write(f"{ti},{r[0]!r},{r[1]!r},{r[2]!r}\n")
        subprocess.run(["Rscript", str(R_SCRIPT), rdir, f"{d}/s.csv", repr(range_g), "1",
                        f"{d}/o.csv"], check=True, stdout=subprocess.DEVNULL,
                       stderr=subprocess.DEVNULL)
        return np.loadtxt(f"{d}/o.csv", delimiter=",", skiprows=1, ndmin=2)


def fixture_path(name: str) -> Path:
    return FIXTURES / f"{name}.csv"


def write_fixture(path: Path, per_segment: list, range_g: float) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w") as f:
        f.write(f"# R MIMSunit 0.11.2 mims_unit(epoch = '1 sec', dynamic_range = +-{range_g:g} g),"
                " raw g; -0.01: undefined\nsegment,t_s,mims,x,y,z\n")
        for s, rows in enumerate(per_segment):
            for r in rows.tolist():
                f.write(f"{s},{r[0]:.0f}," + ",".join(f"{v:.10g}" for v in r[1:]) + "\n")


def read_fixture(path: Path) -> list:
    d = np.loadtxt(path, delimiter=",", skiprows=2, ndmin=2)
    return [d[d[:, 0] == s, 1:] for s in np.unique(d[:, 0])]


def compare(ref: list, got: list) -> dict:
    """Per 1 s epoch of the reference: |ours - R| of the valid ones (``max_abs_diff``; without
    the epochs holding near-range samples, which are extrapolated: ``max_abs_diff_clean``);
    undefined ones must be undefined (NaN) in ours too."""
    valid = undefined = agree_undefined = clean = far = over = 0
    worst = worst_clean = worst_far = 0.0
    for r, (g, *_) in zip(ref, got):
        idx = {int(t): i for i, t in enumerate((g.start_ns // 10**9).tolist())}
        near_t = (g.start_ns[g.near_range] // 10**9).astype(np.float64)
        for row in r:
            i = idx.get(int(row[0]))
            if row[1] == -0.01:
                undefined += 1
                agree_undefined += int(i is None or not np.isfinite(g.mims[i]))
                continue
            valid += 1
            v = g.mims[i] if i is not None else np.nan
            d = abs(v - row[1]) if np.isfinite(v) else np.inf
            worst = max(worst, d)
            over += int(d > 1e-3)
            if i is not None and not g.near_range[i]:
                clean += 1
                worst_clean = max(worst_clean, d)
            if not near_t.shape[0] or np.abs(near_t - row[0]).min() >= FAR_S:
                far += 1
                worst_far = max(worst_far, d)
    return {"valid": valid, "max_abs_diff": worst, "clean": clean,
            "max_abs_diff_clean": worst_clean, "far": far, "max_abs_diff_far": worst_far,
            "over_1e-3": over, "undefined": undefined,
            "undefined_agree": agree_undefined}


def main(argv) -> int:
    real = os.environ.get("STILLPOINT_REAL_DATA")
    if not real:
        print("set STILLPOINT_REAL_DATA to the folder of real recordings")
        return 2
    regenerate = "--regenerate" in argv
    only = [a for a in argv if not a.startswith("--")]  # regenerate these files only
    print(f"{'file':55s} {'epochs':>6s} {'max|d|':>9s} {'clean':>6s} {'max|d|':>9s} "
          f"{'>=30s':>6s} {'max|d|':>9s} {'>1e-3':>5s} {'undef':>5s} {'same':>4s} {'near':>4s} "
          f"{'asis':>4s}")
    for name in FILES + [SYNTHETIC]:
        range_g, segs = segments(Path(real) / name)
        if regenerate and (not only or name in only):
            write_fixture(fixture_path(name), [reference(t, a, range_g) for t, a in segs], range_g)
        got = [ours(t, a, range_g) for t, a in segs]
        r = compare(read_fixture(fixture_path(name)), got)
        near = sum(n for _, n, _ in got)
        asis = sum(n for _, _, n in got)
        print(f"{name:55s} {r['valid']:6d} {r['max_abs_diff']:9.2e} {r['clean']:6d} "
              f"{r['max_abs_diff_clean']:9.2e} {r['far']:6d} {r['max_abs_diff_far']:9.2e} "
              f"{r['over_1e-3']:5d} {r['undefined']:5d} {r['undefined_agree']:4d} {near:4d} {asis:4d}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
