"""Sleep onset and wake against simulated truth (engine/sim/sleep.py): median and 95th-percentile
absolute error over N nights (default 50: ten 6-day recordings of 5 nights each).

    python tools/crosschecks/sleep_accuracy.py [--nights 50] [--seed 100] [--raw]

Nights are simulated at the 5 s epoch level with awakenings, quiet evenings, every tenth night a
daysleeper and every seventh 2 h of nonwear; the operators run exactly as in ``process`` (the
epoch rows streamed through ``SleepStage``, GGIR's defaults, no sleep log). ``--raw``: the whole pipeline instead: the raw wearer simulator
(``stillpoint simulate``, an AX3 at the wrist, 25 Hz, 6 days, its default sleep schedule and sensor
errors) and ``stillpoint process --timezone UTC``; the truth is the simulator's label CSV (a night
runs from the first to the last 10 s window labelled sleep, windows less than 2 h apart joined).
Errors are our onset / wake minus the simulated ones, in minutes. These figures are ours, on simulated data; the
C-statistics 0.86 / 0.83 in van Hees et al. 2018 are that paper's, against polysomnography.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

SLEEP = 2  # engine/sim/wearer.py ACTIVITIES.index("sleep")


def run(nights: int, seed: int) -> dict:
    from stillpoint.engine.sim.sleep import SleepSpec, sleep_scenario
    from stillpoint.engine.sleep import SleepStage
    from stillpoint.engine.tables.epochs import EpochRows
    on_err, wk_err = [], []
    k = 0
    rec = 0
    while len(on_err) < nights:
        ds = tuple(i for i in range(1, 6) if (k + i) % 10 == 0)
        nw = tuple(i for i in range(1, 6) if (k + i) % 7 == 0)
        s = sleep_scenario(SleepSpec("2026-03-02T10:00:00", "Europe/London", 6.0, seed=seed + rec,
                                     daysleeper_nights=ds, nonwear_nights=nw))
        st = SleepStage(s.zone, 5.0)
        n = s.t_ns.shape[0]
        for a in range(0, n, 720):
            b = min(n, a + 720)
            z = np.zeros(b - a, bool)
            st.push(EpochRows(s.t_ns[a:b], np.full(b - a, 500), s.enmo[a:b], z * 0.0, z * 0.0,
                              s.anglez[a:b], z * 0.0, s.nonwear[a:b], z.copy(), z.copy(), z.copy(),
                              z.copy()))
        st.flush()
        truth = {t["night"]: t for t in s.truth}
        for night in st.nights:
            t = truth.get(night.date.isoformat())
            if t is None or night.spt is None or len(on_err) >= nights:
                continue
            on = int(s.t_ns[0]) + night.spt[0] * 5 * 10**9
            wk = int(s.t_ns[0]) + night.spt[1] * 5 * 10**9
            on_err.append((on - t["onset_ns"]) / 60e9)
            wk_err.append((wk - t["wake_ns"]) / 60e9)
            k += 1
        rec += 1
    return _summary(on_err, wk_err, rec)


def _summary(on_err, wk_err, rec) -> dict:
    on_a, wk_a = np.abs(on_err), np.abs(wk_err)
    return {"nights": len(on_err), "recordings": rec,
            "onset_abs_error_min": {"median": round(float(np.median(on_a)), 2),
                                    "p95": round(float(np.percentile(on_a, 95)), 2)},
            "wake_abs_error_min": {"median": round(float(np.median(wk_a)), 2),
                                   "p95": round(float(np.percentile(wk_a, 95)), 2)},
            "onset_bias_min": round(float(np.mean(on_err)), 2),
            "wake_bias_min": round(float(np.mean(wk_err)), 2)}


def _label_nights(labels: Path, start_ns: int) -> list:
    import csv
    rows = list(csv.DictReader(open(labels)))
    t = np.array([float(r["true_start_s"]) for r in rows])
    sl = np.array([int(r["activity"]) == SLEEP for r in rows])
    idx = np.flatnonzero(sl)
    if not idx.shape[0]:
        return []
    cut = np.flatnonzero(np.diff(t[idx]) > 2 * 3600) + 1
    out = []
    for part in np.split(idx, cut):
        out.append((start_ns + int(t[part[0]] * 1e9), start_ns + int((t[part[-1]] + 10) * 1e9)))
    return out


def run_raw(nights: int, seed: int) -> dict:
    import csv
    import json as _json
    import subprocess
    import tempfile
    exe = str(Path(sys.executable).with_name("stillpoint"))
    on_err, wk_err = [], []
    rec = 0
    with tempfile.TemporaryDirectory() as td:
        while len(on_err) < nights:
            f = Path(td) / f"r{rec}.cwa"
            subprocess.run([exe, "simulate", "-o", str(f), "--days", "6", "--hz", "25", "--seed",
                            str(seed + rec), "--truth", str(f.with_suffix(".truth.json")),
                            "--overwrite"], check=True, capture_output=True)
            subprocess.run([exe, "process", str(f), "-o", str(f.with_suffix(".mcap")), "--timezone",
                            "UTC", "-q", "--overwrite"], check=True, capture_output=True)
            start_ns = _json.loads(f.with_suffix(".truth.json").read_text())["start_ns"]
            truth = _label_nights(f.with_name(f.stem + ".labels.csv"), start_ns)
            for r in csv.DictReader(open(f.with_name(f.stem + ".nights.csv"))):
                if not r["onset_utc"] or len(on_err) >= nights:
                    continue
                on = int(np.datetime64(r["onset_utc"][:-1], "ns").astype(np.int64))
                wk = int(np.datetime64(r["wake_utc"][:-1], "ns").astype(np.int64))
                best = min(truth, key=lambda x: abs(x[0] - on), default=None)
                if best is None or abs(best[0] - on) > 6 * 3600 * 10**9:
                    continue
                if best[0] < start_ns + 60 * 10**9 or best[1] > start_ns + 6 * 86400 * 10**9 - 60 * 10**9:
                    continue  # a night cut by the recording's ends
                on_err.append((on - best[0]) / 60e9)
                wk_err.append((wk - best[1]) / 60e9)
            rec += 1
    return _summary(on_err, wk_err, rec)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--nights", type=int, default=50)
    ap.add_argument("--seed", type=int, default=100)
    ap.add_argument("--raw", action="store_true", help="raw simulator + process (minutes)")
    a = ap.parse_args(argv)
    print(json.dumps((run_raw if a.raw else run)(a.nights, a.seed), indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
