"""``stillpoint discrepancy INPUT [--model MODEL.json] [-o REPORT_DIR] [--json]``: find where the
sensor model and the measured nonmovement windows disagree, name the missing effect, add it, and
show the held-out gap shrink. INPUT is a recording (.cwa/.bin, gzip ok), a stillpoint MCAP log or a
CSV of window features (meanx,meany,meanz,sdx,sdy,sdz,temperature).

Without ``-o`` nothing is written; with it the directory gets report.json, report.txt, windows.csv
(per nonmovement window: measured mean, what the start and final models predict, residuals),
final_model.json (the simulator's model format, accepted by ``stillpoint simulate`` as-is) and PNGs
(needs matplotlib: ``pip install 'stillpoint[plot]'``).
"""

from __future__ import annotations

import json
import sys

from stillpoint.engine.core.errors import RecordingError, StillpointError
from ._numbers import MG, RATE_HZ, number

NAME = "discrepancy"
HELP = "name the sensor effects the model misses (held-out gap, dBIC) and write the fitted model"
KEEPS_EXISTING_OUTPUTS = True  # --overwrite replaces an existing output


def add_arguments(parser) -> None:
    parser.add_argument("input", help="recording (.cwa/.bin), MCAP log, or window-feature CSV")
    parser.add_argument("--model", metavar="MODEL.json",
                        help="starting sensor model (simulator JSON; a truth JSON works too); "
                             "default: offset + gain")
    parser.add_argument("-o", "--output", metavar="REPORT_DIR", help="write the report here")
    parser.add_argument("--json", action="store_true", help="print the report as JSON")
    parser.add_argument("--truth", metavar="TRUTH.json",
                        help="the true model (e.g. from `stillpoint simulate --truth`): reports "
                             "noise_floor_mg, the gap the true model gives")
    parser.add_argument("--folds", type=number(2, 100, integer=True), default=5, help="contiguous time blocks for the "
                                                            "held-out gap (default 5)")
    parser.add_argument("--max-steps", type=number(0, 50, integer=True), default=8, help="most effects to add (default 8)")
    parser.add_argument("--effects", help="comma-separated candidate effects to consider "
                                          "(default: the whole library)")
    parser.add_argument("--sd-threshold-mg", type=MG, default=13.0,
                        help="nonmovement criterion: SD below this on every axis (default 13)")
    parser.add_argument("--rate", type=RATE_HZ, help="sample rate (Hz) for the noise check of a "
                                                   "feature table (recordings know theirs)")
    parser.add_argument("--no-plots", action="store_true", help="skip the PNG figures")


def run(args) -> int:
    from stillpoint.engine.workflows.api import analyse
    from stillpoint.engine.workflows.candidates import LIBRARY
    from stillpoint.engine.workflows.report import text

    effects = None
    if args.effects:
        effects = [e.strip() for e in args.effects.split(",") if e.strip()]
        bad = [e for e in effects if e not in LIBRARY]
        if bad:
            raise StillpointError(f"unknown candidate effect(s) {', '.join(bad)}; the library has "
                                  f"{', '.join(LIBRARY)}")
    if args.folds < 2:
        raise StillpointError("--folds must be at least 2")
    if args.output:
        from stillpoint.engine.workflows.report import prepare_report_dir
        prepare_report_dir(args.output)  # before the work: a missing/read-only folder fails now
    try:
        _, d = analyse(args.input, model=args.model, truth=args.truth, out_dir=args.output,
                       folds=args.folds, max_steps=args.max_steps, effects=effects,
                       sd_threshold=args.sd_threshold_mg / 1000.0, rate_hz=args.rate,
                       plots=not args.no_plots)
    except ValueError as e:  # too few nonmovement windows etc.
        if isinstance(e, StillpointError):
            raise
        raise RecordingError(args.input, str(e)) from None
    if args.json:
        json.dump(d, sys.stdout, indent=1)
        sys.stdout.write("\n")
    else:
        print(text(d))
        if args.output:
            print(f"\nreport written to {args.output}/ (report.json, report.txt, windows.csv, final_model.json"
                  + (", " + ", ".join(d.get("figures", [])) if d.get("figures") else "") + ")")
    return 0
