"""The ``STREAM`` preview (usb-protocols.md A6) logged to MCAP with host receive times.

A preview, never analysis data: each line is one on-demand sensor read, at most 100 Hz,
irregular. The MCAP (written with the ``mcap`` package's writer to ``<name>.part``, renamed when
complete) has one JSON topic ``/preview/accel`` ({"host_time_ns", "counts", "g"} per reading, AX6
also "gyro_counts") and a ``preview`` metadata record that says so. The stream is always stopped
before the port is closed (any line stops it).
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Callable, Optional

from stillpoint.drivers import constants as C
from stillpoint.drivers.outputs import AtomicOutput

TOPIC = "/preview/accel"


def stream_preview(client, out, seconds: float, device_type: str = "AX3",
                   report: Optional[Callable[[str], None]] = None) -> dict:
    from mcap.writer import Writer
    scale = C.AX_STREAM_COUNTS_PER_G_AX3 if device_type == "AX3" else C.AX_STREAM_COUNTS_PER_G_AX6
    ao = AtomicOutput(Path(out), what="preview MCAP")
    n = 0
    t_first = t_last = None
    last_report = time.monotonic()
    try:
        import io
        buf = io.BufferedWriter(ao.file)  # flushed by us: the writer only flushes files it opened
        w = Writer(buf)
        w.start(profile="", library="stillpoint preview")
        w.add_metadata("preview", {"kind": "STREAM preview: irregular on-demand reads, at most 100 Hz; "
                                           "not analysis data", "device_type": device_type,
                                   "counts_per_g": str(scale)})
        sid = w.register_schema("stillpoint.PreviewAccel", "jsonschema", json.dumps(
            {"type": "object", "properties": {"host_time_ns": {"type": "integer"},
                                              "counts": {"type": "array"}, "g": {"type": "array"}}}).encode())
        cid = w.register_channel(TOPIC, "json", sid)
        client.stream_start()
        try:
            for t, vals in client.stream_lines(seconds):
                ns = int(t * 1e9)
                msg = {"host_time_ns": ns, "counts": vals[:3], "g": [v / scale for v in vals[:3]]}
                if len(vals) == 6:
                    msg["gyro_counts"] = vals[3:]
                w.add_message(cid, log_time=ns, publish_time=ns, data=json.dumps(msg).encode(),
                              sequence=n)
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
        w.finish()
        buf.flush()
    except BaseException:
        ao.abandon()
        raise
    ao.commit()
    rate = (n - 1) / (t_last - t_first) if n > 1 and t_last > t_first else 0.0
    return {"readings": n, "rate_hz": round(rate, 2), "output": str(out)}
