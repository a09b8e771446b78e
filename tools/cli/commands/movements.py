"""`stillpoint movements FILE [RIGHT_FILE]`: count infant leg movements per leg (Smith et al. 2015
detector as in the Oh, Loeb & Smith 2024 reference code), each leg with its own device's static
calibration."""

from __future__ import annotations

import csv
import json
from pathlib import Path

from ._numbers import number

NAME = "movements"
HELP = "count infant leg movements per leg (AX6 ankle recordings), with static calibration"
KEEPS_EXISTING_OUTPUTS = True  # --overwrite replaces an existing output
DESCRIPTION = (HELP + ". FILE is the left leg, RIGHT_FILE the right; legs are processed "
               "independently. Calibrate each with `--calibration CAL.json` (one per file, in "
               "order; from `static-calibrate -o`) or `--store` (the store's latest static "
               "calibration of each device).")

CSV_COLUMNS = ("leg", "file", "device", "start_index", "second_crossing_index", "end_index",
               "start_ns", "end_ns", "duration_s", "average_ms2", "peak_ms2")


def add_arguments(p) -> None:
    p.add_argument("file", type=Path, help="left-leg recording (AX6 .cwa)")
    p.add_argument("right_file", type=Path, nargs="?", help="right-leg recording (AX6 .cwa)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--calibration", type=Path, action="append", default=[], metavar="CAL.json",
                   help="static calibration JSON (repeat: one per file, in file order)")
    g.add_argument("--store", nargs="?", const="", default=None, metavar="DIR",
                   help="use each device's latest static calibration from the store")
    p.add_argument("--full-matrix", action="store_true",
                   help="apply the calibration's full 3x3 matrix (it must have one)")
    p.add_argument("--variant", choices=("v1", "v2"), default="v2",
                   help="threshold variant: v2 = HBCD release (default), v1 = earlier code")
    p.add_argument("--filter", choices=("none", "2tap", "lowpass8"), default="none",
                   help="none (HBCD release), 2tap = the reference's 'first-order 8 Hz FIR' "
                        "(really a 2-sample average), lowpass8 = a real zero-phase 8 Hz low-pass")
    p.add_argument("--resample", type=number(0, 5000, lo_open=True, unit="Hz"), default=None,
                   metavar="HZ",
                   help="resample onto a uniform grid first (the HBCD release also reports 20 Hz)")
    p.add_argument("--accel-only", action="store_true",
                   help="AX3/GENEActiv: run without the gyro gate (NOT VALIDATED)")
    p.add_argument("--strict-gyro", action="store_true",
                   help="require rotation on every sample of a movement (the paper's wording) "
                        "instead of at the samples the reference code checks")
    p.add_argument("--nominal-time", action="store_true",
                   help="reference arithmetic: samples / nominal rate for durations and rates "
                        "(default: the recording's timestamps)")
    p.add_argument("--json", action="store_true", help="print the per-leg summaries as JSON")
    p.add_argument("-o", "--output", type=Path, help="CSV, one row per movement")
    p.add_argument("--plot", type=Path, metavar="PNG", help="figure: detrended norm, thresholds, "
                                                            "movements")
    p.add_argument("--mcap", type=Path, metavar="OUT.mcap",
                   help="log calibrations, detection parameters, every movement and the summaries")


def _calibrations(args, files):
    from stillpoint.engine.recordings import open_recording
    from stillpoint.engine.calibration.static import (StaticCalibration, load_static_calibration)

    from ._runopts import OptionError
    if args.calibration:
        if len(args.calibration) != len(files):
            raise OptionError(f"--calibration given {len(args.calibration)} time(s) for "
                              f"{len(files)} file(s): give one per file, in file order")
        return [load_static_calibration(p) for p in args.calibration]
    if args.store is not None:
        from stillpoint.engine.calibration import CalibrationStore
        store = CalibrationStore(args.store or None)
        out = []
        for f in files:
            src = open_recording(f)
            key = src.info.device_key
            src.close()
            est = store.latest_static(key)
            if est is None:
                raise OptionError(f"{f}: the store ({store.dir}) holds no static calibration of "
                                  f"device {key}; run `stillpoint static-calibrate CAL.cwa --store`")
            out.append(StaticCalibration.from_estimate(est))
        return out
    return [None] * len(files)


