"""`stillpoint dashboard OUTDIR`: the station's web dashboard read from the ledger alone, while no
station runs (read-only; see docs/dashboard.md)."""

from __future__ import annotations

import signal
import sys
import threading
from pathlib import Path

NAME = "dashboard"
HELP = "serve the station's web dashboard of an output folder from its ledger (read-only)"


def add_arguments(p) -> None:
    from .station import add_web_arguments
    p.add_argument("outdir", type=Path, help="the station's output folder (with its ledger)")
    add_web_arguments(p, station=False)


def run(args) -> int:
    from stillpoint.engine.core.outputs import OutputError
    from stillpoint.engine.station.ledger import LEDGER_NAME

    from .station import start_dashboard
    if not args.outdir.is_dir():
        raise OutputError(args.outdir, "output folder does not exist")
    if not (args.outdir / LEDGER_NAME).is_file():
        raise OutputError(args.outdir, f"holds no station ledger ({LEDGER_NAME}): run "
                                       "`stillpoint station` on it first")
    stop = threading.Event()

    def on_signal(signum, frame):
        stop.set()
    old = signal.signal(signal.SIGINT, on_signal)
    old_term = signal.signal(signal.SIGTERM, on_signal)
    try:
        dash = start_dashboard(args, args.outdir)
        try:
            stop.wait()
        finally:
            dash.close()
    finally:
        signal.signal(signal.SIGINT, old)
        signal.signal(signal.SIGTERM, old_term)
    print("dashboard stopped", file=sys.stderr)
    return 0
