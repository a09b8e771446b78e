"""`stillpoint simulate`: write a simulated recording (.cwa, .bin or .gt3x) with its ground truth."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from ._numbers import RATE_HZ, SEED, number

NAME = "simulate"
KEEPS_EXISTING_OUTPUTS = True  # --overwrite replaces an existing output
HELP = "simulate a free-living recording (AX3/AX6 .cwa, GENEActiv .bin or ActiGraph .gt3x) with ground truth"


def _description() -> str:
    from stillpoint.engine.sim.model import DEFAULT_EFFECTS, effect_help
    return f"""Simulate a wearer (multi-day free-living behaviour at a body site) and a sensor with
named error effects, and write a real recording through the project's writers, plus a truth JSON
(every effect parameter, the clock model, halts/restarts) and a per-10 s-window label CSV (truly
still or not, activity, posture, temperature, true mean acceleration).

Effects (--effects NAME,NAME,...; default: {','.join(DEFAULT_EFFECTS)}; 'none' = an ideal
sensor except the file's own clipping and quantisation). Parameters not given are drawn from
typical values (recorded in the truth). Order of application: as listed.
{effect_help()}

Effect parameters: --effect NAME:KEY=VALUE[UNIT],KEY=VALUE[UNIT] (repeatable; switches the effect
on). KEY is the parameter (z_mg_per_c) or its short form: an axis letter (x, y, z), 'all' for the
three axes, or the parameter's stem (tau, skew, offset, pct, count ...). Units convert to the
parameter's unit: g/mg/ug, mg/C, %/ppm, s/min/h/d, ug/rtHz. Examples:
  --effect temperature:z=3.9mg/C        (temperature = temperature_offset)
  --effect offset:x=20mg,y=-15mg,z=0.08g
  --effect clock:offset=3s,skew=-25ppm
  --effect halts:at=26h,duration=300s   --effect restarts:at=50h,gap=4min
  --effect corrupt_sectors:count=5      --effect thermal_lag:tau=10min
--model MODEL.json takes a model file (format stillpoint.sensor_model, as written by
`stillpoint discrepancy` or --save-model; a truth JSON works too) as the base.
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.description = _description()
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.add_argument("-o", "--output", required=True, help="output file (.cwa for ax3/ax6, .bin for geneactiv, .gt3x for gt3x)")
    p.add_argument("--device", default="ax3", choices=("ax3", "ax6", "geneactiv", "gt3x"))
    p.add_argument("--site", default="wrist", choices=("wrist", "hip", "thigh", "ankle"))
    from stillpoint.engine.sim.wearer import WEARERS
    p.add_argument("--wearer", default="default", choices=tuple(WEARERS),
                   help="the wearer's behaviour: 'default' a typical adult, 'shift' a night-shift "
                        "worker asleep 05:00-14:00, 'still' a sedentary older participant with long still periods, long nights and long "
                        "off-wrist periods (engine/sim/wearer.py WEARERS)")
    p.add_argument("--days", type=number(0, 366, lo_open=True, unit="days"), default=7.0, help="duration in days (fractions allowed)")
    p.add_argument("--hz", type=RATE_HZ, default=100.0, help="nominal sample rate")
    p.add_argument("--range", dest="range_g", type=number(1, 16, integer=True), default=None,
                   help="accelerometer range in g (AX: 2, 4, 8, 16; default AX3 8, AX6 16)")
    p.add_argument("--unpacked", action="store_true", help="AX3: 16-bit unpacked sectors instead of packed")
    p.add_argument("--gyro", type=number(0, 100_000, lo_open=True, unit="dps"), default=2000.0, metavar="DPS",
                   help="AX6 gyro range in dps (125-2000; 0 = accelerometer only)")
    p.add_argument("--effects", default=None, help="comma-separated effect names (see above)")
    p.add_argument("--effect", action="append", default=[], metavar="NAME:KEY=VALUE,...",
                   help="switch an effect on with parameters (repeatable)")
    p.add_argument("--model", default=None, help="sensor model JSON to start from")
    p.add_argument("--seed", type=SEED, default=1)
    p.add_argument("--start", default=None, help="start time, ISO 8601 (default 2025-03-03T10:00Z)")
    p.add_argument("--truth", default=None, help="truth JSON path (default: <output stem>.truth.json)")
    p.add_argument("--pair", default=None, choices=("wrist", "hip", "thigh", "ankle"),
                   help="also simulate a second device at this site on the same body")
    p.add_argument("--pair-output", default=None, help="second device's file (default: <stem>.<site><ext>)")
    p.add_argument("--pair-device", default=None, choices=("ax3", "ax6", "geneactiv", "gt3x"))
    p.add_argument("--pair-hz", type=RATE_HZ, default=None, help="second device's sample rate (default --hz)")
    p.add_argument("--pair-effect", action="append", default=[], metavar="NAME:KEY=VALUE,...",
                   help="an effect for the second device only (e.g. halts:at=30h,duration=120s); "
                        "--effects/--effect/--model apply to both devices, each drawing its own "
                        "values for parameters not given")
    p.add_argument("--save-model", default=None, help="also write the resolved sensor model JSON here")
    p.add_argument("--json", action="store_true", help="print a JSON summary")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress on stderr")
    from . import _static_scenarios
    _static_scenarios.add_arguments(p)


# options that only one kind of run reads: option -> (its default, the runs that read it)
_ONLY_FOR = {
    "order": (None, ("sixface",)), "hold_s": (10.0, ("sixface",)),
    "minutes": (20.0, ("infant",)), "sleep": ([], ("infant",)), "controls": (False, ("infant",)),
    "skew_ppm": (0.0, ("infant",)), "device_id": (None, ("sixface", "infant")),
    "cross_axis": (0.0, ("sixface", "infant")), "sensor_errors": ("table2", ("sixface", "infant")),
    "coupling": (0.0, ("sixface", "infant")), "table_tilt_deg": (0.0, ("sixface",)),
    "pair_output": (None, ("pair",)), "pair_device": (None, ("pair",)),
    "pair_hz": (None, ("pair",)), "pair_effect": ([], ("pair",)),
    "wearer": ("default", ("free-living",)),
}


def _check_ignored(args) -> None:
    """Refuse an option the requested run would not read (it was silently ignored)."""
    from stillpoint.engine.sim.model import ModelError
    runs = {getattr(args, "scenario", "free-living")} | ({"pair"} if getattr(args, "pair", None) else set())
    for name, (default, used_by) in _ONLY_FOR.items():
        if getattr(args, name, default) != default and not runs & set(used_by):
            need = " or ".join("--pair SITE" if u == "pair" else f"--scenario {u}" for u in used_by)
            raise ModelError(f"--{name.replace('_', '-')} applies with {need} only; it would be "
                             "ignored here")


def run(args) -> int:
    from stillpoint.engine.sim.model import ModelError, parse_effect_option
    from stillpoint.engine.sim.record import build_model, simulate_pair, simulate_recording
    from stillpoint.engine.sim.wearer import wearer_params

    _check_ignored(args)
    if getattr(args, "scenario", "free-living") != "free-living":
        from . import _static_scenarios
        return _static_scenarios.run(args)
    out = Path(args.output)
    ext = {"ax3": ".cwa", "ax6": ".cwa", "geneactiv": ".bin", "gt3x": ".gt3x"}[args.device]
    if not (out.name.endswith(ext) or out.name.endswith(ext + ".gz")):
        raise ModelError(f"{out}: a {args.device} recording needs a {ext} file name")
    overrides = [parse_effect_option(e) for e in args.effect]
    effects = args.effects
    if effects is None and args.model is None:
        effects = "default"
    model = build_model(effects, model=args.model, overrides=overrides)
    if args.save_model:
        from stillpoint.engine.core.outputs import check_output_path
        check_output_path(args.save_model, what="model")
    common = dict(days=args.days, hz=args.hz, seed=args.seed, start=args.start,
                  range_g=args.range_g, packed=False if args.unpacked else None,
                  gyro_range_dps=args.gyro if args.device == "ax6" else None,
                  wearer=wearer_params(getattr(args, "wearer", "default")))
    t0 = time.perf_counter()
    from stillpoint.engine.progress import Progress
    bar = Progress("simulate", quiet=args.quiet)
    common["progress"] = bar.update
    try:
        if args.pair:
            dev_b = args.pair_device or args.device
            ext_b = {"ax3": ".cwa", "ax6": ".cwa", "geneactiv": ".bin", "gt3x": ".gt3x"}[dev_b]
            stem = out.name[: -len(ext)] if out.name.endswith(ext) else out.stem
            out_b = Path(args.pair_output) if args.pair_output else out.with_name(f"{stem}.{args.pair}{ext_b}")
            if common["gyro_range_dps"] is None and dev_b == "ax6":
                common["gyro_range_dps"] = args.gyro
            model_b = build_model(None, model=model, overrides=[parse_effect_option(e) for e in args.pair_effect])
            truths = simulate_pair(out, out_b, site_a=args.site, site_b=args.pair, device_a=args.device,
                                   device_b=dev_b, effects=model, effects_b=model_b, truth_a=args.truth,
                                   hz_b=args.pair_hz, **common)
        else:
            truths = [simulate_recording(out, device=args.device, site=args.site, effects=model,
                                         truth_path=args.truth, **common)]
    except ValueError as e:
        bar.close(completed=False)
        if isinstance(e, ModelError):
            raise
        raise ModelError(str(e)) from None
    except BaseException:
        bar.close(completed=False)
        raise
    bar.close()
    elapsed = time.perf_counter() - t0
    if args.save_model:
        from stillpoint.engine.core.outputs import atomic_output
        with atomic_output(args.save_model, binary=False, what="model") as f:
            f.write(truths[0].sensor_model.to_json() + "\n")
    summary = [{"path": t.path, "truth": t.truth_path,
                "labels": t.labels_path, "device": t.device["kind"], "site": t.site,
                "samples": t.samples_written, "effects": list(t.sensor_model.effects),
                "still_hours_per_day": round(t.summary["still_hours_per_day"], 2),
                "clock_drift_s_per_day": round(_drift_per_day(t), 3),
                "corrupt_sectors": t.corrupt_sectors} for t in truths]
    if args.json:
        json.dump({"recordings": summary, "seconds": round(elapsed, 2)}, sys.stdout, indent=1)
        print()
    else:
        for s in summary:
            print(f"{s['path']}: {s['device']} at the {s['site']}, {s['samples']} samples, "
                  f"effects {', '.join(s['effects']) or 'none'}")
            print(f"  truth {s['truth']}, labels {s['labels']}; still {s['still_hours_per_day']} h/day, "
                  f"clock drift {s['clock_drift_s_per_day']:+.3f} s/day"
                  + (f", corrupt sectors {s['corrupt_sectors']}" if s["corrupt_sectors"] else ""))
        print(f"done in {elapsed:.1f} s")
    return 0


def _drift_per_day(t) -> float:
    tab = t.clock["table"]
    ts, off = tab["true_s"], tab["device_minus_true_s"]
    if len(ts) < 2 or ts[-1] <= 0:
        return 0.0
    return (off[-1] - off[0]) / (ts[-1] - ts[0]) * 86400.0
