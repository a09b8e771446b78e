"""`stillpoint view FILE.mcap`: serve a logged recording to Foxglove over its WebSocket protocol,
with playback control (time range, seek, speed); ``--layout`` writes the layout generated from the
log's topics beside it (``<stem>.layout.json``). Needs the ``live`` extra (foxglove-sdk) to serve."""

from __future__ import annotations

import signal
import sys
import threading
from pathlib import Path

from ._numbers import PLAYBACK_SPEED, PORT

NAME = "view"
KEEPS_EXISTING_OUTPUTS = True  # --overwrite replaces an existing layout file
HELP = "serve a stillpoint MCAP to Foxglove (ws://localhost:PORT) with playback control"


def add_arguments(p) -> None:
    p.add_argument("file", type=Path, help="a finished stillpoint MCAP")
    p.add_argument("--port", type=PORT, default=8765, help="WebSocket port (default 8765; 0: any free port)")
    p.add_argument("--host", default="127.0.0.1",
                   help="address to listen on (default loopback; 0.0.0.0 serves the network)")
    p.add_argument("--speed", type=PLAYBACK_SPEED, default=1.0,
                   help="playback speed, times real time (Foxglove's speed control overrides it)")
    p.add_argument("--layout", action="store_true",
                   help="also write the Foxglove layout for this log beside it as <stem>.layout.json")
    p.add_argument("--layout-only", action="store_true",
                   help="write the layout (as --layout) and exit without serving")


def layout_path(mcap: Path) -> Path:
    return mcap.with_name(mcap.stem + ".layout.json")


def write_layout(mcap: Path) -> Path:
    from stillpoint.engine.core.outputs import atomic_output, check_output_path
    from stillpoint.engine.live.layouts import layout_json, recording_layout
    from stillpoint.engine.live.playback import read_catalogue
    out = check_output_path(layout_path(mcap), what="layout")
    channels, _rng = read_catalogue(mcap)
    with atomic_output(out, binary=False, what="layout") as f:
        f.write(layout_json(recording_layout(channels)))
    return out


def run(args) -> int:
    if args.layout or args.layout_only:
        out = write_layout(args.file)
        print(f"layout: {out}", flush=True)
        if args.layout_only:
            return 0
    from stillpoint.engine.live.playback import RecordingPlayer
    player = RecordingPlayer(args.file, port=args.port, speed=args.speed, host=args.host)
    stop = threading.Event()
    old = signal.signal(signal.SIGINT, lambda *a: stop.set())
    old_term = signal.signal(signal.SIGTERM, lambda *a: stop.set())
    try:
        print(f"serving {args.file} on ws://{args.host}:{player.port} ({len(player.channels)} topics); "
              "open it in Foxglove: Open connection -> Foxglove WebSocket; playback starts when "
              "Foxglove subscribes; Ctrl-C stops", flush=True)
        while not stop.wait(0.5) and player.error is None:
            pass  # serves until Ctrl-C (or the log turns out damaged further on)
    finally:
        signal.signal(signal.SIGINT, old)
        signal.signal(signal.SIGTERM, old_term)
        player.stop()
    if player.error:
        print(f"stillpoint view: error: {player.error}", file=sys.stderr)
        return 2
    return 0
