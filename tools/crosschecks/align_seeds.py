"""The alignment accuracy table: 20 seeds of simulated two-device pairs per scenario.

Scenarios:
  linear   clocks with offset up to +-10 s and skew up to +-50 ppm, no temperature dependence
  halt     as linear, plus one sampling halt of 2-400 s after day 1 in the second device
           (simulator: the RTC runs on through a halt, so the halt is a gap in the timestamps)
  clockstop as halt, but the device clock stops during the halt (the AX3 behaviour Brønd et al.
           report; synthetic pair from tests/synthetic_alignment.py): a step in the lag
  temperature  crystal parabola -0.035 ppm/degC^2 on both devices (held-out RMSE compared)

Usage:
  /work/venv/bin/python tools/crosschecks/align_seeds.py [--seeds 20] [--days 7] [--hz 50]
         [--scenarios linear,halt,clockstop,temperature] [--sites wrist,hip] [--jobs 2]

For each seed: the pair is simulated (stillpoint.engine.sim.simulate_pair, real .cwa files in a
temporary directory) and aligned with both methods; errors are against the truth JSON clocks.
Prints one row per seed and a summary (pass counts against the targets).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np

RATE = 30.0
DAY = 86400.0


def _truth_offset(ta: dict, tb: dict, t0_ns: int):
    """other-minus-reference clock offset (s) at reference times (s since t0), from truths."""
    def dev(tr, tau):
        c = tr["clock"]["table"]
        return tau + np.interp(tau, c["true_s"], c["device_minus_true_s"])

    g = np.asarray(ta["clock"]["table"]["true_s"], dtype=np.float64)

    def f(t):
        t = np.asarray(t, dtype=np.float64)
        c_ref = (t0_ns - ta["start_ns"]) / 1e9 + t
        tau = np.interp(c_ref, dev(ta, g), g)  # linear extrapolation is not needed within data
        # beyond the table: extend with the last skew (clock table covers the recording)
        return dev(tb, tau) - c_ref
    return f


def _eval_span(ta: dict, t0_ns: int, span_s: float) -> float:
    """Longest reference time (s since t0) the truth clock table covers (no extrapolation)."""
    tab = ta["clock"]["table"]
    dev_end = tab["true_s"][-1] + tab["device_minus_true_s"][-1]
    return min(span_s, dev_end - (t0_ns - ta["start_ns"]) / 1e9 - 60.0)


def _day7(f, span_s):
    """Truth accumulated drift over the recording, scaled to 7 days (the estimate is compared
    over the same span and scaled alike; for a 7-day recording the scale is ~1)."""
    return float(f(span_s) - f(0.0)) * 7 * DAY / span_s


def run_sim_seed(args):
    scenario, seed, days, hz, sites = args
    from stillpoint.drivers import open_recording
    from stillpoint.engine.alignment import AlignConfig, estimate_alignment
    from stillpoint.engine.sim.record import build_model, simulate_pair
    rng = np.random.default_rng(10_000 + seed)
    off_a, off_b = rng.uniform(-10, 10, 2)
    sk_a, sk_b = rng.uniform(-50, 50, 2)
    curv = -0.035 if scenario == "temperature" else 0.0
    base = ["offset", "gain", "noise", "clipping", "quantisation", "clock"]
    ma = build_model(base, overrides=[("clock", {"offset_s": off_a, "skew_ppm": sk_a,
                                                  "curvature_ppm_per_c2": curv})])
    ob = [("clock", {"offset_s": off_b, "skew_ppm": sk_b, "curvature_ppm_per_c2": curv})]
    halt = None
    if scenario == "halt":
        halt = float(rng.uniform(2, 400))
        ob.append(("halts", {"count": 1, "min_duration_s": halt, "max_duration_s": halt}))
    mb = build_model(base + (["halts"] if halt else []), overrides=ob)
    with tempfile.TemporaryDirectory() as d:
        pa, pb = os.path.join(d, "a.cwa"), os.path.join(d, "b.cwa")
        t_sim = time.perf_counter()
        ta, tb = simulate_pair(pa, pb, site_a=sites[0], site_b=sites[1], days=days, hz=hz,
                               effects=ma, effects_b=mb, seed=seed,
                               truth_a=os.path.join(d, "a.json"), truth_b=os.path.join(d, "b.json"))
        t_sim = time.perf_counter() - t_sim
        ta, tb = ta.to_dict(), tb.to_dict()
        row = {"scenario": scenario, "seed": seed, "sim_s": round(t_sim, 1), "halt_s": halt}
        for method in ("robust", "brond"):
            t = time.perf_counter()
            res = estimate_alignment(open_recording(pa), open_recording(pb),
                                     AlignConfig(method=method))
            row[f"{method}_s"] = round(time.perf_counter() - t, 1)
            if not res.ok:
                row[method] = {"aligned": False, "reason": res.reason[:60]}
                continue
            f = _truth_offset(ta, tb, res.t0_ns)
            span = _eval_span(ta, res.t0_ns, res.ref_span_s[1])
            fit = res.fit
            est7 = float(fit.offset_s(span) - fit.offset_s(0.0)) * 7 * DAY / span
            r = {"aligned": True, "model": fit.model,
                 "offset_err_s": float(fit.initial_offset_s - f(0.0)),
                 "day7_err_s": float(est7 - _day7(f, span)),
                 "rmse_samples": float(fit.rmse)}
            if halt:
                hb = tb["clock"]["halts"][0]
                gaps = [g for g in res.as_dict()["steps"] if g.get("kind") == "gap"
                        and g["device"] == "other"]
                t_h = (hb["start_device_ns"] - res.t0_ns) / 1e9 - float(f(0.0))
                r["halt_found"] = any(abs(g["time_s"] - t_h) < 3600 for g in gaps)
            if scenario == "temperature" and method == "robust":
                r["heldout_with"] = fit.diagnostics["temperature"].get("heldout_rmse_with")
                r["heldout_without"] = fit.diagnostics["temperature"].get("heldout_rmse_without")
            row[method] = r
        return row


def run_clockstop_seed(args):
    _, seed, days, hz, _ = args
    from stillpoint.engine.alignment import AlignConfig, estimate_alignment
    from stillpoint.tools import testdoubles  # noqa: F401  (tests/ on sys.path)
    from synthetic_alignment import DeviceClock, SyntheticPair
    rng = np.random.default_rng(20_000 + seed)
    halt = float(rng.uniform(2, 400))
    at = float(rng.uniform(1.05, min(days, 6.0) - 0.1)) * DAY
    pair = SyntheticPair(seed=seed, duration_s=days * DAY, rate_ref=hz, rate_other=hz,
                         clock_ref=DeviceClock(offset_s=0.0, skew_ppm=float(rng.uniform(-50, 50))),
                         clock_other=DeviceClock(offset_s=float(rng.uniform(-10, 10)),
                                                 skew_ppm=float(rng.uniform(-50, 50)),
                                                 halt_at_s=at, halt_s=halt))
    tr = pair.truth()
    row = {"scenario": "clockstop", "seed": seed, "halt_s": round(halt, 1)}
    t_ref = float(pair.clock(0, at) - pair.first_sample_clock(0))
    for method in ("robust", "brond"):
        cfg = AlignConfig(method=method, max_lag_s=600.0 if method == "brond" else None)
        t = time.perf_counter()
        res = estimate_alignment(pair.source(0), pair.source(1), cfg)
        row[f"{method}_s"] = round(time.perf_counter() - t, 1)
        if not res.ok:
            row[method] = {"aligned": False, "reason": res.reason[:60]}
            continue
        fit = res.fit
        r = {"aligned": True, "model": fit.model,
             "offset_err_s": fit.initial_offset_s - tr["initial_offset_s"],
             "day7_err_s": fit.drift_day7_s - tr["drift_day7_s"], "rmse_samples": fit.rmse}
        r["halt_found"] = any(s.window_s[0] - 1 <= t_ref <= s.window_s[1] + 1
                              and s.window_s[1] - s.window_s[0] <= 3600 for s in fit.steps)
        row[method] = r
    return row


def _fmt(r):
    if r is None:
        return "-"
    if not r.get("aligned"):
        return "NOT ALIGNED " + r.get("reason", "")[:30]
    s = f"{r['model'][:18]:18s} off {r['offset_err_s'] * 1000:+8.1f} ms  d7 {r['day7_err_s']:+7.3f} s"
    if "halt_found" in r:
        s += f"  halt {'found' if r['halt_found'] else 'MISSED'}"
    if r.get("heldout_with") is not None:
        s += f"  heldout {r['heldout_with']:.2f}/{r['heldout_without']:.2f}"
    return s


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--days", type=float, default=7.0)
    ap.add_argument("--hz", type=float, default=50.0)
    ap.add_argument("--scenarios", default="linear,halt,clockstop,temperature")
    ap.add_argument("--sites", default="wrist,hip")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--json", help="also write all rows to this JSON file")
    a = ap.parse_args(argv)
    sites = tuple(a.sites.split(","))
    rows = []
    t0 = time.perf_counter()
    for sc in a.scenarios.split(","):
        fn = run_clockstop_seed if sc == "clockstop" else run_sim_seed
        jobs = [(sc, s, a.days, a.hz, sites) for s in range(1, a.seeds + 1)]
        print(f"== {sc}: {a.seeds} seeds, {a.days:g} days at {a.hz:g} Hz, "
              f"{'synthetic pair' if sc == 'clockstop' else '/'.join(sites)}", flush=True)
        with ProcessPoolExecutor(a.jobs) as ex:
            for row in ex.map(fn, jobs):
                rows.append(row)
                extra = f" halt {row['halt_s']:.0f} s" if row.get("halt_s") else ""
                print(f"seed {row['seed']:2d}{extra:12s} robust: {_fmt(row.get('robust'))}\n"
                      f"{'':20s}brond:  {_fmt(row.get('brond'))}", flush=True)
        sel = [r for r in rows if r["scenario"] == sc]
        for m in ("robust", "brond"):
            ok = [r[m] for r in sel if r.get(m, {}).get("aligned")]
            if sc in ("linear", "temperature"):
                good = sum(abs(r["offset_err_s"]) <= 1 / RATE and abs(r["day7_err_s"]) <= 0.1
                           for r in ok)
                msg = f"offset within 1 sample and day-7 within 0.1 s: {good}/{len(sel)}"
                if sc == "temperature" and m == "robust":
                    chosen = sum(r["model"].endswith("temperature") for r in ok)
                    better = sum((r.get("heldout_with") or 9e9) < (r.get("heldout_without") or 0)
                                 for r in ok)
                    msg += (f"; temperature term chosen (dBIC + held-out) {chosen}/{len(sel)}, "
                            f"held-out RMSE with < without {better}/{len(sel)}")
            else:
                good = sum(r.get("halt_found", False) and abs(r["day7_err_s"]) < 0.5 for r in ok)
                msg = f"halt found within one block and day-7 error < 0.5 s: {good}/{len(sel)}"
            if ok:
                oe = np.array([abs(r["offset_err_s"]) for r in ok])
                de = np.array([abs(r["day7_err_s"]) for r in ok])
                msg += (f"; |offset err| median {np.median(oe) * 1000:.1f} ms max "
                        f"{oe.max() * 1000:.1f} ms; |day-7 err| median {np.median(de):.3f} s "
                        f"max {de.max():.3f} s")
            print(f"   {m:6s} {msg}", flush=True)
    print(f"total {time.perf_counter() - t0:.0f} s")
    if a.json:
        with open(a.json, "w") as f:
            json.dump(rows, f, indent=1, default=float)
    return 0


if __name__ == "__main__":
    sys.exit(main())
