"""``stillpoint calibrate-features FEATURES.csv``: the autocalibration fit on a table of window
features (columns meanx, meany, meanz, sdx, sdy, sdz, temperature; extra columns ignored), e.g.
GGIR's ``spheredata``. ``--ggir-compatible`` reproduces GGIR's g.calibrate numbers.

By default the table is taken as given (GGIR's spheredata is already its nonmovement selection);
``--select`` applies the nonmovement rule (SD < 13 mg, |mean| < 2 g, repeats collapsed) first.
"""

from __future__ import annotations

from .calibrate import add_fit_arguments, finish_output

NAME = "calibrate-features"
HELP = "fit the autocalibration on a CSV of window features (e.g. GGIR spheredata); --json"


def add_arguments(parser) -> None:
    parser.add_argument("file", help="CSV with meanx,meany,meanz,sdx,sdy,sdz[,temperature]")
    add_fit_arguments(parser)
    parser.add_argument("--select", action="store_true",
                        help="apply the nonmovement selection to the rows first")


def run(args) -> int:
    from stillpoint.engine.calibration import fit_calibration, select_calibration_windows
    from stillpoint.engine.calibration.table import read_features_csv

    feats = read_features_csv(args.file)
    est = fit_calibration(feats, temperature=not args.no_temperature,
                          ggir_compatible=args.ggir_compatible, variant=args.variant,
                          select=args.select)
    shown = select_calibration_windows(feats).features if args.select else feats
    return finish_output(args, est, shown, title=args.file)
