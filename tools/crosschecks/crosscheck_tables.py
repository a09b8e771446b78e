"""Cross-check the epoch/day tables against GGIR's nonwear rule as published and against peers.

    python tools/crosschecks/crosscheck_tables.py [FILE.cwa ...] [--sim-days 2] [--hz 25] [--peers PYTHON]

For each recording (default: two simulated ones with drawer nonwear, plus the 3-hour real AX3 file
from STILLPOINT_REAL_DATA when set):

1. ``process`` it with the tables (both nonwear forms);
2. run GGIR's ``detect_nonwear_clipping`` loop as published, on sample indices from the first
   sample (GGIR's windows start at the data, ours on the 15-min clock grid), on the same calibrated
   samples, whole-array; map its 15-min flags to our epochs; print per-epoch agreement and wear
   hours per day both ways;
3. with a peers environment (``--peers`` or STILLPOINT_PEERS_PYTHON: a Python with
   scikit-digital-health and/or actipy), compute ENMO and anglez per 5-s epoch with their
   functions on the same calibrated samples and print the differences from our columns.

Not a test: heavy, whole-array, and the peers are run as child processes only. Prints a table.
"""

from __future__ import annotations

import argparse
import csv
import gzip
import json
import math
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))


def calibrated_samples(path, summary):
    """(times ns, calibrated g (n, 3)) of the whole recording, with the run's final estimate."""
    from stillpoint.drivers import open_recording
    from stillpoint.engine.calibration.estimate import CalibrationEstimate
    est = CalibrationEstimate.from_dict(dict(summary["calibration"]))
    applied = est.applied
    opts = {}
    tz = summary.get("_reader_tz")
    if tz is not None:
        opts["timezone"] = tz
    ts, gs = [], []
    with open_recording(path, **opts) as src:
        for b in src:
            g = b.accel_g()
            if applied:
                t = b.temperature_per_sample() if est.uses_temperature else None
                if t is not None:
                    t = np.where(np.isfinite(t), t, est.temperature_ref)
                g = est.apply(g, t)
            ts.append(b.time_ns)
            gs.append(g)
    return np.concatenate(ts), np.concatenate(gs)


