"""`stillpoint devices`: one row per attached AX3/AX6 (real or emulated)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

NAME = "devices"
HELP = ("list attached AX3/AX6 devices: slot, id, type, firmware, session, battery, clock offset, "
        "recording window (always, never, from/until a time), data, state")


def add_arguments(p) -> None:
    p.add_argument("--json", action="store_true", help="print JSON")
    p.add_argument("--ledger", type=Path, default=None,
                   help="a station output folder: show 'verified' for sessions its ledger holds")
    p.add_argument("--port", default=None, help="use this serial port (manual override)")
    p.add_argument("--volume", default=None, help="the device's drive is mounted here (manual override)")


COLUMNS = ("slot", "id", "type", "fw", "session", "battery", "clock", "window", "data", "state")
_RIGHT = {"id", "fw", "session", "battery", "clock", "data"}  # numbers: aligned right


def _cells(r: dict) -> dict:
    size = r.get("data_bytes")
    off = r.get("clock_offset_s")
    bat = r.get("battery_pct")
    window = r.get("window") or ("-" if r.get("start") is None else f"{r['start']}..{r.get('stop')}")
    return {"slot": str(r.get("slot", "-")), "id": str(r["id"]), "type": str(r.get("type", "?")),
            "fw": str(r.get("firmware", "-")), "session": str(r.get("session", "-")),
            "battery": f"{bat} %" if bat is not None else "-",
            "clock": f"{off:+.1f} s" if off is not None else "-", "window": window,
            "data": f"{size / 1e6:.1f} MB" if size is not None else "-",
            "state": str(r.get("state", "-")) + (f" ({r['problem']})" if r.get("problem") else "")}


def table(rows: list[dict]) -> list[str]:
    """A header row, then one row per device, each column as wide as its widest value."""
    cells = [_cells(r) for r in rows]
    width = {c: max([len(c)] + [len(x[c]) for x in cells]) for c in COLUMNS}

    def line(values: dict) -> str:
        return "  ".join(values[c].rjust(width[c]) if c in _RIGHT else
                         (values[c] if c == COLUMNS[-1] else values[c].ljust(width[c]))
                         for c in COLUMNS).rstrip()
    return [line({c: c for c in COLUMNS})] + [line(x) for x in cells]


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
        for line in table(rows):
            print(line)
    return 2 if any(r.get("state") == "error" for r in rows) else 0
