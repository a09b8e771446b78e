"""`stillpoint devices`: one row per attached AX3/AX6 (real or emulated)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

NAME = "devices"
HELP = "list attached AX3/AX6 devices: id, type, firmware, session, battery, clock, data, state, slot"


def add_arguments(p) -> None:
    p.add_argument("--json", action="store_true", help="print JSON")
    p.add_argument("--ledger", type=Path, default=None,
                   help="a station output folder: show 'verified' for sessions its ledger holds")
    p.add_argument("--port", default=None, help="use this serial port (manual override)")
    p.add_argument("--volume", default=None, help="the device's drive is mounted here (manual override)")


def _fmt(r: dict) -> str:
    size = r.get("data_bytes")
    off = r.get("clock_offset_s")
    return (f"{r.get('slot', '-'):<10} {r['id']:>8} {r.get('type', '?'):<4} fw {str(r.get('firmware', '-')):>3} "
            f"session {str(r.get('session', '-')):>6} battery {str(r.get('battery_pct', '-')):>3} % "
            f"clock {('%+.1f s' % off) if off is not None else '-':>8} "
            f"window {r.get('start', '-')}..{r.get('stop', '-')} "
            f"data {('%.1f MB' % (size / 1e6)) if size is not None else '-':>9}  {r.get('state', '-')}"
            + (f" ({r['problem']})" if r.get("problem") else ""))


def run(args) -> int:
    from stillpoint.engine.station.ledger import Ledger
    from stillpoint.engine.station.status import list_devices
    ledger = Ledger(args.ledger) if args.ledger else None
    rows = list_devices(ledger=ledger, port=args.port, volume=args.volume)
    if args.json:
        json.dump(rows, sys.stdout, indent=1)
        print()
    elif not rows:
        print("no AX3/AX6 device attached (Linux: is the user in the 'dialout' group? is the drive "
              "mounted? `stillpoint device emulate` runs emulated devices)")
    else:
        for r in rows:
            print(_fmt(r))
    return 2 if any(r.get("state") == "error" for r in rows) else 0
