"""The ``STREAM`` preview (usb-protocols.md A6) logged to MCAP with host receive times.

A preview, never analysis data: each line is one on-demand sensor read, at most 100 Hz,
irregular. The MCAP (written through the one writer path, engine/mcap/log.py: ``<name>.part``,
renamed when complete) has one JSON topic ``/preview/accel`` ({"host_time_ns", "counts", "g"} per reading, AX6
also "gyro_counts") and a ``preview`` metadata record that says so. The stream is always stopped
before the port is closed (any line stops it).
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Callable, Optional

from stillpoint.drivers import constants as C

TOPIC = "/preview/accel"
PREVIEW_SCHEMA = json.dumps({"type": "object", "properties": {"host_time_ns": {"type": "integer"},
                                                             "counts": {"type": "array"},
                                                             "g": {"type": "array"}}})


def stream_preview(client, out, seconds: float, device_type: str = "AX3",
                   report: Optional[Callable[[str], None]] = None,
                   on_reading: Optional[Callable[[int, dict, bytes], None]] = None) -> dict:
    """Log ``seconds`` of the preview to ``out``; ``on_reading(host_ns, message, payload)`` is
    called with every reading logged (a live view)."""
    from stillpoint.engine.mcap.jsonschemas import JsonSchema
    from stillpoint.engine.mcap.log import McapLog
    scale = C.AX_STREAM_COUNTS_PER_G_AX3 if device_type == "AX3" else C.AX_STREAM_COUNTS_PER_G_AX6
    n = 0
    t_first = t_last = None
    last_report = time.monotonic()
    schema = JsonSchema("stillpoint.PreviewAccel", PREVIEW_SCHEMA)
    with McapLog(Path(out), what="preview MCAP") as w:
        w.write_metadata("preview", {"kind": "STREAM preview: irregular on-demand reads, at most 100 Hz; "
                                             "not analysis data", "device_type": device_type,
                                     "counts_per_g": str(scale)})
        cid = w.channel(TOPIC, "json", schema)
        client.stream_start()
        try:
            for t, vals in client.stream_lines(seconds):
                ns = int(t * 1e9)
                msg = {"host_time_ns": ns, "counts": vals[:3], "g": [v / scale for v in vals[:3]]}
                if len(vals) == 6:
                    msg["gyro_counts"] = vals[3:]
                payload = json.dumps(msg).encode()
                w.add(cid, ns, payload, sequence=n)
                if on_reading is not None:
                    on_reading(ns, msg, payload)
                n += 1
                t_first = t_first or t
                t_last = t
                if report and time.monotonic() - last_report >= 1.0:
                    last_report = time.monotonic()
                    rate = (n - 1) / (t_last - t_first) if t_last > t_first else 0.0
                    g = [round(x, 3) for x in msg["g"]]
                    report(f"{n} readings, {rate:.1f} Hz, last {g} g")
        finally:
            client.stream_stop()
    rate = (n - 1) / (t_last - t_first) if n > 1 and t_last > t_first else 0.0
    return {"readings": n, "rate_hz": round(rate, 2), "output": str(out)}
