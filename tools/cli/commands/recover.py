"""`stillpoint recover BROKEN.mcap -o FIXED.mcap`: salvage an interrupted run's log."""

from __future__ import annotations

import json
import re
from pathlib import Path

from stillpoint.engine.recover import recover

NAME = "recover"
KEEPS_EXISTING_OUTPUTS = True  # --overwrite replaces an existing output
HELP = "salvage every complete chunk of an unfinished MCAP into a valid, indexed file"


def add_arguments(p) -> None:
    p.add_argument("file", type=Path, help="an MCAP whose writer was killed (e.g. the "
                                           "OUT.mcap.part an interrupted run left)")
    p.add_argument("-o", "--output", type=Path, help="output (default: FILE with .recovered.mcap)")
    p.add_argument("--json", action="store_true", help="print the report as JSON")


def default_output(path: Path) -> Path:
    """``run.mcap`` / ``run.mcap.part`` / ``run.mcap.part.<time>`` -> ``run.recovered.mcap``."""
    name = re.sub(r"\.part(\.[0-9TZ-]+)?$", "", path.name)
    if name.endswith(".mcap"):
        name = name[:-len(".mcap")]
    return path.with_name(name + ".recovered.mcap")


def run(args) -> int:
    out = args.output or default_output(args.file)
    from stillpoint.engine.core.outputs import check_output_path
    check_output_path(out, what="recovered MCAP")  # never the input (protected by the CLI)
    rep = recover(args.file, out)
    if args.json:
        print(json.dumps(rep.as_dict(), indent=2, sort_keys=True))
        return 0
    state = "was finished (copied)" if rep.finished else "was not finished"
    print(f"{args.file} {state}: recovered {rep.messages:,} messages on {rep.channels} channels, "
          f"{rep.metadata} metadata records -> {out}")
    if rep.last_log_time_ns:
        import datetime as dt
        t = dt.datetime.fromtimestamp(rep.last_log_time_ns / 1e9, dt.timezone.utc)
        print(f"data up to {t.isoformat(timespec='seconds')}; per topic: "
              + ", ".join(f"{k} {v:,}" for k, v in sorted(rep.per_topic.items())))
    for bad in rep.bad_records:
        print(f"skipped an unreadable record, its messages are lost: {bad}")
    if rep.stopped_at:
        print(f"reading stopped at the torn tail: {rep.stopped_at}")
    return 0
