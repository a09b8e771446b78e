"""`stillpoint process FILE`: calibrate a recording and log everything to MCAP."""

from __future__ import annotations

import json
from pathlib import Path

from stillpoint.engine.core.outputs import check_distinct_outputs, check_output_path
from stillpoint.engine.calibration.estimate import CalibrationEstimate
from stillpoint.engine.calibration.outcome import store_refusal
from stillpoint.engine.run import RunSettings, process_file

from ._numbers import SECONDS_DAY
from ._staticopts import add_static_arguments, resolve_static
from ._outcomeopts import add_outcome_arguments, outcome_settings
from ._tableopts import (add_table_arguments, add_zone_arguments, table_settings, zone_settings,
                         tables_text)
from ._runopts import (OptionError, Progress, add_setting_arguments, human_summary,
                       settings_overrides, write_summary)

NAME = "process"
KEEPS_EXISTING_OUTPUTS = True  # --overwrite replaces an existing output
HELP = "autocalibrate a .cwa/.bin recording; write raw, corrected, metrics and estimates to MCAP"
DESCRIPTION = (HELP + ". Batch mode reads the file twice (features + fit, then corrected "
               "output); online mode refits every 12 h of data in one pass.")


def default_output(path: Path) -> Path:
    name = path.name
    for suffix in (".gz",):
        if name.endswith(suffix):
            name = name[: -len(suffix)]
    stem = name.rsplit(".", 1)[0] if "." in name else name
    if name.endswith(".mcap"):
        stem += ".replay"
    return path.with_name(stem + ".mcap")


def add_arguments(p) -> None:
    p.add_argument("file", type=Path, help="recording (.cwa, .cwa.gz, .bin, .gt3x) or a stillpoint MCAP")
    p.add_argument("-o", "--output", type=Path, help="output MCAP (default: FILE with .mcap)")
    p.add_argument("--summary", type=Path, help="write the run summary as JSON here")
    p.add_argument("--json", action="store_true", help="print the summary JSON instead of text")
    p.add_argument("--prior", type=Path,
                   help="online: JSON estimate in force before the first accepted refit")
    p.add_argument("--store", nargs="?", const="", default=None, metavar="DIR",
                   help="use the calibration store (default location, or DIR): online takes its "
                        "prior from it; the final estimate is added to it")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar and no text summary")
    p.add_argument("--follow", nargs="?", const=5.0, default=None, type=SECONDS_DAY, metavar="IDLE_S",
                   help="read a .cwa/.bin that is still being written until it has not grown for "
                        "IDLE_S seconds (default 5); use with --mode online (one pass)")
    p.add_argument("--report", action="store_true",
                   help="also write a one-page PNG report (+ HTML) beside the MCAP (needs matplotlib)")
    add_zone_arguments(p)
    add_static_arguments(p)
    add_setting_arguments(p)
    add_table_arguments(p)
    add_outcome_arguments(p)
    _add_sleep_arguments(p)


def _add_sleep_arguments(p) -> None:
    """Sleep (engine/sleep): on with the tables; without a zone on the device's clock."""
    g = p.add_argument_group("sleep (GGIR's HDCZA and sustained inactivity bouts; nights in the "
                             "zone's local time, or on the device's clock without --timezone: "
                             "24 h nights, no DST)")
    g.add_argument("--no-sleep", dest="sleep", action="store_false",
                   help="no spt/sib columns and no <stem>.nights.csv")
    g.add_argument("--sleep-log", type=Path, metavar="LOG.csv",
                   help="sleep diary in GGIR's basic or advanced sleep-log format: its nights "
                        "guide the sleep period (HDCZA where a night is missing)")
    g.add_argument("--sleep-log-id", metavar="ID",
                   help="the participant's ID in the sleep log (default: the recording's file "
                        "name without extension)")
    g.add_argument("--hdcza-ignore-invalid", choices=("false", "true", "na"), default="false",
                   help="GGIR's HASPT.ignore.invalid: nonwear judged on its anglez (false, "
                        "default), counted as movement (true) or as no movement (na)")


def _sleep_settings(args, tables, out: Path) -> None:
    if not getattr(args, "sleep", False) or tables is None:
        if getattr(args, "sleep_log", None) is not None:
            raise OptionError("--sleep-log needs the tables and sleep (not with --no-tables or "
                              "--no-sleep)")
        return
    from stillpoint.engine.sleep import HdczaOptions, SleepOptions, nights_path, read_sleep_log
    log = None
    if args.sleep_log is not None:
        name = args.file.name
        pid = args.sleep_log_id or (name.split(".", 1)[0] if "." in name else name)
        log = read_sleep_log(args.sleep_log, pid)
    ign = {"false": False, "true": True, "na": None}[args.hdcza_ignore_invalid]
    tables.sleep = SleepOptions(hdcza=HdczaOptions(ignore_invalid=ign), sleep_log=log)
    tables.nights_path = nights_path(out)


def _store(arg):
    from stillpoint.engine.calibration import CalibrationStore
    return CalibrationStore(arg or None)


