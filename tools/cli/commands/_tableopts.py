"""Options shared by `process`, `export` and `report` for the epoch/day tables and time zones."""

from __future__ import annotations

from pathlib import Path

from ._numbers import SECONDS_DAY, number, number_list

ENMO_BANDS = number_list(number(0, 10_000, lo_open=True, unit="mg"), increasing=True,
                         what="increasing mg values")


def add_zone_arguments(p) -> None:
    """``--timezone ZONE`` and ``--timezone-override``: every command that reads a recording's
    times takes them with this one help text (engine/timezones.py applies them)."""
    p.add_argument("--timezone", default=None, metavar="ZONE",
                   help="the participant's time zone: an IANA name (Europe/London) or an offset "
                        "(+01:00). .cwa: the device clock is that zone's wall-clock time (DST-aware); "
                        "without it times are 'device local time, zone unknown'. GENEActiv: must "
                        "agree with the header's zone unless --timezone-override")
    p.add_argument("--timezone-override", action="store_true",
                   help="GENEActiv: let --timezone replace a header zone it contradicts (the "
                        "run's settings record that it did)")


def add_table_arguments(p, *, with_switch: bool = True) -> None:
    g = p.add_argument_group("epoch and day tables")
    if with_switch:
        g.add_argument("--no-tables", dest="tables", action="store_false",
                       help="do not write <stem>.epochs.csv.gz and <stem>.days.csv beside the MCAP")
    g.add_argument("--nonwear", choices=("2013", "2023"), default="2023",
                   help="GGIR nonwear rule: 2023 (default; flags the whole 60-min window) or 2013 "
                        "(centred window, flags the 15-min window)")
    g.add_argument("--valid-day-hours", type=number(0, 25, lo_open=True, unit="h"), default=16.0,
                   help="a valid day has at least this many hours of clean wear (default 16)")
    g.add_argument("--enmo-bands", type=ENMO_BANDS, default="40,100,400", metavar="MG,MG,...",
                   help="ENMO band edges in mg for minutes per band (default 40,100,400; the second "
                        "edge is the MVPA threshold)")
    g.add_argument("--mvpa-bout-s", type=SECONDS_DAY, default=60.0,
                   help="MVPA counts runs of at least this many seconds (default 60)")


def table_settings(args, mcap_out: Path):
    from stillpoint.engine.tables import TablesSettings, table_paths
    bands = tuple(args.enmo_bands)  # the three options are checked when parsed (_numbers)
    from stillpoint.engine.rhythm.table import rhythm_path
    from stillpoint.engine.timeuse.table import windows_path
    ep, dp = table_paths(mcap_out)
    return TablesSettings(ep, dp, nonwear_version=args.nonwear, valid_day_hours=args.valid_day_hours,
                          enmo_bands_mg=bands, mvpa_bout_s=args.mvpa_bout_s,
                          rhythm_path=rhythm_path(mcap_out), windows_path=windows_path(mcap_out))


def check_zone(spec):
    """Validate a --timezone value before any work (one line, exit 2 on a bad one)."""
    from stillpoint.engine.timezones import parse_zone
    return parse_zone(spec)


def zone_settings(args) -> dict:
    """The run settings of ``--timezone`` and ``--timezone-override``, checked before any work."""
    from ._runopts import OptionError
    over = {}
    if getattr(args, "timezone", None) is not None:
        check_zone(args.timezone)
        over["timezone"] = args.timezone
    if getattr(args, "timezone_override", False):
        if getattr(args, "timezone", None) is None:
            raise OptionError("--timezone-override replaces a GENEActiv header's zone with "
                              "--timezone: give --timezone too")
        over["timezone_override"] = True
    return over


def tables_text(summary: dict) -> str:
    """Lines for the text summary: the zone and what the tables hold."""
    lines = [f"times: {summary.get('timezone', 'UTC')}"]
    if summary.get("timezone_override"):
        lines[0] += " (replaces the GENEActiv header's zone: --timezone-override)"
    t = summary.get("tables")
    if t:
        f = t["file"]
        fl = t["flags"]
        enmo = f.get("enmo_mean_mg")
        lines.append(
            f"tables: {t['epoch_rows']:,} epochs ({t['clean_epochs']:,} clean; nonwear "
            f"{fl['nonwear']:,}, clipping {fl['clipping']:,}, gap {fl['gap']:,}, qc {fl['qc']:,}, "
            f"filter warm-up {fl['filter_warmup']:,}), {t['day_rows']} day(s), "
            f"{f['valid_day']} valid; mean ENMO over clean epochs "
            f"{'n/a' if enmo is None else f'{enmo:.2f} mg'} (nonwear rule {t['nonwear_version']})")
        sl = t.get("sleep")
        if sl:
            g = ", ".join(f"{k} {v}" for k, v in sl["guiders"].items()) or "none"
            from stillpoint.engine.timezones import UNKNOWN_LABEL
            clock = (" on the device's clock (zone unknown: nights of 24 h, DST not applied; "
                     "--timezone gives local nights)"
                     if summary.get("timezone") == UNKNOWN_LABEL else "")
            lines.append(f"sleep: {sl['night_rows']} night(s){clock} (guider: {g}), "
                         f"{sl['sib_bouts']:,} inactivity bouts; nights table {sl['nights']}")
        if t.get("epochs_not_in_table"):
            lines.append(f"warning: {t['epochs_not_in_table']:,} epochs are in the MCAP log but not "
                         "in the tables: the clock went back at a restart, to before rows already "
                         "written")
    return "\n".join(lines)
