"""`stillpoint replay IN.mcap`: re-run the engine on the raw stream a run logged."""

from __future__ import annotations

import json
from pathlib import Path

from stillpoint.drivers.mcap_replay import McapRawSource

from ._runopts import add_setting_arguments
from ._staticopts import add_static_arguments
from .process import build_settings, default_output, execute

NAME = "replay"
KEEPS_EXISTING_OUTPUTS = True  # --overwrite replaces an existing output
HELP = "re-process the raw stream logged in a stillpoint MCAP (same settings -> identical output)"
DESCRIPTION = (HELP + ". Settings default to those logged in IN.mcap; any option given overrides "
               "them. --check compares the corrected stream, metrics and estimates with IN.")


def add_arguments(p) -> None:
    p.add_argument("file", type=Path, help="a stillpoint MCAP (from process, or recovered)")
    p.add_argument("-o", "--output", type=Path, help="output MCAP (default: IN.replay.mcap)")
    p.add_argument("--summary", type=Path, help="write the run summary as JSON here")
    p.add_argument("--json", action="store_true", help="print the summary JSON instead of text")
    p.add_argument("--prior", type=Path, help="online: JSON estimate in force at the start")
    p.add_argument("--check", action="store_true",
                   help="compare the output with IN topic by topic; exit 1 if they differ")
    p.add_argument("-q", "--quiet", action="store_true")
    add_static_arguments(p)
    add_setting_arguments(p, defaults_from_input=True)
    p.set_defaults(store=None)


def run(args) -> int:
    src = McapRawSource(args.file)  # validates: a finished stillpoint MCAP
    logged = dict(src.settings or {})
    src.close()
    logged.setdefault("view_hz", 0.0)  # a log from before the view topic had none
    out = args.output or default_output(args.file)
    settings = build_settings(args, logged)
    rc = execute(args, settings, out)
    if args.check:
        from stillpoint.engine.mcap.compare import compare
        res = compare(args.file, out)
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
