"""Do the reported standard errors cover the truth? Coverage of +-2 SE intervals on simulated
recordings, and the block bootstrap beside the sandwich.

    python tools/crosschecks/calibration_coverage.py [--recordings 50] [--days 3] [--hz 100] [--unpacked]
        [--bootstrap-every 5] [--replicates 100] [--first-seed 100]

Each recording is the simulator's default device (adult wrist, AX3 packed +-8 g unless
``--unpacked``, every default effect: offset, gain, temperature offset, bias instability, noise,
clipping, quantisation, rate error, clock) with its own seed, generated in memory (``SimSource``:
the same counts a file would hold) and calibrated by ``calibrate_source`` (the path of
``stillpoint calibrate``). 3 days = the 72 h first load that ``calibrate`` fits on a week.

Per recording:

* the C2 fit (``variant="c2"``: temperature term kept whatever its SE) -> z = (fit - truth) / SE
  for every offset, scale and temperature coefficient (truth in the GGIR form at the fit's
  T_ref);
* the default (``auto``) fit -> whether the temperature term was kept; its coefficients' z
  (C1: compared at the windows' mean temperature) and, where the term is kept, its error;
* every ``--bootstrap-every``-th recording: block-bootstrap SEs (``--replicates`` refits on
  blocks drawn with replacement) against the sandwich SEs.

Prints one line per recording and a summary: coverage of +-2 SE (nominal 95.4 %) per
coefficient kind, |z| quantiles, and the bootstrap / sandwich SE ratios.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

from stillpoint.engine.calibration import fit_calibration, select_calibration_windows
from stillpoint.engine.calibration.fit import icp_sphere_fit
from stillpoint.engine.calibration.quantisation import dequantised
from stillpoint.engine.calibration.recording import calibrate_source
from stillpoint.engine.calibration.uncertainty import block_bootstrap
from stillpoint.engine.sim import SensorModel, SimSource, ggir_equivalent
from stillpoint.engine.sim.device import build_model

KINDS = ("offset", "scale", "tempoffset")


def _se(u: dict, kind: str) -> np.ndarray:
    return np.array([np.nan if v is None else v for v in u[kind]], np.float64)


def zscores(est, truth_model: SensorModel, t_ref: float) -> dict:
    """(fit - truth) / SE per coefficient kind; NaN where no SE (coefficient not fitted)."""
    g = ggir_equivalent(truth_model, t_ref)
    u = est.uncertainty or {k: [None] * 3 for k in KINDS}
    out = {}
    for k in KINDS:
        fit = np.asarray(getattr(est, k), np.float64)
        with np.errstate(invalid="ignore", divide="ignore"):
            out[k] = (fit - np.asarray(g[k])) / _se(u, k)
        out[k + "_error"] = fit - np.asarray(g[k])
    return out


def truth_of(sim) -> SensorModel:
    return SensorModel({k: v for k, v in sim.model.effects.items()
                        if k in ("offset", "gain", "temperature_offset")})


def run_recording(seed: int, *, days: float = 3.0, hz: float = 100.0, packed: bool = True,
                  replicates: int = 0) -> dict:
    """Simulate, calibrate (C2 and auto), score against the truth; optional block bootstrap."""
    src = SimSource(days=days, hz=hz, seed=seed, effects=build_model(None), packed=packed)
    tm = truth_of(src.sim)
    res = calibrate_source(src, variant="c2", read_all=True)
    c2 = res.estimate
    windows = res.windows
    auto = fit_calibration(windows, select=False, quantisation_step_g=src.sim.spec.lsb_g)
    t_mean = float(np.mean(windows.temperature))
    out = {"seed": seed, "windows": c2.windows, "blocks": c2.extra.get("uncertainty_blocks"),
           "temperature_sd": float(np.std(windows.temperature)),
           "c2": zscores(c2, tm, c2.temperature_ref),
           "auto_kept_temperature": auto.uses_temperature,
           "auto": zscores(auto, tm, auto.temperature_ref if auto.uses_temperature else t_mean),
           "c2_se": {k: _se(c2.uncertainty, k) for k in KINDS},
           "warnings": [w["code"] for w in auto.extra.get("warnings", [])]}
    if replicates:
        sel = dequantised(select_calibration_windows(windows).features, src.sim.spec.lsb_g)

        def fit(mean, temp):
            tr = float(np.mean(temp))
            r = icp_sphere_fit(mean, temp - tr)
            return r.offset, r.scale, r.tempoffset, tr
        bs = block_bootstrap(sel.mean, sel.temperature, sel.start_ns, fit, replicates=replicates,
                             seed=seed)
        out["bootstrap_ratio"] = {k: bs[k] / out["c2_se"][k] for k in KINDS}
    return out


def score_file(path) -> dict:
    """``calibrate``'s default fit of a simulated recording (with its ``.truth.json`` beside it),
    and the C2 fit, scored against the truth."""
    from pathlib import Path

    from stillpoint.engine.calibration.recording import calibrate_recording
    from stillpoint.engine.sim import load_truth

    path = Path(path)
    truth = load_truth(path.with_name(path.name.split(".")[0] + ".truth.json"))
    model = truth.sensor_model if hasattr(truth, "sensor_model") else SensorModel.from_dict(
        truth["sensor_model"])
    tm = SensorModel({k: v for k, v in model.effects.items()
                      if k in ("offset", "gain", "temperature_offset")})
    res = calibrate_recording(path)
    auto = res.estimate
    c2 = calibrate_recording(path, variant="c2").estimate
    t_mean = float(np.mean(res.windows.temperature))
    return {"file": str(path), "auto": auto, "c2": c2,
            "z_auto": zscores(auto, tm, auto.temperature_ref if auto.uses_temperature else t_mean),
            "z_c2": zscores(c2, tm, c2.temperature_ref)}


def print_file_scores(paths) -> None:
    for p in paths:
        r = score_file(p)
        for name in ("auto", "c2"):
            est, z = r[name], r["z_" + name]
            print(f"{r['file']} {name:4s} {est.method}: " + "; ".join(
                f"{k} error {' '.join(f'{v * m:+.3f}' for v in z[k + '_error'])} {u} "
                f"(z {' '.join(f'{v:+.1f}' for v in z[k])})"
                for k, m, u in (("offset", 1e3, "mg"), ("scale", 1e2, "%"),
                                ("tempoffset", 1e3, "mg/degC"))
                if np.any(np.isfinite(z[k]))))
        print(f"  warnings: {[w['code'] for w in r['auto'].extra.get('warnings', [])]}")


def coverage(rows: list, fit: str, kind: str) -> tuple[float, int, np.ndarray]:
    z = np.concatenate([r[fit][kind] for r in rows])
    z = z[np.isfinite(z)]
    return (float(np.mean(np.abs(z) <= 2.0)) if z.size else float("nan")), int(z.size), z


def summary(rows: list, args) -> str:
    lines = [f"\n{len(rows)} recordings, {args.days:g} days at {args.hz:g} Hz, AX3 "
             f"{'unpacked' if args.unpacked else 'packed +-8 g'}, simulator default effects"]
    lines.append("coverage of +-2 SE (nominal 95.4 %), C2 fit (temperature term kept):")
    allz = []
    for k in KINDS:
        c, n, z = coverage(rows, "c2", k)
        allz.append(z)
        q = np.percentile(np.abs(z), [50, 95]) if z.size else [np.nan] * 2
        lines.append(f"  {k:10s} {100 * c:5.1f} % of {n}   |z| median {q[0]:.2f}, p95 {q[1]:.2f}, "
                     f"max {np.abs(z).max():.2f}")
    z = np.concatenate(allz)
    lines.append(f"  all        {100 * np.mean(np.abs(z) <= 2):5.1f} % of {z.size}")
    kept = [r for r in rows if r["auto_kept_temperature"]]
    lines.append(f"default (auto): temperature term kept in {len(kept)} of {len(rows)} "
                 "(dropped where its SE > 0.05 mg/degC and it cannot be told from zero)")
    for k in ("offset", "scale") + (("tempoffset",) if kept else ()):
        c, n, _ = coverage(rows, "auto", k)
        lines.append(f"  {k:10s} {100 * c:5.1f} % of {n} within +-2 SE")
    if kept:
        e = np.concatenate([np.abs(r["auto"]["tempoffset_error"]) for r in kept]) * 1000
        se = np.concatenate([r["c2_se"]["tempoffset"] for r in kept]) * 1000
        lines.append(f"  where kept: temperature coefficient error max {e.max():.3f} mg/degC, "
                     f"median {np.median(e):.3f}; {np.mean(e <= 0.1) * 100:.1f} % within 0.1; "
                     f"{np.mean(se <= 0.05) * 100:.1f} % of their SEs within 0.05 mg/degC")
    se_t = np.concatenate([r["c2_se"]["tempoffset"] for r in rows]) * 1000
    lines.append(f"C2 temperature coefficient SE: median {np.median(se_t):.3f}, range "
                 f"{se_t.min():.3f}-{se_t.max():.3f} mg/degC")
    bs = [r for r in rows if "bootstrap_ratio" in r]
    if bs:
        lines.append(f"block bootstrap SE / reported SE over {len(bs)} recordings "
                     f"({args.replicates} replicates each): median [p10, p90]")
        for k in KINDS:
            v = np.concatenate([r["bootstrap_ratio"][k] for r in bs])
            v = v[np.isfinite(v)]
            p = np.percentile(v, [10, 50, 90])
            lines.append(f"  {k:10s} {p[1]:.2f} [{p[0]:.2f}, {p[2]:.2f}]")
    codes = {}
    for r in rows:
        for c in r["warnings"]:
            codes[c] = codes.get(c, 0) + 1
    lines.append("warnings of the default fit: " + (", ".join(f"{c} {n}/{len(rows)}"
                                                       for c, n in sorted(codes.items())) or "none"))
    return "\n".join(lines)


def _to_json(r):
    if isinstance(r, dict):
        return {k: _to_json(v) for k, v in r.items()}
    if isinstance(r, (np.ndarray, list, tuple)):
        return [_to_json(v) for v in r]
    if isinstance(r, (np.floating, float)):
        return None if not np.isfinite(r) else float(r)
    if isinstance(r, np.integer):
        return int(r)
    return r


def _from_json(line: str) -> dict:
    def conv(v):
        if isinstance(v, dict):
            return {k: conv(x) for k, x in v.items()}
        if isinstance(v, list) and all(x is None or isinstance(x, (int, float)) for x in v):
            return np.array([np.nan if x is None else x for x in v], np.float64)
        return v
    r = conv(json.loads(line))
    r["warnings"] = list(r["warnings"]) if not isinstance(r["warnings"], np.ndarray) else []
    return r


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--recordings", type=int, default=50)
    ap.add_argument("--first-seed", type=int, default=100)
    ap.add_argument("--days", type=float, default=3.0)
    ap.add_argument("--hz", type=float, default=100.0)
    ap.add_argument("--unpacked", action="store_true", help="AX3 unpacked (3.9 mg steps)")
    ap.add_argument("--bootstrap-every", type=int, default=5,
                    help="block bootstrap on every N-th recording (0: never)")
    ap.add_argument("--replicates", type=int, default=100)
    ap.add_argument("--rows-out", metavar="JSONL",
                    help="also append each recording's scores to this file (one JSON line)")
    ap.add_argument("--summarise", nargs="+", metavar="JSONL",
                    help="instead: print the summary of rows saved by --rows-out (several runs)")
    ap.add_argument("--files", nargs="+", metavar="CWA",
                    help="instead: score `calibrate` on these simulated recordings (each with "
                         "its .truth.json)")
    args = ap.parse_args(argv)
    if args.files:
        print_file_scores(args.files)
        return 0
    if args.summarise:
        rows = [_from_json(line) for f in args.summarise for line in open(f) if line.strip()]
        print(summary(rows, args))
        return 0
    rows = []
    for i in range(args.recordings):
        seed = args.first_seed + i
        t = time.perf_counter()
        boot = args.replicates if args.bootstrap_every and i % args.bootstrap_every == 0 else 0
        r = run_recording(seed, days=args.days, hz=args.hz, packed=not args.unpacked,
                          replicates=boot)
        rows.append(r)
        if args.rows_out:
            with open(args.rows_out, "a") as fh:
                fh.write(json.dumps(_to_json(r)) + "\n")
        z = np.concatenate([r["c2"][k] for k in KINDS])
        print(f"seed {seed}: {r['windows']} windows, {r['blocks']} blocks, C2 |z| max "
              f"{np.nanmax(np.abs(z)):.2f}, tempoffset error "
              f"{' '.join(f'{v * 1000:+.3f}' for v in r['c2']['tempoffset_error'])} mg/degC "
              f"(SE {' '.join(f'{v * 1000:.3f}' for v in r['c2_se']['tempoffset'])}); auto "
              f"{'C2' if r['auto_kept_temperature'] else 'C1'}"
              + (f"; bootstrap/SE tempoffset {np.round(r['bootstrap_ratio']['tempoffset'], 2)}"
                 if "bootstrap_ratio" in r else "")
              + f" ({time.perf_counter() - t:.0f} s)", flush=True)
    print(summary(rows, args))
    return 0


if __name__ == "__main__":
    sys.exit(main())
