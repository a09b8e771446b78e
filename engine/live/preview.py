"""A device's ``STREAM`` preview live in Foxglove (``stillpoint device stream ID --foxglove``).

Each reading the preview logs (engine/station/preview.py) is also published: ``/preview/accel``
(the logged message, same schema) and ``/preview/corrected`` (``{"host_time_ns", "g", "norm",
"calibration"}``: the reading corrected by the device's stored calibration when the calibration
store has one: its latest static six-orientation calibration, else its latest usable estimate;
``(g + offset) * scale``; a temperature term is not applied, a preview reading carries no
temperature). Without a stored calibration ``g`` is the uncorrected reading and ``calibration``
is null. Log times are host receive times. A preview, never analysis data.
"""

from __future__ import annotations

import json
import math
from typing import Optional

from . import sdk
from .layouts import layout_json, recording_layout
from stillpoint.engine.mcap.stream import ChannelInfo

TOPIC_RAW = "/preview/accel"
TOPIC_CORRECTED = "/preview/corrected"
CORRECTED_SCHEMA = json.dumps({
    "$schema": "https://json-schema.org/draft/2020-12/schema", "title": "Corrected preview reading",
    "type": "object", "properties": {
        "host_time_ns": {"type": "integer", "description": "host receive time, ns (UTC)"},
        "g": {"type": "array", "items": {"type": "number"}, "description": "x, y, z, g"},
        "x": {"type": "number"}, "y": {"type": "number"}, "z": {"type": "number"},
        "norm": {"type": "number", "description": "vector magnitude, g"},
        "calibration": {"type": ["string", "null"],
                        "description": "method of the stored calibration applied (null: none)"}}},
    sort_keys=True).encode()


def stored_calibration(device_key: str, store_root=None):
    """The device's stored calibration (latest static, else latest usable), or None."""
    from stillpoint.engine.calibration.store import CalibrationStore
    store = CalibrationStore(store_root)
    return store.latest_static(device_key) or store.latest(device_key)


class PreviewLive:
    def __init__(self, device_key: str, raw_schema: bytes, *, port: int = sdk.DEFAULT_PORT,
                 host: str = "127.0.0.1", calibration=None):
        fg = sdk.load("--foxglove")
        self.cal = calibration
        self._ctx = fg.Context()
        infos = [ChannelInfo(TOPIC_RAW, "json", "stillpoint.PreviewAccel", "jsonschema", raw_schema),
                 ChannelInfo(TOPIC_CORRECTED, "json", "stillpoint.PreviewCorrected", "jsonschema",
                             CORRECTED_SCHEMA)]
        self.channels = {c.topic: fg.Channel(c.topic, schema=fg.Schema(
            name=c.schema_name, encoding=c.schema_encoding, data=c.schema_data),
            message_encoding="json", context=self._ctx) for c in infos}
        self.layout_text = layout_json(recording_layout(infos))
        self.server = sdk.start(fg, self._ctx, f"preview {device_key}", port=port, host=host,
                                layout=lambda: self.layout_text)

    @property
    def port(self) -> int:
        return self.server.port

    def corrected(self, g: list) -> tuple[list, Optional[str]]:
        if self.cal is None:
            return list(g), None
        return ([(float(v) + float(o)) * float(s) for v, o, s in zip(g, self.cal.offset, self.cal.scale)],
                self.cal.method)

    def on_reading(self, host_ns: int, msg: dict, payload: bytes) -> None:
        self.channels[TOPIC_RAW].log(payload, log_time=host_ns)
        g, method = self.corrected(msg["g"])
        self.channels[TOPIC_CORRECTED].log(json.dumps({
            "host_time_ns": host_ns, "g": g, "x": g[0], "y": g[1], "z": g[2],
            "norm": math.sqrt(sum(v * v for v in g)), "calibration": method}).encode(),
            log_time=host_ns)

    def close(self) -> None:
        self.server.stop()
