"""A finished log served over Foxglove's WebSocket protocol with playback control
(``stillpoint view FILE.mcap``).

Every channel of the log is advertised with its schema (read from the summary only); the
server announces the log's time range (its Statistics record) and the ``playbackControl`` and
``time`` capabilities. Playback starts when the first client subscribes (after a short grace so
a client subscribing to several channels at once gets the first messages of each), with no
control message needed. A playback control request pauses, plays, changes the speed or seeks:
a seek restarts the read at the first chunk that reaches the requested time (earlier chunks are
skipped unread, ``stream.iter_topic_messages(start_ns=...)``) and drops the messages before it.

Messages are read with the one flat-memory reader (engine/mcap/stream.py: one chunk at a time),
sent at ``log_time`` pace scaled by the speed, and the server's clock follows them. Memory stays
flat for a 14-day log: nothing is kept but the current chunk, and each client's queue is bounded
by the SDK (``BACKLOG`` messages; a client that falls behind loses the oldest data messages, the
reader never waits on it).
"""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Optional

from stillpoint.engine.mcap.reading import McapReadError
from stillpoint.engine.mcap.stream import McapFormatError, iter_messages, read_channels, read_time_range

from . import sdk
from .layouts import layout_json, recording_layout

START_GRACE_S = 0.25  # first subscription -> first message
CLOCK_EVERY_S = 0.05  # the server clock is sent at most this often (wall time)
BACKLOG = 4096  # messages queued per client before the oldest data message is dropped


def read_catalogue(path) -> tuple[list, Optional[tuple[int, int]]]:
    """(channels, (first, last) log time) of a finished log, or an ``McapReadError``."""
    from stillpoint.engine.mcap.replay import check_is_log
    check_is_log(path)  # a recording, or no MCAP at all: one line saying which
    try:
        with open(path, "rb") as f:
            return read_channels(f), read_time_range(f)
    except OSError as e:
        raise McapReadError(path, f"cannot open: {e.strerror or e}") from None
    except (McapFormatError, ValueError) as e:
        raise McapReadError(path, f"cannot serve it: {e}; `stillpoint recover` salvages an "
                                  "unfinished log") from None


