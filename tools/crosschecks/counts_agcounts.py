"""Dev script: ActiLife counts (engine/operators/counts.py) against ActiGraph's own implementation,
the ``agcounts`` package (GPL-3; never a dependency, never copied: it runs in a separate venv,
``AGCOUNTS_PYTHON``, default /work/venv-peers/bin/python, through a subprocess).

For every real recording of ``STILLPOINT_REAL_DATA`` at a rate the algorithm defines (30-100 Hz in
steps of 10; 85.7 Hz and 20 Hz files are left out) and for ActiLife's raw CSV export of the
ActiGraph NEO file, the raw g values of each segment (no calibration: ActiLife's numbers) are
given to agcounts (``get_counts``; ``lfe``: its per-sample ``_extract_slow``, since its vectorised
low-frequency-extension path fails on 2-D input) and to our ``CountsOperator`` in blocks of random
length (with the nominal sample clock from a whole hour, so that our UTC-grid epochs are
agcounts' epochs from the first sample). Epoch: 1 s (60 s for the 3-hour AX3 file).

    --regenerate [FILE...]   run agcounts (on FILEs only, if named) and write its counts to
                   tests/data/counts/<file>.<mode>.csv
    (default)      compare ours with those committed fixtures and print the agreement

    STILLPOINT_REAL_DATA=/work/shared/data/real python tools/crosschecks/counts_agcounts.py [--regenerate]
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

AGCOUNTS_PYTHON = os.environ.get("AGCOUNTS_PYTHON", "/work/venv-peers/bin/python")
FIXTURES = Path(__file__).resolve().parents[2] / "tests" / "data" / "counts"
ACTILIFE_CSV = "actigraph_pygt3x_neo_30hz_legacy.actilife.csv"
# (file, epoch s, modes)
FILES = [
    (ACTILIFE_CSV, 1, ("normal", "lfe")),
    ("actigraph_pygt3x_neo_30hz_legacy.gt3x", 1, ("normal",)),
    ("actigraph_actfast_mos_60hz_81s.gt3x", 1, ("normal",)),
    ("actigraph_pygt3x_tas_30hz_ism_disabled.gt3x", 1, ("normal",)),
    ("ax3_ggirread_testfile_100hz_145blocks.cwa", 1, ("normal", "lfe")),
    ("ax3_openmovement_example_610_steps_fw30_nofrac.cwa", 1, ("normal",)),
    ("ax6_ggirread_testfile_100hz_16g_gyro250dps.cwa", 1, ("normal",)),
    ("ax6_skdh_sample_100hz_16g_gyro2000dps.cwa", 1, ("normal",)),
    ("ax3_oxwearables_tiny_sample_3h_with_restart.cwa.gz", 60, ("normal",)),
    ("geneactiv_genearead_TESTfile_100hz_104pages.bin", 1, ("normal", "lfe")),
    ("geneactiv_sleeppy_test_100hz_64pages.bin", 1, ("normal",)),
    ("geneactiv_skdh_gait_back_50hz_22pages.bin", 1, ("normal", "lfe")),
    ("geneactiv_actfast_cmi_60hz_20pages_LF_fw0617.bin", 1, ("normal",)),
]

_AGCOUNTS = r"""
import sys, numpy as np
from agcounts.extract import get_counts
from agcounts.legacy import _extract_slow
a = np.load(sys.argv[1]); rate = int(sys.argv[2]); epoch = int(sys.argv[3]); mode = sys.argv[4]
if mode == "normal":
    c = get_counts(a, rate, epoch)
else:
    c = np.concatenate([_extract_slow(a[:, [i]], rate, True, epoch) for i in range(3)], 0).T
np.save(sys.argv[5], np.asarray(c, np.int64))
"""


def actilife_csv(path: Path) -> np.ndarray:
    """ActiLife's raw CSV export: ten header lines, the column line, then x,y,z in g."""
    return np.loadtxt(path, delimiter=",", skiprows=11, dtype=np.float64).reshape(-1, 3)


def segments(path: Path):
    """(rate, [raw g of each segment]) of a recording."""
    if path.name.endswith(".csv"):
        return 30.0, [actilife_csv(path)]
    from stillpoint.drivers import open_recording
    src = open_recording(path)
    rate = float(src.info.sample_rate_nominal)
    segs: dict[int, list] = {}
    try:
        for block in src:
            segs.setdefault(block.segment, []).append(block.accel_g())
    finally:
        src.close()
    return rate, [np.concatenate(v) for _, v in sorted(segs.items())]


