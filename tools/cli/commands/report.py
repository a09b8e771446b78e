"""`stillpoint report FILE.mcap`: a one-page PNG (and an HTML page embedding it) per recording."""

from __future__ import annotations

from pathlib import Path

NAME = "report"
KEEPS_EXISTING_OUTPUTS = True  # --overwrite replaces an existing output
HELP = "one-page visual report (PNG + HTML) of a processed recording: activity per day, temperature, calibration, QC"


def add_arguments(p) -> None:
    p.add_argument("file", type=Path, nargs="+", help="stillpoint MCAP(s) written by process")
    p.add_argument("-o", "--output", type=Path, default=None,
                   help="PNG path (one input only; default: <stem>.report.png beside the MCAP)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress on stderr")


def run(args) -> int:
    from stillpoint.engine.core.outputs import check_output_path
    from stillpoint.engine.report import report_paths, require_matplotlib, write_report
    from ._runopts import OptionError
    require_matplotlib()  # before any work
    if args.output and len(args.file) > 1:
        raise OptionError("-o takes one input; without it each report goes beside its MCAP")
    for f in args.file:
        png = args.output or report_paths(f)[0]
        check_output_path(png, what="report")
    from stillpoint.engine.progress import Progress
    for f in args.file:
        png = args.output
        page = png.with_suffix(".html") if png else None
        with Progress(f"report {Path(f).name}", quiet=args.quiet) as bar:
            out = write_report(f, out_png=png, out_html=page, progress=bar)
        print(f"wrote {out['report']} and {out['report_html']}")
    return 0
