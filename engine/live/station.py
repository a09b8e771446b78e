"""The station's devices live in Foxglove (``stillpoint station OUTDIR --foxglove [PORT]``).

``StationLive(out_dir, port=...)`` is a station listener (``Station.add_listener(live.on_change)``)
that publishes, per device, under ``/device/<type>-<id>/`` (``AX3-10001``):

* ``state``: ``{"state", "reason", "info", "detached", "session"}`` on every state change;
* ``progress``: ``{"done_bytes", "total_bytes", "percent", "mbps"}`` on every progress update;
* ``battery`` (``{"percent"}``) and ``clock_offset`` (``{"seconds"}``: device clock minus host
  local time) once the device is identified;
* while it downloads, the topics of the online pipeline's log as it is written
  (``<stem>.unverified.mcap.part``, followed by ``follow.McapFollower``): ``corrected/accel``,
  ``view/accel``, ``metrics/epoch``, ``temperature``, ``calibration`` (every estimate) and ``qc``,
  with their schemas and data times. The raw topics are not served (the raw copy is the record).

Station topics carry host time (ns); the followed topics their data time. The log of record is
untouched: the listener only reads what the download's worker writes. A listener call is quick
and never raises (the station's rule); the log is followed on the listener's own thread, only while
a client is subscribed (a station with no viewer does no extra work). A client subscribing to a
station topic, ``calibration`` or ``qc`` gets its last message again at once (a late viewer sees
the current state and estimate, not only the next change); the streams are not repeated, at most
``follow.MAX_RECORDS_PER_POLL`` records per device per poll. A client that disconnects, or one too
slow to keep up (the SDK drops its oldest queued data messages), never reaches a device's flow.
"""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path

from stillpoint.engine.mcap.stream import ChannelInfo
from stillpoint.engine.station import names

from . import sdk
from .follow import McapFollower
from .layouts import layout_json, station_layout

POLL_S = 0.25
BACKLOG = 4096  # messages queued per client before the SDK drops its oldest data message
RAW_TOPICS = ("/raw/accel", "/raw/gyro")
FOLLOWED_STATES = ("downloading", "verifying")
LATCHED_TOPICS = ("/calibration", "/qc")  # rare events of the followed log, sent again on subscribe


def _obj(title: str, props: dict) -> bytes:
    return json.dumps({"$schema": "https://json-schema.org/draft/2020-12/schema", "title": title,
                       "type": "object", "properties": props}, sort_keys=True).encode()


def _n(desc: str) -> dict:
    return {"type": ["number", "null"], "description": desc}


STATE = ("stillpoint.StationState", _obj("Device state", {
    "state": {"type": "string", "description": "identifying, downloading, verifying, verified, "
                                               "clearing, cleared, configuring, configured, empty, error"},
    "reason": {"type": ["string", "null"]}, "info": {"type": "string"},
    "detached": {"type": "boolean"}, "session": {"type": ["integer", "null"]}}))
PROGRESS = ("stillpoint.StationProgress", _obj("Download progress", {
    "done_bytes": _n("bytes copied"), "total_bytes": _n("bytes on the device"),
    "percent": _n("done_bytes / total_bytes, %"), "mbps": _n("copy speed, MB/s")}))
BATTERY = ("stillpoint.StationBattery", _obj("Battery", {"percent": _n("battery level, %")}))
CLOCK = ("stillpoint.StationClockOffset", _obj("Clock offset", {
    "seconds": _n("device clock minus host local time, s")}))
STATION_TOPICS = {"state": STATE, "progress": PROGRESS, "battery": BATTERY, "clock_offset": CLOCK}


def device_key(flow) -> str:
    return f"{flow.att.device_type}-{flow.att.device_id}"