def ours(a: np.ndarray, rate: float, epoch: int, mode: str, seed: int = 0) -> np.ndarray:
    """Our counts of one segment, pushed in blocks of random length on the nominal clock."""
    from stillpoint.engine.operators.correction import CorrectedBatch
    from stillpoint.engine.operators.counts import CountsOperator, EpochCounts
    n = a.shape[0]
    t = 1_599_998_400 * 10**9 + (np.arange(n) * (1e9 / rate)).round().astype(np.int64)
    op = CountsOperator(rate, epoch, mode)
    rng = np.random.default_rng(seed)
    cuts = np.unique(np.concatenate([rng.integers(1, n, 20), [n]])) if n > 1 else np.array([n])
    out, s = [], 0
    for c in cuts.tolist():
        out.append(op.push(CorrectedBatch(t[s:c], a[s:c], np.zeros(c - s), 0)))
        s = c
    out.append(op.flush())
    return EpochCounts.concat(out).counts


def agcounts(a: np.ndarray, rate: float, epoch: int, mode: str) -> np.ndarray:
    with tempfile.TemporaryDirectory() as d:
        np.save(f"{d}/a.npy", a)
        subprocess.run([AGCOUNTS_PYTHON, "-c", _AGCOUNTS, f"{d}/a.npy", str(int(rate)), str(epoch),
                        mode, f"{d}/c.npy"], check=True, stderr=subprocess.DEVNULL)
        c = np.load(f"{d}/c.npy")
    return c[:, [1, 0, 2]]  # ActiLife's order: axis1 = Y, axis2 = X, axis3 = Z


def fixture_path(name: str, mode: str) -> Path:
    return FIXTURES / f"{name}.{mode}.csv"


def write_fixture(path: Path, per_segment: list, rate: float, epoch: int) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w") as f:
        f.write(f"# agcounts get_counts, rate {rate:g} Hz, epoch {epoch} s, raw g; "
                "axis1 (Y), axis2 (X), axis3 (Z)\nsegment,epoch,axis1,axis2,axis3\n")
        for s, c in enumerate(per_segment):
            for k, row in enumerate(c.tolist()):
                f.write(f"{s},{k},{row[0]},{row[1]},{row[2]}\n")


def read_fixture(path: Path) -> list:
    d = np.loadtxt(path, delimiter=",", skiprows=2, dtype=np.int64, ndmin=2)
    return [d[d[:, 0] == s, 2:].astype(np.float64) for s in np.unique(d[:, 0])]


def compare(ref: list, got: list) -> dict:
    """Agreement over whole epochs (ours may add a last, partial epoch agcounts leaves out)."""
    epochs = equal = 0
    worst = 0.0
    for r, g in zip(ref, got):
        k = r.shape[0]
        epochs += k
        d = np.abs(r - g[:k]).max(axis=1) if k else np.zeros(0)
        equal += int((d == 0).sum())
        worst = max(worst, float(d.max()) if k else 0.0)
    return {"epochs": epochs, "equal": equal, "max_abs_diff": worst}


def main(argv) -> int:
    real = os.environ.get("STILLPOINT_REAL_DATA")
    if not real:
        print("set STILLPOINT_REAL_DATA to the folder of real recordings")
        return 2
    regenerate = "--regenerate" in argv
    only = [a for a in argv if not a.startswith("--")]  # regenerate these files only
    print(f"{'file':55s} {'mode':6s} {'rate':>5s} {'epoch':>5s} {'epochs':>7s} {'equal':>7s} "
          f"{'max|d|':>6s}")
    for name, epoch, modes in FILES:
        rate, segs = segments(Path(real) / name)
        for mode in modes:
            if regenerate and (not only or name in only):
                write_fixture(fixture_path(name, mode), [agcounts(a, rate, epoch, mode) for a in segs],
                              rate, epoch)
            ref = read_fixture(fixture_path(name, mode))
            got = [ours(a, rate, epoch, mode) for a in segs]
            r = compare(ref, got)
            print(f"{name:55s} {mode:6s} {rate:5g} {epoch:5d} {r['epochs']:7d} {r['equal']:7d} "
                  f"{r['max_abs_diff']:6g}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
