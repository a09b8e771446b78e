"""A minimal Foxglove WebSocket client for the live tests (the ``websockets`` package, loopback),
speaking the ``foxglove.sdk.v1`` subprotocol (``foxglove.websocket.v1`` offered too): server
info, advertised channels with their schemas, subscriptions, message data, the server's clock,
playback state and control, and asset fetches, decoded per the protocol's message layouts
(github.com/foxglove/ws-protocol docs/spec.md; the playback messages:
github.com/foxglove/foxglove-sdk rust/foxglove/src/websocket/ws_protocol/)."""

from __future__ import annotations

import json
import struct
import importlib
import os
import time
from collections import defaultdict


def need_live() -> None:
    """The live extra (foxglove-sdk) and the websockets client: a visible skip when absent, a
    failure in CI (where the test extra installs both)."""
    import pytest
    for mod, what in (("foxglove", "the live extra (foxglove-sdk)"),
                      ("websockets", "the websockets test client")):
        if os.environ.get("CI"):
            importlib.import_module(mod)  # CI installs the test extra: missing is a failure
        else:
            pytest.importorskip(mod, reason=f"{what} is not installed (pip install -e '.[test]')")

SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]
OP_MESSAGE, OP_TIME, OP_ASSET, OP_PLAYBACK_STATE = 1, 2, 4, 5
OP_PLAYBACK_CONTROL = 3  # client -> server
PLAY, PAUSE = 0, 1
STATUS = {0: "playing", 1: "paused", 2: "buffering", 3: "ended"}


class LiveClient:
    def __init__(self, port: int, host: str = "127.0.0.1", timeout: float = 10.0,
                 subprotocols=SUBPROTOCOLS):
        from websockets.sync.client import connect
        self.closed = False
        self.ws = connect(f"ws://{host}:{port}", subprotocols=list(subprotocols), open_timeout=timeout,
                          max_size=None).__enter__()  # open as long as the client (close())
        self.subprotocol = self.ws.subprotocol
        self.server_info = None
        self.channels: dict[int, dict] = {}  # id -> advertised channel
        self.subs: dict[int, int] = {}  # subscription id -> channel id
        self.messages = defaultdict(list)  # topic -> [(log_time, payload)]
        self.times: list[int] = []
        self.states: list[dict] = []
        self.assets: dict[int, tuple[int, bytes]] = {}
        self.received_at: dict[str, list[float]] = defaultdict(list)

    def close(self):
        self.ws.close()

    def _handle(self, m) -> None:
        if isinstance(m, str):
            d = json.loads(m)
            if d["op"] == "serverInfo":
                self.server_info = d
            elif d["op"] == "advertise":
                for c in d["channels"]:
                    self.channels[c["id"]] = c
            elif d["op"] == "unadvertise":
                for cid in d["channelIds"]:
                    self.channels.pop(cid, None)
            return
        op = m[0]
        if op == OP_MESSAGE:
            sid, lt = struct.unpack_from("<IQ", m, 1)
            topic = self.channels[self.subs[sid]]["topic"] if self.subs[sid] in self.channels else "?"
            self.messages[topic].append((lt, bytes(m[13:])))
            self.received_at[topic].append(time.monotonic())
        elif op == OP_TIME:
            self.times.append(struct.unpack_from("<Q", m, 1)[0])
        elif op == OP_ASSET:
            rid, status, n = struct.unpack_from("<IBI", m, 1)
            self.assets[rid] = (status, bytes(m[10 + n:]))
        elif op == OP_PLAYBACK_STATE:
            status, t, speed, seek, n = struct.unpack_from("<BQfBI", m, 1)
            rid = bytes(m[19:19 + n]).decode()
            self.states.append({"status": STATUS.get(status, status), "time": t, "speed": speed,
                                "did_seek": bool(seek), "request_id": rid})

    def pump(self, seconds: float, until=None) -> None:
        """Read for up to ``seconds`` (stop early once ``until()`` is true, or the server closes)."""
        from websockets.exceptions import ConnectionClosed
        end = time.monotonic() + seconds
        while time.monotonic() < end and not self.closed:
            if until is not None and until():
                return
            try:
                m = self.ws.recv(timeout=min(0.2, max(0.01, end - time.monotonic())))
            except TimeoutError:
                continue
            except ConnectionClosed:  # the server stopped (its command ended)
                self.closed = True
                return
            self._handle(m)

    def subscribe(self, topics=None) -> None:
        subs = []
        for cid, c in self.channels.items():
            if topics is None or c["topic"] in topics:
                sid = len(self.subs) + 1
                self.subs[sid] = cid
                subs.append({"id": sid, "channelId": cid})
        self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))

    def playback(self, command: int, speed: float, seek_ns=None, request_id: str = "r") -> None:
        rid = request_id.encode()
        self.ws.send(struct.pack("<BBfBQ", OP_PLAYBACK_CONTROL, command, speed,
                                 seek_ns is not None, seek_ns or 0)
                     + struct.pack("<I", len(rid)) + rid)

    def fetch_asset(self, uri: str, request_id: int = 1) -> None:
        self.ws.send(json.dumps({"op": "fetchAsset", "uri": uri, "requestId": request_id}))

    def topics(self) -> dict[str, dict]:
        return {c["topic"]: c for c in self.channels.values()}