class StationLive:
    def __init__(self, out_dir, *, port: int = sdk.DEFAULT_PORT, host: str = "127.0.0.1"):
        fg = sdk.load("--foxglove")
        self._fg = fg
        self.out_dir = Path(out_dir)
        self._ctx = fg.Context()
        self._lock = threading.Lock()
        self._channels: dict[str, object] = {}
        self._topics: dict[str, dict[str, ChannelInfo]] = {}  # device -> topic -> info
        self._followers: dict[str, McapFollower] = {}
        self._last: dict[str, tuple] = {}
        self._subscriptions = 0
        self._latest: dict[str, tuple[bytes, int]] = {}  # station topic -> its last message
        self.published = 0
        self.server = sdk.start(fg, self._ctx, "station", port=port, host=host,
                                listener=_Listener(self), layout=self.layout_text,
                                backlog=BACKLOG)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._follow_loop, name="station-live", daemon=True)
        self._thread.start()

    @property
    def port(self) -> int:
        return self.server.port

    def layout_text(self) -> str:
        with self._lock:
            devices = {k: list(v.values()) for k, v in self._topics.items()}
        return layout_json(station_layout(devices))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5.0)
        self.server.stop()

    # ------------------------------------------------------------------ channels
    def _channel(self, key: str, info: ChannelInfo):
        topic = f"/device/{key}{info.topic}"
        with self._lock:
            ch = self._channels.get(topic)
            if ch is None:
                schema = self._fg.Schema(name=info.schema_name, encoding=info.schema_encoding,
                                         data=info.schema_data) if info.schema_name else None
                ch = self._channels[topic] = self._fg.Channel(
                    topic, schema=schema, message_encoding=info.message_encoding, context=self._ctx)
                self._topics.setdefault(key, {})[topic] = ChannelInfo(
                    topic, info.message_encoding, info.schema_name, info.schema_encoding,
                    info.schema_data)
        return ch

    def _publish(self, key: str, name: str, obj: dict, log_time: int) -> None:
        schema_name, schema = STATION_TOPICS[name]
        ch = self._channel(key, ChannelInfo(f"/{name}", "json", schema_name, "jsonschema", schema))
        data = json.dumps(obj).encode()
        self._latest[f"/device/{key}/{name}"] = (data, log_time)
        ch.log(data, log_time=log_time)
        self.published += 1

    # ------------------------------------------------------------------ the station listener
    def on_change(self, flow) -> None:
        key = device_key(flow)
        now = time.time_ns()
        last = self._last.get(key, ())
        state = (flow.state, flow.reason, flow.info, flow.detached, flow.session)
        if not last or last[0] != state:
            self._publish(key, "state", {"state": flow.state, "reason": flow.reason,
                                         "info": flow.info, "detached": bool(flow.detached),
                                         "session": flow.session}, now)
        progress = (flow.done_bytes, flow.total_bytes)
        if not last or last[1] != progress:
            pct = 100.0 * flow.done_bytes / flow.total_bytes if flow.total_bytes else None
            self._publish(key, "progress", {"done_bytes": flow.done_bytes,
                                            "total_bytes": flow.total_bytes, "percent": pct,
                                            "mbps": flow.mbps}, now)
        batt = getattr(flow, "battery_pct", None)
        clock = getattr(flow, "clock_offset_s", None)
        if batt is not None and (not last or last[2] != batt):
            self._publish(key, "battery", {"percent": batt}, now)
        if clock is not None and (not last or last[3] != clock):
            self._publish(key, "clock_offset", {"seconds": clock}, now)
        self._last[key] = (state, progress, batt, clock)
        if flow.state in FOLLOWED_STATES and flow.session is not None:
            with self._lock:
                if key not in self._followers:
                    stem = names.stem(flow.att.device_type, flow.att.device_id, flow.session)
                    log = names.log_unverified(self.out_dir, stem)
                    # the part file is renamed when finished: the same bytes, followed on
                    self._followers[key] = McapFollower(
                        [Path(str(log) + ".part"), log, names.log_final(self.out_dir, stem)],
                        skip_topics=RAW_TOPICS)
        elif key in self._followers:
            with self._lock:
                self._followers[key].finishing = True

    # ------------------------------------------------------------------ the followed logs
    def _follow_loop(self) -> None:
        while not self._stop.wait(POLL_S):
            if self._subscriptions <= 0:  # nobody watching: a finished download is not replayed later
                with self._lock:
                    for key in [k for k, f in self._followers.items() if f.finishing]:
                        del self._followers[key]
                continue
            with self._lock:
                followers = list(self._followers.items())
            for key, fol in followers:
                try:
                    msgs = fol.poll()
                except Exception:  # noqa: BLE001 - a view's fault never reaches the station
                    msgs = []
                for m in msgs:
                    ch = self._channel(key, m.channel)
                    if m.channel.topic in LATCHED_TOPICS:
                        self._latest[f"/device/{key}{m.channel.topic}"] = (m.data, m.log_time)
                    ch.log(m.data, log_time=m.log_time)
                    self.published += 1
                if getattr(fol, "finishing", False) and not msgs:
                    with self._lock:
                        self._followers.pop(key, None)


class _Listener:
    def __init__(self, live: StationLive):
        self.live = live

    def on_subscribe(self, client, channel) -> None:
        with self.live._lock:
            self.live._subscriptions += 1
            ch = self.live._channels.get(channel.topic)
        last = self.live._latest.get(channel.topic)  # a late viewer sees the current state
        if ch is not None and last is not None:
            ch.log(last[0], log_time=last[1])

    def on_unsubscribe(self, client, channel) -> None:  # also called when a client disconnects
        with self.live._lock:
            self.live._subscriptions -= 1

