"""`stillpoint replay IN.mcap`: re-run the engine on the raw stream a run logged."""

from __future__ import annotations

import json
from pathlib import Path

from stillpoint.engine.mcap.replay import McapRawSource

from ._runopts import add_setting_arguments
from ._staticopts import add_static_arguments
from .process import build_settings, default_output, execute

NAME = "replay"
KEEPS_EXISTING_OUTPUTS = True  # --overwrite replaces an existing output
HELP = "re-process the raw stream logged in a stillpoint MCAP (same settings -> identical output)"
DESCRIPTION = (HELP + ". Settings default to those logged in IN.mcap; any option given overrides "
               "them. A run that computed sleep (a time zone and the tables) is replayed with "
               "its tables and sleep, with the settings it logged, so the log's /sleep topics "
               "come out again. --check compares every topic with IN. A lean log (--log lean) holds no "
               "raw stream: give the recording it was made from with --raw (with --log full the "
               "replay is the full log the recording gives, bit for bit).")


def add_arguments(p) -> None:
    p.add_argument("file", type=Path, help="a stillpoint MCAP (from process, or recovered)")
    p.add_argument("-o", "--output", type=Path, help="output MCAP (default: IN.replay.mcap)")
    p.add_argument("--summary", type=Path, help="write the run summary as JSON here")
    p.add_argument("--json", action="store_true", help="print the summary JSON instead of text")
    p.add_argument("--prior", type=Path, help="online: JSON estimate in force at the start")
    p.add_argument("--raw", type=Path, metavar="RECORDING",
                   help="read the samples from the recording IN was made from (.cwa, .bin, .gt3x) "
                        "instead of IN's raw stream (needed for a lean log)")
    p.add_argument("--check", action="store_true",
                   help="compare the output with IN topic by topic; exit 1 if they differ")
    p.add_argument("-q", "--quiet", action="store_true")
    add_static_arguments(p)
    add_setting_arguments(p, defaults_from_input=True)
    p.set_defaults(store=None)


def run(args) -> int:
    src = McapRawSource(args.file)  # validates: a finished stillpoint MCAP
    logged = dict(src.settings or {})
    meta = dict(src.metadata)
    src.close()
    logged.setdefault("view_hz", 0.0)  # a log from before the view topic had none
    out = args.output or default_output(args.file)
    settings = build_settings(args, logged)
    _logged_sleep(args, meta)
    log = args.file
    if getattr(args, "raw", None) is not None:
        _check_raw(args.raw, meta, log)
        args.file = args.raw  # the run reads the recording (its name, as process had it)
    rc = execute(args, settings, out)
    args.file = log
    if args.check:
        from stillpoint.engine.mcap.compare import compare
        res = compare(log, out)
        same = all(r["identical"] for r in res.values())
        for t, r in res.items():
            print(f"{t}: {'identical' if r['identical'] else 'DIFFERENT'} "
                  f"({r['messages'][0]} vs {r['messages'][1]} messages)")
        if not same:
            changed = {k: v for k, v in settings.to_dict().items() if logged.get(k) != v
                       and k in logged}
            if changed:
                print("settings differ from the logged run: " + json.dumps(changed, default=str))
            return 1
    return rc


def _logged_sleep(args, meta: dict) -> None:
    """When the logged run computed sleep (its summary's ``tables.sleep``), the replay does too,
    with the run's nonwear rule and sleep settings (``engine.sleep.tap.logged_settings``; a log
    from before those were logged: the defaults). Sleep is computed by the table writer, so the
    replay writes the tables beside its output (``<out>.epochs.csv.gz``, ``.days.csv``,
    ``.nights.csv``)."""
    try:
        tables = json.loads((meta.get("summary") or {}).get("tables") or "null")
    except (TypeError, ValueError, RecursionError):
        return
    if not isinstance(tables, dict) or not isinstance(tables.get("sleep"), dict):
        return
    sl = tables["sleep"].get("settings") or {}
    args.tables, args.sleep = True, True
    args.nonwear = str(tables.get("nonwear_version") or "2023")
    args.valid_day_hours, args.enmo_bands, args.mvpa_bout_s = 16.0, (40.0, 100.0, 400.0), 60.0
    ign = sl.get("HASPT_ignore_invalid", False)
    args.hdcza_ignore_invalid = {False: "false", True: "true", None: "na"}.get(ign, "false")
    args.sleep_log = Path(sl["sleep_log"]) if sl.get("sleep_log") else None
    args.sleep_log_id = sl.get("sleep_log_participant")


def _check_raw(raw: Path, meta: dict, log: Path) -> None:
    """The recording given with ``--raw`` must be the one the log was made from: the same
    device type, id and session as the log's ``device`` record (one line, exit 2, otherwise)."""
    from stillpoint.engine.recordings import open_recording
    from stillpoint.drivers.byteio import check_recording_path
    from stillpoint.engine.core.errors import RecordingError
    check_recording_path(raw)
    src = open_recording(raw)
    try:
        info = src.info
    finally:
        src.close()
    from dataclasses import asdict
    from stillpoint.engine.core.jsonsafe import jsonable
    keys = ("device_type", "device_id", "session_id")
    try:
        logged = json.loads((meta.get("device") or {}).get("json") or "{}")
    except (TypeError, ValueError, RecursionError):
        logged = {}
    ours = jsonable(asdict(info))
    have = tuple(str(ours.get(k)) for k in keys)
    want = tuple(str(logged.get(k) if isinstance(logged, dict) else None) for k in keys)
    if have != want:
        raise RecordingError(raw, f"is not the recording {log} was made from (device "
                                  f"{'/'.join(have)}, the log's {'/'.join(want)})")
