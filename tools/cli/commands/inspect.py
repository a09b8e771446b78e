"""``stillpoint inspect FILE``: what is in a recording (``stillpoint.engine.inspection``, whose
``inspect_recording`` dict this command prints: laid out for people, or one JSON object with
``--json``). ``--header-only`` reads the header alone (fast). Several files: one summary each
(``--json``: one JSON object per line); a bad file is reported on stderr and the others are
still inspected (exit code 2 if any failed).
"""

from __future__ import annotations

import json
import sys

from stillpoint.engine.core.errors import StillpointError
from stillpoint.engine.core.jsonsafe import jsonable
from stillpoint.engine.core.times import offset_text
from stillpoint.engine.inspection import inspect_recording

from ._numbers import SECONDS_DAY
from ._tableopts import add_zone_arguments

NAME = "inspect"
HELP = "summarise a recording (device, samples, rate, times, QC); --json for machine-readable output"


def add_arguments(parser) -> None:
    parser.add_argument("file", nargs="+",
                        help="recording(s): .cwa, .bin (GENEActiv), optionally .gz; .gt3x (ActiGraph). With several files "
                             "--json prints one JSON object per line; a bad file is reported on "
                             "stderr and the others are still inspected (exit code 2 if any failed)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--header-only", action="store_true",
                        help="read the header only (fast; no sample counts or QC)")
    parser.add_argument("--follow", nargs="?", const=5.0, default=None, type=SECONDS_DAY,
                        metavar="IDLE_S", help="read a file that is still being written (a download "
                        "in progress) until it has not grown for IDLE_S seconds (default 5)")
    add_zone_arguments(parser)


def format_text(d: dict) -> str:
    """A readable summary (the --json dict, laid out for people)."""
    lines = []
    add = lines.append
    add(f"{d.get('path')}")
    add(f"  device      {d['device_type']} {d['device_id']}"
        + (f"  session {d['session_id']}" if d.get("session_id") is not None else "")
        + (f"  firmware {d['firmware']}" if d.get("firmware") else ""))
    rng = f"+-{d['accel_range_g']:g} g" if d.get("accel_range_g") else ""
    if d.get("gyro_range_dps"):
        rng += f", gyro +-{d['gyro_range_dps']:g} dps"
    add(f"  rate        {d['sample_rate_nominal']:.6g} Hz nominal"
        + (f", {d['sample_rate_measured']:.6f} Hz measured" if d.get("sample_rate_measured") else "")
        + (f"   range {rng}" if rng else ""))
    tz = d.get("timezone_offset_s") or 0
    clock = f"UTC{offset_text(tz)}"
    unknown = bool(d.get("timezone")) and "unknown" in d["timezone"]
    if unknown:
        clock = d["timezone"] + " (start/end below are the device clock, not UTC)"
    elif d.get("timezone"):
        clock += f" (zone {d['timezone']})"
    add(f"  clock       {clock}")
    ag = d.get("actigraph")
    if ag:
        add(f"  actigraph   {ag['model'] or '?'}, {ag['layout']} layout, scale {ag['scale_lsb_per_g']:g} "
            f"LSB/g ({ag['scale_source']}), stored zone {ag['timezone_stored'] or 'none'}")
        idle = ag.get("idle_sleep_enabled")
        line = ("idle sleep " + ("on" if idle else "off" if idle is not None else "not stated"))
        if "idle_sleep_s" in ag:
            line += (f"; {ag['idle_sleep_s']} s in idle sleep ({ag['idle_sleep_periods']} period(s), "
                     "last sample repeated)")
        if ag.get("usb_connections"):
            line += f"; {ag['usb_connections']} USB connection record(s)"
        add(f"              {line}")
    if "samples" in d:
        add(f"  samples     {d['samples']}  ({', '.join(d['channels'])})")
        if unknown:
            add(f"  start       {d.get('start_local') or '-'}  (device clock)")
            add(f"  end         {d.get('end_local') or '-'}  (device clock)")
        else:
            add(f"  start       {d['start'] or '-'}" + (f"  (local {d['start_local']})"
                                                       if d.get("start_local") else ""))
            add(f"  end         {d['end'] or '-'}" + (f"  (local {d['end_local']})"
                                                     if d.get("end_local") else ""))
        dur = d["duration_s"]
        add(f"  duration    {dur:.3f} s ({dur / 3600:.3f} h, {dur / 86400:.4f} days)")
        for unit, u in d.items():
            if isinstance(u, dict) and set(u) == {"total", "valid", "skipped"}:
                add(f"  {unit:<11} {u['total']} total, {u['valid']} valid, {u['skipped']} skipped; "
                    f"{d['segments']} segment(s)")
        if d.get("temperature_range_c"):
            lo, hi = d["temperature_range_c"]
            add(f"  temperature {lo:.2f} .. {hi:.2f} degC")
        if d.get("battery_range_v"):
            lo, hi = d["battery_range_v"]
            add(f"  battery     {lo:.3f} .. {hi:.3f} V")
        for w in d.get("header_warnings", []):
            add(f"  warning     {w}")
        qc = d.get("qc", [])
        add(f"  qc          {len(qc)} event(s)")
        for e in qc[:50]:
            add(f"    {e['index']:>8}  {e['reason']:<20} {e.get('detail', '')}")
        if len(qc) > 50:
            add(f"    ... {len(qc) - 50} more (see --json)")
    else:
        for k, v in d.get("metadata", {}).items():
            add(f"  {k:<28}{v}")
        hdr = d.get("header", {})
        for k, v in hdr.items():
            if isinstance(v, (str, int, float)) and k not in d.get("metadata", {}):
                add(f"  {k:<28}{v}")
    return "\n".join(lines)


def _print(d: dict, as_json: bool) -> None:
    if as_json:
        json.dump(jsonable(d), sys.stdout, default=str)
        sys.stdout.write("\n")
    else:
        print(format_text(d))
    sys.stdout.flush()


def run(args) -> int:
    files = args.file
    if len(files) == 1:  # one file: a bad one is the CLI's one-line error (exit 2)
        _print(inspect_recording(files[0], header_only=args.header_only, timezone=args.timezone,
                                 follow_idle_s=args.follow,
                                 timezone_override=args.timezone_override),
               args.json)
        return 0
    failed = 0
    for i, f in enumerate(files):
        try:
            d = inspect_recording(f, header_only=args.header_only, timezone=args.timezone,
                                  follow_idle_s=args.follow,
                                  timezone_override=args.timezone_override)
        except StillpointError as e:
            failed += 1
            print(f"stillpoint inspect: error: {e}", file=sys.stderr)
            continue
        except Exception as e:  # one file's failure never stops the others
            failed += 1
            print(f"stillpoint inspect: error: {f}: unexpected {type(e).__name__}: {e}", file=sys.stderr)
            continue
        if i and not args.json:
            print()
        _print(d, args.json)
    return 2 if failed else 0
