"""``stillpoint export FILE -o OUT.csv|OUT.csv.gz|OUT.npz``: per-sample values of a recording
(time, accel in g, gyro in dps, temperature, light, battery, ...), ActiLife's raw CSV of a .gt3x
(``--actilife``), or a topic (``--topic``) or table (``--table``) of a stillpoint log.

The columns, units and streaming are described in ``stillpoint.engine.export``, whose
``export_recording`` and ``export_actilife`` this command calls.
"""

from __future__ import annotations

from pathlib import Path

from stillpoint.engine.export import TABLES, TIME_FORMATS, export_actilife, export_recording

from ._tableopts import add_zone_arguments

NAME = "export"
KEEPS_EXISTING_OUTPUTS = True  # --overwrite replaces an existing output
HELP = "write per-sample time, accel (g), gyro (dps), temperature, light, battery to CSV or NPZ"


def add_arguments(parser) -> None:
    parser.add_argument("file", help="recording (.cwa, .bin, optionally .gz; .gt3x) or a run's .mcap")
    parser.add_argument("-o", "--output", required=True, help="OUT.csv, OUT.csv.gz or OUT.npz")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress on stderr")
    parser.add_argument("--time", choices=TIME_FORMATS, default="iso",
                        help="CSV time column: iso (microseconds; default), epoch (seconds, 9 "
                             "decimals) or ns (integer nanoseconds); UTC in a `time` column when the "
                             "zone is known, else the device clock in a `time_local` column")
    add_zone_arguments(parser)
    parser.add_argument("--compress", action="store_true", help="NPZ: deflate the columns")
    parser.add_argument("--actilife", action="store_true",
                        help="ActiGraph .gt3x: write ActiLife's raw CSV layout (header lines, "
                             "Accelerometer X/Y/Z rows in g to 3 decimals, idle sleep repeated, "
                             "other missing seconds as zeros)")
    parser.add_argument("--topic", action="append", default=None,
                        help="MCAP input: topic(s) to export (repeatable); an MCAP export needs "
                             "--topic or --table")
    parser.add_argument("--table", choices=TABLES, default=None,
                        help="MCAP input: write the epoch table (OUT.csv.gz), the day table "
                             "(OUT.csv) or the nights table (OUT.csv) made from the log, with the "
                             "run's final calibration from the first sample")
    from ._tableopts import add_table_arguments
    add_table_arguments(parser, with_switch=False)
    from ._outcomeopts import add_outcome_arguments
    add_outcome_arguments(parser)


def run(args) -> int:
    from ._tableopts import table_settings
    ts = table_settings(args, Path(args.output))
    opts = {"nonwear_version": ts.nonwear_version, "valid_day_hours": ts.valid_day_hours,
            "enmo_bands_mg": ts.enmo_bands_mg, "mvpa_bout_s": ts.mvpa_bout_s}
    from ._outcomeopts import outcome_settings
    outcomes = outcome_settings(args)
    if outcomes.active:
        opts["outcomes"] = outcomes
    from stillpoint.engine.progress import Progress
    if args.actilife:
        rep = export_actilife(args.file, args.output)
        r = rep["actilife"]
        print(f"wrote {r['rows']} rows in ActiLife's raw CSV layout to {rep['output']} "
              f"({r['samples']} samples, {r['idle_rows']} of them idle sleep; {r['zero_rows']} zero "
              "rows for missing seconds)")
        if r.get("zero_seconds_cut"):
            print(f"note: {r['zero_seconds_cut']} s of zero rows were not written (a run of zeros "
                  "longer than 31 days: a damaged clock or download time)")
        return 0
    with Progress("export", quiet=args.quiet) as bar:
        rep = export_recording(args.file, args.output, time_format=args.time,
                               timezone=args.timezone, compress=args.compress, topics=args.topic,
                               table=args.table, table_options=opts,
                               timezone_override=args.timezone_override, progress=bar.update)
    if rep.get("tables"):
        t = rep["tables"]
        what = (f"{t['epoch_rows']:,} epochs" if rep["table"] == "epochs"
                else f"{t['sleep']['night_rows']} night(s)" if rep["table"] == "nights"
                else f"{t['day_rows']} day(s) and the file summary row")
        print(f"wrote {rep['output']} ({what}); times: {t['timezone']}")
    elif rep.get("format") == "mcap":
        from stillpoint.engine.timezones import log_zone
        zone = log_zone(args.file)  # the log's clock record
        print(f"wrote {rep['output']} (from the MCAP log)" + (
            "" if zone is None else f"; times: {zone.label}" +
            ("" if zone.known else " (time_local: the device clock, not UTC)")))
    else:
        q = rep["qc"]
        print(f"wrote {rep['samples']} samples to {rep['output']} "
              f"({q['valid']} of {q['total']} {q['unit']}s valid, {len(q['events'])} QC event(s))")
        tz = rep.get("timezone", "")
        print(f"times: {tz}" + (" (the time_local column holds the device clock, not UTC)"
                                if "unknown" in tz else " (the time column is UTC)"))
    return 0
