"""Why the autocalibration misses on the simulator's default recordings: exact ablations.

    python tools/crosschecks/calibration_cause.py [--seeds 11 3 7] [--hours 72] [--resimulate]

For each seed the simulator's default device (AX3 packed +-8 g, 100 Hz, adult wrist, default
effects) is generated in memory for the first ``--hours`` (72 h: the data the batch schedule's
first load fits on). Every 10 s window (true time) gets several means computed from the *same*
samples, so exactly one thing differs between the rows:

* ``stored``       the counts as a file holds them (what ``calibrate`` sees)
* ``no quantisation``  the measured values before quantisation (same noise, bias, everything)
* ``no quantisation, no bias instability``  the same minus the simulated bias wander
* ``noise-free``   the deterministic sensor model applied to the true window mean (offset,
                   gain, temperature offset only): what a perfect window mean would be
* ``+5 mg within-window motion``  the measured values plus 5 mg of white variation per sample,
                   then stored: what the micro-movement of a worn still wrist (real still-window
                   SDs are 6-11 mg) would do to the quantisation

All rows use the same windows (selected on the stored samples: SD < 13 mg, |mean| < 2 g,
repeats collapsed) and the same temperatures (the stored 10-bit sector codes), so the rows
separate quantisation, bias instability, noise and the window selection / temperature spread.
Errors are fit minus truth in the GGIR form at the fit's reference temperature.

``--resimulate`` also re-simulates each seed with one default effect switched off at a time
(bias_instability, rate_error, clock) and unpacked storage (3.9 mg steps), fitted by the
engine's own ``calibrate_source`` path.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from stillpoint.engine.calibration import fit_calibration, select_calibration_windows
from stillpoint.engine.features import WindowFeatures
from stillpoint.engine.sim import SensorModel, apply_deterministic, ggir_equivalent
from stillpoint.engine.sim.device import make_devices, build_model
from stillpoint.engine.sim.model import DEFAULT_EFFECTS

WINDOW_S = 10.0
MICRO_MOTION_MG = 5.0  # within-window variation of a worn still wrist (real still-window SDs 6-11 mg)


def _window_sums(idx, x):
    """Per-window sums of x (n, d) for sorted window indices idx (n,)."""
    starts = np.r_[0, np.nonzero(np.diff(idx))[0] + 1]
    return idx[starts], np.add.reduceat(x, starts, axis=0), np.diff(np.r_[starts, idx.size])


def window_table(sim, hours: float):
    """Window means of several variants of the same samples (see the module docstring)."""
    cpg = sim.spec.counts_per_g
    end_s = hours * 3600.0
    acc = {k: [] for k in ("win", "n", "stored", "stored_sq", "meas", "true", "temp", "dith")}
    rng = np.random.default_rng(sim.seed)
    for c in sim.chunks():
        keep = c.true_s < end_s
        if not np.any(keep):
            break
        t = c.true_s[keep]
        w = (t // WINDOW_S).astype(np.int64)
        stored = c.counts[keep] / cpg
        traw = np.clip(np.rint((c.temperature_c[keep] + 50.0) * (256.0 / 75.0)), 0, 1023)
        temp = traw * 75.0 / 256.0 - 50.0  # the stored sector code (cwa-format)
        win, s_sum, n = _window_sums(w, stored)
        _, s_sq, _ = _window_sums(w, stored * stored)
        _, m_sum, _ = _window_sums(w, c.measured_g[keep].astype(np.float64))
        _, t_sum, _ = _window_sums(w, c.true_g[keep].astype(np.float64))
        _, T_sum, _ = _window_sums(w, temp[:, None])
        # the same samples with MICRO_MOTION_MG of extra within-window variation before storage
        extra = c.measured_g[keep] + rng.standard_normal(stored.shape) * (MICRO_MOTION_MG / 1e3)
        _, d_sum, _ = _window_sums(w, sim.spec.to_counts(extra) / cpg)
        for k, v in (("win", win), ("n", n), ("stored", s_sum), ("stored_sq", s_sq),
                     ("meas", m_sum), ("true", t_sum), ("temp", T_sum[:, 0]), ("dith", d_sum)):
            acc[k].append(v)
        if not np.all(keep):
            break
    win = np.concatenate(acc["win"])
    n = np.concatenate(acc["n"]).astype(np.float64)
    # a window can straddle a chunk boundary: merge its pieces
    uw, inv = np.unique(win, return_inverse=True)

    def merge(a):
        a = np.concatenate(a)
        out = np.zeros((uw.size,) + a.shape[1:])
        np.add.at(out, inv, a)
        return out
    nn = merge([np.concatenate(acc["n"]).astype(np.float64)])
    s, sq = merge(acc["stored"]), merge(acc["stored_sq"])
    meas, true, temp = merge(acc["meas"]), merge(acc["true"]), merge(acc["temp"])
    dith = merge(acc["dith"])
    full = nn >= 0.95 * WINDOW_S * sim.hz
    nn = nn[full]
    mean = s[full] / nn[:, None]
    var = (sq[full] - nn[:, None] * mean * mean) / (nn[:, None] - 1)
    start_ns = sim.start_ns + (uw[full] * WINDOW_S * 1e9).astype(np.int64)
    feats = WindowFeatures.from_arrays(mean, np.sqrt(np.clip(var, 0, None)), temp[full] / nn,
                                       start_ns=start_ns, n=nn)
    tmid = (uw[full] + 0.5) * WINDOW_S
    bias = np.column_stack([np.interp(tmid, sim.t_grid, sim.bias_grid[:, k]) for k in range(3)])
    return feats, {"meas": meas[full] / nn[:, None], "true": true[full] / nn[:, None],
                   "dithered": dith[full] / nn[:, None],
                   "bias": bias, "accel_temperature": np.interp(tmid, sim.t_grid, sim.Ta_grid)}


def truth_model(sim) -> SensorModel:
    return SensorModel({k: v for k, v in sim.model.effects.items()
                        if k in ("offset", "gain", "temperature_offset")})


def errors(est, tm: SensorModel) -> dict:
    g = ggir_equivalent(tm, est.temperature_ref)
    return {"offset_mg": (est.offset - np.array(g["offset"])) * 1e3,
            "gain_pct": (est.scale / np.array(g["scale"]) - 1) * 100,
            "tempoffset_mg_c": (est.tempoffset - np.array(g["tempoffset"])) * 1e3}


def fmt(e: dict) -> str:
    return (" ".join(f"{v:+6.2f}" for v in e["offset_mg"]) + " | "
            + " ".join(f"{v:+7.4f}" for v in e["gain_pct"]) + " | "
            + " ".join(f"{v:+6.3f}" for v in e["tempoffset_mg_c"]))


def ablate(seed: int, hours: float, days: float = 7.0) -> None:
    t0 = time.perf_counter()
    [sim] = make_devices(sites=["wrist"], devices=["ax3"], days=days, hz=100.0, seed=seed,
                         effects=build_model(None))
    feats, alt = window_table(sim, hours)
    sel = select_calibration_windows(feats)
    keep = np.isin(feats.start_ns, sel.features.start_ns)
    tm = truth_model(sim)
    f = sel.features
    T = f.temperature
    print(f"seed {seed}: {len(feats)} windows, {len(f)} nonmovement; window temperature "
          f"p5/p50/p95 {np.percentile(T, 5):.2f}/{np.percentile(T, 50):.2f}/"
          f"{np.percentile(T, 95):.2f} degC, SD {T.std():.2f} degC "
          f"({time.perf_counter() - t0:.0f} s)")
    print("  variant                                  offset x y z (mg)     |"
          " gain x y z (%)             | tempoffset x y z (mg/degC)")
    rows = [("stored counts (what calibrate sees)", f.mean),
            (f"stored, +{MICRO_MOTION_MG:g} mg within-window motion", alt["dithered"][keep]),
            ("no quantisation (same samples)", alt["meas"][keep]),
            ("no quantisation, no bias instability", alt["meas"][keep] - alt["bias"][keep])]
    det = apply_deterministic(alt["true"][keep], tm, temperature_c=alt["accel_temperature"][keep])
    rows.append(("noise-free window means", det))
    for name, mean in rows:
        ff = WindowFeatures.from_arrays(mean, f.sd, T, start_ns=f.start_ns)
        est = fit_calibration(ff, select=False, variant="c2")
        print(f"  {name:40s} {fmt(errors(est, tm))}   ({est.status}, {est.error_after_mg:.2f} mg)")
    q = f.mean - alt["meas"][keep]
    print(f"  quantisation bias of the window means: SD {q.std(axis=0).round(5) * 1e3} mg, "
          f"max |.| {np.abs(q).max(axis=0).round(5) * 1e3} mg")
    b = alt["bias"][keep]
    print(f"  bias instability at the windows: SD {b.std(axis=0).round(5) * 1e3} mg")
    sys.stdout.flush()


def resimulate(seed: int, days: float) -> None:
    from stillpoint.engine.calibration.recording import calibrate_source
    from stillpoint.engine.sim import SimSource

    tm = None
    print(f"seed {seed}: re-simulated, one effect off at a time (calibrate_source, {days:g} days)")
    for label, effects, packed in (
            ("default", list(DEFAULT_EFFECTS), None),
            ("- bias_instability", [e for e in DEFAULT_EFFECTS if e != "bias_instability"], None),
            ("- rate_error", [e for e in DEFAULT_EFFECTS if e != "rate_error"], None),
            ("- clock", [e for e in DEFAULT_EFFECTS if e != "clock"], None),
            ("unpacked (3.9 mg steps)", list(DEFAULT_EFFECTS), False)):
        kw = {} if packed is None else {"packed": packed}
        src = SimSource(days=days, seed=seed, effects=build_model(effects), **kw)
        if tm is None:
            tm = truth_model(src.sim)
        est = calibrate_source(src, variant="c2").estimate
        print(f"  {label:40s} {fmt(errors(est, tm))}   ({est.status}, {est.error_after_mg:.2f} mg,"
              f" {est.windows} windows)")
        sys.stdout.flush()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[11, 3, 7])
    ap.add_argument("--hours", type=float, default=72.0)
    ap.add_argument("--days", type=float, default=7.0, help="simulated length (default 7)")
    ap.add_argument("--resimulate", action="store_true")
    args = ap.parse_args(argv)
    for s in args.seeds:
        ablate(s, args.hours, args.days)
        if args.resimulate:
            resimulate(s, args.days)
    return 0


if __name__ == "__main__":
    sys.exit(main())