class RecordingPlayer:
    """Plays ``path`` to every connected client. ``status``: waiting (no subscriber yet),
    playing, paused or ended; ``position_ns``: the data time reached."""

    def __init__(self, path, *, port: int = sdk.DEFAULT_PORT, speed: float = 1.0,
                 host: str = "127.0.0.1"):
        fg = sdk.load("stillpoint view")
        from foxglove.websocket import Capability
        self.path = Path(path)
        self.channels_info, rng = read_catalogue(self.path)
        self.start_ns, self.end_ns = rng if rng else (0, 0)
        self.layout_text = layout_json(recording_layout(self.channels_info))
        self._cond = threading.Condition()
        self.status = "waiting"
        self.speed = float(speed)
        self.position_ns = self.start_ns
        self._gen = 0  # bumped by every seek: the reader restarts
        self._anchor = (time.monotonic(), self.start_ns)  # (wall, data) of the current pace
        self._stop = False
        self.sent = 0
        self._ctx = ctx = fg.Context()  # kept: the SDK drops the channels of a context that goes
        self.channels = {}
        for c in self.channels_info:
            schema = fg.Schema(name=c.schema_name, encoding=c.schema_encoding,
                               data=c.schema_data) if c.schema_name else None
            self.channels[c.topic] = fg.Channel(c.topic, schema=schema,
                                                message_encoding=c.message_encoding, context=ctx)
        self.server = sdk.start(fg, ctx, f"view {self.path.name}", port=port, host=host,
                                listener=_Listener(self), layout=lambda: self.layout_text,
                                time_range=(self.start_ns, self.end_ns) if rng else None,
                                capabilities=[Capability.Time], backlog=BACKLOG)
        self.error: Optional[str] = None
        self._thread = threading.Thread(target=self._run, name="view-playback", daemon=True)
        self._thread.start()

    @property
    def port(self) -> int:
        return self.server.port

    # ------------------------------------------------------------------ control (SDK threads)
    def _reanchor(self, delay_s: float = 0.0) -> None:
        self._anchor = (time.monotonic() + delay_s, self.position_ns)

    def subscribed(self) -> None:
        with self._cond:
            if self.status == "waiting":
                self.status = "playing"
                self._reanchor(START_GRACE_S)
                self._cond.notify_all()

    def control(self, play: bool, speed: float, seek_ns: Optional[int]) -> None:
        with self._cond:
            if speed and speed > 0:
                self.speed = float(speed)
            if seek_ns is not None:
                self.position_ns = min(max(int(seek_ns), self.start_ns), self.end_ns)
                self._gen += 1
            elif play and self.status == "ended":  # play again from the start
                self.position_ns = self.start_ns
                self._gen += 1
            self.status = "playing" if play else "paused"
            self._reanchor()
            self._cond.notify_all()

    def state(self, fg_ws, did_seek: bool, request_id) -> object:
        S = fg_ws.PlaybackStatus
        status = {"playing": S.Playing, "paused": S.Paused, "ended": S.Ended,
                  "waiting": S.Paused}[self.status]
        return fg_ws.PlaybackState(status, int(self.position_ns), float(self.speed), did_seek,
                                   request_id)

    def stop(self) -> None:
        with self._cond:
            self._stop = True
            self._cond.notify_all()
        self._thread.join(5.0)
        self.server.stop()

    def wait(self, timeout: Optional[float] = None) -> None:
        self._thread.join(timeout)

    # ------------------------------------------------------------------ the reader thread
    def _due(self, lt: int, gen: int) -> bool:
        """Wait (lock held) until message time ``lt`` is due; False if a seek or stop came."""
        while True:
            if self._stop or gen != self._gen:
                return False
            if self.status != "playing":
                self._cond.wait(0.5)
                continue
            wall, data = self._anchor
            due = wall + (lt - data) / 1e9 / self.speed
            now = time.monotonic()
            if due <= now:
                return True
            self._cond.wait(min(due - now, 0.5))

    def _run(self) -> None:
        from foxglove import websocket as fg_ws
        try:
            while True:
                with self._cond:
                    while not self._stop and self.status != "playing":
                        self._cond.wait(0.5)
                    if self._stop:
                        return
                    gen, start = self._gen, self.position_ns
                ended = self._play(gen, start)
                with self._cond:
                    if ended and gen == self._gen and not self._stop:
                        self.status = "ended"
                        self.position_ns = self.end_ns
                        self.server.broadcast_time(int(self.end_ns))
                        self.server.broadcast_playback_state(self.state(fg_ws, False, None))
        except McapReadError as e:
            self.error = str(e)
            with self._cond:
                self.status = "ended"

    def _play(self, gen: int, start: int) -> bool:
        """Send the messages from ``start``; True at the end of the log, False on a seek/stop."""
        last_clock = 0.0
        msgs = iter_messages(self.path, start_ns=start)
        try:
            for topic, _i, m in msgs:
                lt = m.log_time
                if lt < start:
                    continue
                with self._cond:
                    if not self._due(lt, gen):
                        return False
                    self.position_ns = max(self.position_ns, lt)
                self.channels[topic].log(bytes(m.data), log_time=lt)
                self.sent += 1
                now = time.monotonic()
                if now - last_clock >= CLOCK_EVERY_S:
                    self.server.broadcast_time(int(lt))
                    last_clock = now
        finally:
            msgs.close()
        return True


class _Listener:
    """The SDK's server listener: the first subscription starts playback; control requests
    go to the player."""

    def __init__(self, player: RecordingPlayer):
        self.player = player

    def on_subscribe(self, client, channel) -> None:
        self.player.subscribed()

    def on_unsubscribe(self, client, channel) -> None:
        return None

    def on_playback_control_request(self, req):
        from foxglove import websocket as fg_ws
        play = req.playback_command == fg_ws.PlaybackCommand.Play
        self.player.control(play, req.playback_speed, req.seek_time)
        with self.player._cond:
            return self.player.state(fg_ws, req.seek_time is not None, req.request_id)