def human(label: str, s: dict) -> str:
    r = s["rate_per_hour_awake"]
    cal = s["calibration"]
    lines = [f"{label} leg: {s['file']} ({s['device']})",
             f"  thresholds {s['threshold_positive_ms2']:+.3f} / {s['threshold_negative_ms2']:+.3f} m/s² "
             f"(variant {s['variant']}, filter {s['filter']}, {s['fs_hz']} Hz)",
             f"  movements {s['count']} (candidates {s['candidates']}, cycle filter removed "
             f"{s['removed_by_cycle_filter']})",
             f"  recording {s['recording_hours']:.3f} h, sleep {s['sleep_hours']:.3f} h, awake "
             f"{s['awake_hours']:.3f} h, rate {'n/a' if r is None else f'{r:.1f}'} per hour awake",
             "  calibration: " + (f"static ({cal['mode']} mode), {cal.get('gap_hours', float('nan')):.1f} h "
                                  "before the recording" if cal.get("applied") else "none (raw readings)")]
    for f in s["flags"]:
        lines.append(f"  note: {f}")
    return "\n".join(lines)


def run(args) -> int:
    from stillpoint.drivers.names import csv_cell
    from stillpoint.engine.core.outputs import atomic_output, check_distinct_outputs, check_output_path
    from stillpoint.engine.core.jsonsafe import dumps
    from stillpoint.engine.movements import count_leg

    from ._runopts import OptionError
    files = [args.file] + ([args.right_file] if args.right_file else [])
    labels = ["left", "right"] if len(files) == 2 else ["left"]
    check_distinct_outputs({"movements CSV": args.output, "plot": args.plot, "MCAP": args.mcap})
    for p in (args.output, args.plot, args.mcap):
        if p is not None:
            check_output_path(p)
    if args.resample is not None and args.resample <= 0:
        raise OptionError("--resample must be positive")
    cals = _calibrations(args, files)
    if args.full_matrix and any(c is None or c.matrix is None for c in cals):
        raise OptionError("--full-matrix needs a calibration made with `static-calibrate --full-matrix`")
    results = []
    for f, cal in zip(files, cals):
        results.append(count_leg(f, cal, variant=args.variant, filter=args.filter,
                                 resample_hz=args.resample, accel_only=args.accel_only,
                                 timing="nominal" if args.nominal_time else "real",
                                 full_matrix=True if args.full_matrix else None,
                                 keep_signals=bool(args.plot), strict_gyro=args.strict_gyro))
    legs = [r[0] if isinstance(r, tuple) else r for r in results]
    outputs = {}
    if args.output:
        with atomic_output(args.output, binary=False, what="movements CSV") as fh:
            w = csv.DictWriter(fh, fieldnames=CSV_COLUMNS)
            w.writeheader()
            for label, leg in zip(labels, legs):
                for row in leg.rows():
                    w.writerow({k: csv_cell(v) for k, v in
                                dict(row, leg=label, file=leg.path, device=leg.device_key).items()})
        outputs["csv"] = str(args.output)
    if args.plot:
        from stillpoint.engine.movements.plot import plot_movements
        plot_movements([(lab, *r) for lab, r in zip(labels, results)], args.plot)
        outputs["plot"] = str(args.plot)
    if args.mcap:
        from stillpoint.engine.movements.mcap_out import write_movements_mcap
        write_movements_mcap(args.mcap, list(zip(labels, legs, cals)))
        outputs["mcap"] = str(args.mcap)
    summaries = {lab: leg.summary() for lab, leg in zip(labels, legs)}
    if args.json:
        print(json.dumps(dict(json.loads(dumps(summaries)), outputs=outputs), indent=1, sort_keys=True))
    else:
        for lab in labels:
            print(human(lab, summaries[lab]))
        if outputs:
            print("outputs: " + ", ".join(f"{k} {v}" for k, v in outputs.items()))
    return 0