def ggir_published(a: np.ndarray, sf: float, version: str, clipthres: float = 7.5):
    """GGIR's detect_nonwear_clipping loop (R indices translated to 0-based), then g.weardec's
    thresholds: returns per 15-min window (nonwear bool, clipping bool), window length in samples."""
    window2 = int(round(900 * sf))
    window = int(round(3600 * sf))
    n = a.shape[0]
    nmin = n // window2
    crit = (window / window2) / 2 + 1
    NW = np.zeros((nmin, 3), bool)
    CW = np.zeros((nmin, 3))
    step = math.ceil(sf / 5)
    for h in range(1, nmin + 1):
        c1, c2 = (h - 1) * window2, h * window2
        if version == "2013":
            flag = [h]
            if h <= crit:
                lo, hi = 1, window
            elif h >= nmin - crit:
                lo, hi = int((nmin - crit) * window2), nmin * window2
            else:
                lo = int((h - 1) * window2 + window2 * 0.5 - window * 0.5)
                hi = int((h - 1) * window2 + window2 * 0.5 + window * 0.5)
            idx = np.arange(lo, min(hi, n))
        else:
            flag = [k for k in range(h, h + window // window2) if k <= nmin]
            lo = h * window2 - window2 + 1
            hi = min(lo + window - 1, n)
            idx = np.arange(lo, hi, step)
        seg = a[idx]
        for j in range(3):
            x = np.abs(a[c1:c2, j])
            above = x > clipthres
            CW[h - 1, j] = window2 if (x[above] > 1.5 * clipthres).any() else above.sum()
            if seg.shape[0] > 1 and np.ptp(seg[:, j]) < 0.05 and np.std(seg[:, j], ddof=1) < 0.013:
                for k in flag:
                    NW[k - 1, j] = True
    score = NW.sum(axis=1)
    out = score.copy()
    for i in np.flatnonzero(score == 1):
        if 0 < i < len(score) - 1 and score[i - 1] > 1 and score[i + 1] > 1:
            out[i] = 2
    return out >= 2, (CW / window2).max(axis=1) > 0.3, window2


def read_epochs(path):
    with gzip.open(path, "rt") as f:
        return list(csv.DictReader(f))


def epoch_times(rows):
    key = "time_utc" if rows and rows[0].get("time_utc") else "time_local"
    return np.array([np.datetime64(r[key][:19], "ns").astype(np.int64) for r in rows])


PEER_SCRIPT = r"""
import json, sys, warnings, numpy as np
warnings.simplefilter("ignore")
d = np.load(sys.argv[1])
t, a, starts = d["t"], d["a"], d["starts"]
out = {}
try:
    import skdh
    from skdh.activity import metrics as M
    out["skdh_version"] = skdh.__version__
    lo = np.searchsorted(t, starts)
    hi = np.searchsorted(t, starts + 5 * 10**9)
    enmo, mad, ang = [], [], []
    for i, j in zip(lo, hi):
        if j - i < 2:
            enmo.append(None); mad.append(None); ang.append(None)
            continue
        x = a[i:j]
        enmo.append(float(M.metric_enmo(x, wlen=j - i)[0]) * 1000)
        mad.append(float(M.metric_mad(x, wlen=j - i)[0]) * 1000)
        ang.append(float(M.metric_anglez(x, wlen=j - i)[0]))
    out["enmo"], out["mad"], out["anglez"] = enmo, mad, ang
except Exception as e:
    out["skdh_error"] = repr(e)
try:
    import actipy
    import actipy.processing as P
    out["actipy_version"] = actipy.__version__
    out["actipy_metrics"] = sorted(x for x in dir(P) if not x.startswith("_") and x.islower())
except Exception as e:
    out["actipy_error"] = repr(e)
print(json.dumps(out))
"""


def peers_epochs(peers, t, a, starts):
    with tempfile.TemporaryDirectory() as d:
        f = Path(d) / "x.npz"
        np.savez(f, t=t, a=a, starts=starts)
        p = subprocess.run([peers, "-c", PEER_SCRIPT, str(f)], capture_output=True, text=True)
        if p.returncode:
            return {"error": p.stderr[-500:]}
        return json.loads(p.stdout)


def _col(rows, k):
    return np.array([float(r[k]) if r[k] else np.nan for r in rows])


def check(path, workdir, peers=None):
    from stillpoint.engine.run import RunSettings, process_file
    from stillpoint.engine.tables import TablesSettings
    rows = {}
    for version in ("2023", "2013"):
        out = Path(workdir) / f"{Path(path).name}.{version}.mcap"
        ep, dp = out.with_suffix(".epochs.csv.gz"), out.with_suffix(".days.csv")
        s = process_file(path, out, RunSettings(), tables=TablesSettings(ep, dp, nonwear_version=version))
        rows[version] = (s, read_epochs(ep))
        out.unlink()
    s = rows["2023"][0]
    t, a = calibrated_samples(path, s)
    sf = float(s["device"]["rate_hz"])
    print(f"\n{Path(path).name}: {t.size:,} samples, {sf:g} Hz, calibration {s['calibration']['status']}")
    for version in ("2023", "2013"):
        _, e = rows[version]
        nw_g, clip_g, w2 = ggir_published(a, sf, version)
        te = epoch_times(e)
        # GGIR window of each epoch: the window holding the first sample at or after its start
        k = np.searchsorted(t, te, side="left") // w2
        inside = k < len(nw_g)
        ours = np.array([r["nonwear"] == "1" for r in e])
        gap = np.array([r["gap"] == "1" for r in e])
        m = inside & ~gap
        theirs = np.zeros(len(e), bool)
        theirs[inside] = nw_g[k[inside]]
        agree = (ours[m] == theirs[m]).mean() if m.any() else float("nan")
        print(f"  nonwear {version}: per-epoch agreement with GGIR as published {100 * agree:.2f} % "
              f"({m.sum():,} epochs; ours {ours[m].sum():,} nonwear, GGIR {theirs[m].sum():,}); "
              f"clipping windows GGIR {int(clip_g.sum())}, ours {sum(r['clipping'] == '1' for r in e) // 180}")
        date = np.array([r["time_local"][:10] for r in e])
        for d in sorted(set(date[m])):
            sel = m & (date == d)
            print(f"    {d}: wear h ours {(~ours[sel]).sum() * 5 / 3600:6.2f}  "
                  f"GGIR rule {(~theirs[sel]).sum() * 5 / 3600:6.2f}")
    if peers:
        e = rows["2023"][1]
        te = epoch_times(e)
        res = peers_epochs(peers, t, a, te)
        if "error" in res or "skdh_error" in res:
            print("  peers:", res.get("error") or res.get("skdh_error"))
            return
        clean = np.array([r["gap"] == "0" for r in e])  # epochs with data (incl. partial ones: skip)
        full = clean & np.array([int(r["n"]) >= 0.9 * 5 * sf for r in e])
        print(f"  skdh {res['skdh_version']} on the same calibrated samples, per epoch "
              f"({full.sum():,} full epochs):")
        for k, ours_col in (("enmo", "enmo_mg"), ("mad", "mad_mg"), ("anglez", "anglez_deg")):
            theirs = np.array([np.nan if v is None else v for v in res[k]], float)
            ours = _col(e, ours_col)
            m = full & np.isfinite(theirs) & np.isfinite(ours)
            if not m.any():
                print(f"    {k}: no paired epochs")
                continue
            dlt = ours[m] - theirs[m]
            unit = "deg" if k == "anglez" else "mg"
            print(f"    {k:7s} ours - skdh: median {np.median(dlt):+.4f}, p99 |d| "
                  f"{np.percentile(np.abs(dlt), 99):.4f}, max |d| {np.abs(dlt).max():.4f} {unit}; "
                  f"means {ours[m].mean():.3f} vs {theirs[m].mean():.3f}")
        print(f"  actipy {res.get('actipy_version')}: processing offers "
              f"{', '.join(res.get('actipy_metrics', []))} (no ENMO or anglez)")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("files", nargs="*")
    ap.add_argument("--sim-days", type=float, default=2.0)
    ap.add_argument("--hz", type=float, default=25.0)
    ap.add_argument("--peers", default=os.environ.get("STILLPOINT_PEERS_PYTHON"))
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as d:
        files = list(args.files)
        if not files:
            from stillpoint.engine.sim import simulate_recording
            from stillpoint.engine.sim.wearer import WearerParams
            for seed in (20, 27):
                p = Path(d) / f"sim{seed}.cwa"
                simulate_recording(p, days=args.sim_days, hz=args.hz, seed=seed,
                                   wearer=WearerParams(drawer_per_day=1.0),
                                   truth_path=False, labels_path=False)
                files.append(str(p))
            real = os.environ.get("STILLPOINT_REAL_DATA")
            if real:
                files.append(str(Path(real) / "ax3_oxwearables_tiny_sample_3h_with_restart.cwa.gz"))
        for f in files:
            check(f, d, args.peers)
    return 0


if __name__ == "__main__":
    sys.exit(main())