def build_settings(args, base: dict | None = None) -> RunSettings:
    over = settings_overrides(args)
    if getattr(args, "prior", None):
        from stillpoint.engine.calibration.validate import validate_estimate
        try:
            d = json.loads(args.prior.read_text())
        except (OSError, ValueError, RecursionError) as e:
            raise OptionError(f"--prior {args.prior}: not a calibration estimate JSON ({e})") from None
        over["prior"] = validate_estimate(d, f"--prior {args.prior}").to_dict()
    over.update(zone_settings(args))
    if (getattr(args, "static", None) or getattr(args, "static_from_store", None) is not None) \
            and over.get("calibrate") is False:
        raise OptionError("--static/--static-from-store apply a calibration: not with --no-calibrate")
    if getattr(args, "static", None):
        from stillpoint.engine.calibration.static import load_static_calibration
        over["static_calibration"] = load_static_calibration(args.static).to_estimate().to_dict()
    return RunSettings.from_dict(base or {}, **over)


def check_log_name(out: Path) -> None:
    """The log is an MCAP file: a name that does not say so (``-o x.csv``) would hold MCAP bytes
    under a table's name and put the tables beside it as ``x.csv.epochs.csv.gz``; refused."""
    if not out.name.lower().endswith(".mcap"):
        raise OptionError(f"-o {out}: the log is an MCAP file, name it NAME.mcap (the tables are "
                          "written beside it as NAME.epochs.csv.gz and NAME.days.csv; "
                          "`stillpoint export` writes CSV from a log)")


def execute(args, settings: RunSettings, out: Path) -> int:
    # every output is checked before the work starts: a long run must not fail at its end (none
    # may be an input: the command line protects those; nor two of them the same file)
    check_log_name(out)
    check_output_path(out, what="MCAP output")
    if getattr(args, "summary", None):
        check_output_path(args.summary, what="summary")
    named = {"MCAP output": out, "summary": getattr(args, "summary", None)}
    if getattr(args, "tables", False):
        from stillpoint.engine.tables import table_paths
        from stillpoint.engine.rhythm.table import rhythm_path
        named["epoch table"], named["day table"] = table_paths(out)
        named["rhythm table"] = rhythm_path(out)
        if getattr(args, "sleep", False):
            from stillpoint.engine.sleep import nights_path
            from stillpoint.engine.timeuse.table import windows_path
            named["nights table"] = nights_path(out)
            named["windows table"] = windows_path(out)
    if getattr(args, "report", False):
        from stillpoint.engine.report import report_paths
        named["report"], named["report page"] = report_paths(out)
    check_distinct_outputs(named)
    if getattr(args, "store", None) is not None:
        _store(args.store).check()
    progress = Progress(enabled=False if args.quiet else None,
                        label=getattr(args, "command", None) or "process")  # or replay
    resolve_static(args, settings)
    if getattr(args, "store", None) is not None and settings.mode == "online" and settings.prior is None:
        from stillpoint.engine.recordings import open_recording
        src = open_recording(args.file)
        key = src.info.device_key
        src.close()
        prior = _store(args.store).prior_for(key)
        if prior is not None:
            settings.prior = prior.to_dict()
    tables = table_settings(args, out) if getattr(args, "tables", False) else None
    _sleep_settings(args, tables, out)
    if tables is not None and hasattr(args, "cutpoints"):
        tables.outcomes = outcome_settings(args)
        if tables.outcomes.cutpoints and not settings.counts:
            from stillpoint.engine.outcomes.cutpoints import lookup
            if lookup(tables.outcomes.cutpoints).counts:
                raise OptionError(f"--cutpoints {tables.outcomes.cutpoints} is on ActiLife counts: "
                                  "add --counts normal (or lfe)")
    if getattr(args, "report", False):
        if settings.log == "lean":
            raise OptionError("--report reads the raw samples, which a lean log (--log lean) does "
                              "not keep: use --log full")
        from stillpoint.engine.report import require_matplotlib
        require_matplotlib()
    try:
        opts = None
        if getattr(args, "follow", None) is not None:
            if settings.mode != "online":
                raise OptionError("--follow reads the file once as it grows: use it with --mode online")
            opts = {"follow": True, "follow_idle_s": args.follow}
        summary = process_file(args.file, out, settings, progress=progress, tables=tables,
                               source_options=opts)
        if getattr(args, "report", False):  # part of the run: "done" only once it is written
            from stillpoint.engine.report import write_report
            summary["outputs"].update(write_report(out, summary=summary))
    except BaseException:
        progress.done(completed=False)
        raise
    progress.done()
    if getattr(args, "store", None) is not None:
        est = CalibrationEstimate.from_dict(dict(summary["calibration"]))
        if store_refusal(est) is None and summary.get("device"):
            d = summary["device"]
            store = _store(args.store)
            store.add(est, device_key=f"{d['type']}-{d['id']}", source=str(args.file))
            summary["outputs"]["store"] = str(store.dir)
    if args.summary:
        write_summary(summary, args.summary)
        summary["outputs"]["summary"] = str(args.summary)
    if args.json:
        from stillpoint.engine.core.jsonsafe import dumps
        print(json.dumps(json.loads(dumps(summary)), indent=2, sort_keys=True))
    elif not args.quiet:
        print(human_summary(summary))
        print(tables_text(summary))
    return 0


def run(args) -> int:
    from stillpoint.drivers.byteio import check_recording_path
    from stillpoint.engine.core.errors import RecordingError
    try:
        check_recording_path(args.file)
    except RecordingError as e:
        if args.file.is_dir():  # `process .`: a folder of recordings is a cohort
            raise RecordingError(args.file, "is a directory, not a recording: name one recording, "
                                            f"or run every recording in it with `stillpoint cohort "
                                            f"run {args.file} -o OUT_DIR`") from None
        raise e from None
    out = args.output or default_output(args.file)
    return execute(args, build_settings(args), out)
