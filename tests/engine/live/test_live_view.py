"""`stillpoint view`: a logged MCAP served over Foxglove's WebSocket protocol to a loopback client
(server info, every channel advertised with its schema, playback on subscribe, messages equal to
the MCAP's, seek, speed, the layout offered); the layouts generated from the topics; the extra
absent gives one clear line."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from collections import defaultdict

import pytest

from stillpoint.engine.mcap.stream import iter_messages, read_channels, read_time_range
from stillpoint.engine.run import RunSettings, process_file
from stillpoint.tools.cli import main as cli
from synthetic_recording import make_recording


@pytest.fixture(scope="module")
def logged(tmp_path_factory):
    d = tmp_path_factory.mktemp("view")
    rec = d / "rec.cwa"
    make_recording(rec, hours=0.25, rate=50.0, seed=3)
    out = d / "rec.mcap"
    process_file(rec, out, RunSettings())
    return out


def _messages(path):
    got = defaultdict(list)
    for topic, _i, m in iter_messages(path):
        got[topic].append((m.log_time, bytes(m.data)))
    return got


def _sdk():
    from live_client import LiveClient, need_live
    need_live()
    from stillpoint.engine.live.playback import RecordingPlayer
    return LiveClient, RecordingPlayer


def test_view_serves_every_topic_with_its_schema_and_the_mcaps_messages(logged):
    LiveClient, RecordingPlayer = _sdk()
    want = _messages(logged)
    with open(logged, "rb") as f:
        chans = {c.topic: c for c in read_channels(f)}
        first, last = read_time_range(f)
    player = RecordingPlayer(logged, port=0, speed=5000)
    try:
        c = LiveClient(player.port)
        c.pump(5.0, until=lambda: len(c.channels) == len(chans))
        info = c.server_info
        assert c.subprotocol == "foxglove.sdk.v1"
        assert {"playbackControl", "time", "assets"} <= set(info["capabilities"])
        assert info["dataStartTime"]["sec"] * 10**9 + info["dataStartTime"]["nsec"] == first
        assert info["dataEndTime"]["sec"] * 10**9 + info["dataEndTime"]["nsec"] == last
        adv = c.topics()
        assert set(adv) == set(chans) == set(want)
        for topic, ch in chans.items():
            assert adv[topic]["encoding"] == ch.message_encoding
            assert adv[topic]["schemaName"] == ch.schema_name
            assert adv[topic]["schemaEncoding"] == ch.schema_encoding
            assert adv[topic]["schema"].encode() == ch.schema_data
        time.sleep(0.5)
        assert player.status == "waiting" and not c.messages  # nothing before a subscription
        c.subscribe()
        total = sum(len(v) for v in want.values())
        c.pump(60.0, until=lambda: sum(len(v) for v in c.messages.values()) >= total
               and any(s["status"] == "ended" for s in c.states))
        for topic in want:
            assert c.messages[topic] == want[topic], topic  # every message, in order, same bytes
        assert c.times and c.times[-1] == last  # the server clock followed the messages
        c.fetch_asset("package://stillpoint/layout.json", 7)
        c.pump(5.0, until=lambda: 7 in c.assets)
        status, data = c.assets[7]
        assert status == 0 and json.loads(data) == json.loads(player.layout_text)
        c.close()
    finally:
        player.stop()


def test_view_seek_and_speed(logged):
    LiveClient, RecordingPlayer = _sdk()
    with open(logged, "rb") as f:
        first, last = read_time_range(f)
    seek = first + 600 * 10**9
    want = [(m.log_time, bytes(m.data)) for t, _i, m in iter_messages(logged, ["/view/accel"])
            if m.log_time >= seek]
    player = RecordingPlayer(logged, port=0, speed=1.0)
    try:
        c = LiveClient(player.port)
        c.pump(5.0, until=lambda: len(c.channels) >= 7)
        c.subscribe(["/view/accel", "/metrics/epoch"])
        c.pump(5.0, until=lambda: bool(c.messages))  # real time: the first second only
        assert player.status == "playing"
        # seek to 10 minutes in, 60 x real time: the next messages start there
        c.messages.clear()
        c.playback(0, 60.0, seek_ns=seek, request_id="seek-1")
        t0 = time.monotonic()
        # the end of playback and the last messages travel separately: wait for both
        c.pump(30.0, until=lambda: any(s["status"] == "ended" for s in c.states)
               and want[-1] in c.messages.get("/view/accel", ()))
        elapsed = time.monotonic() - t0
        reply = next(s for s in c.states if s["request_id"] == "seek-1")
        assert reply["did_seek"] and reply["speed"] == pytest.approx(60.0)
        assert reply["time"] == seek
        got = c.messages["/view/accel"]
        assert got and min(t for t, _ in got) >= seek
        assert got[-len(want):] == want  # from the seek point on, every message
        # pacing: the ~300 s after the seek at 60 x take at least 5 s (never faster than asked)
        assert elapsed >= (last - seek) / 1e9 / 60.0 * 0.95
        # pause: nothing more is sent
        c.playback(1, 60.0, seek_ns=first, request_id="pause")
        c.pump(3.0, until=lambda: any(s["request_id"] == "pause" for s in c.states))
        paused = next(s for s in c.states if s["request_id"] == "pause")
        assert paused["status"] == "paused" and paused["time"] == first
        c.messages.clear()
        c.pump(1.0)
        assert not c.messages
        c.close()
    finally:
        player.stop()


def test_view_memory_flat_seek_skips_chunks_unread(logged, monkeypatch):
    """A seek reads no chunk that ends before it (a 14-day log is never read from its start to
    reach its last day)."""
    from stillpoint.engine.mcap import stream
    decompressed = []
    real = stream._decompressor

    def counting(name):
        d = real(name)
        return lambda b, n: decompressed.append(n) or d(b, n)
    monkeypatch.setattr(stream, "_decompressor", counting)
    with open(logged, "rb") as f:
        first, last = read_time_range(f)
    all_msgs = list(iter_messages(logged))
    n_all = len(decompressed)
    decompressed.clear()
    late = [m for _t, _i, m in iter_messages(logged, start_ns=last - 60 * 10**9)]
    assert 0 < len(decompressed) < n_all / 4
    assert late and len(late) < len(all_msgs) / 4
    tail = [m.log_time for _t, _i, m in all_msgs if m.log_time >= last - 60 * 10**9]
    assert set(tail) <= {m.log_time for m in late}


def test_recording_layout_is_generated_from_the_topics(logged, tmp_path):
    """`view --layout-only` writes <stem>.layout.json: every plotted path a numeric field of a
    logged topic, every Raw Messages panel a logged JSON topic; batches are not plotted; a second
    run refuses to replace it without --overwrite."""
    from stillpoint.engine.mcap.schemas import ALL_TYPES
    mcap = tmp_path / logged.name
    mcap.write_bytes(logged.read_bytes())
    assert cli(["view", str(mcap), "--layout-only"]) == 0
    out = tmp_path / "rec.layout.json"
    layout = json.loads(out.read_text())
    with open(mcap, "rb") as f:
        chans = {c.topic: c for c in read_channels(f)}
    fields = {t.name: {f for f, kind in t.fields if kind != "time" and not kind.endswith("]")}
              for t in ALL_TYPES}
    plotted = set()
    raw = set()
    for pid, cfg in layout["configById"].items():
        if pid.startswith("Plot!"):
            for p in cfg["paths"]:
                topic, field = p["value"].rsplit(".", 1)
                assert field in fields[chans[topic].schema_name], p["value"]
                plotted.add(p["value"])
        elif pid.startswith("RawMessages!"):
            assert chans[cfg["topicPath"]].message_encoding == "json"
            raw.add(cfg["topicPath"])
    assert {"/view/accel.x", "/view/accel.norm", "/metrics/epoch.enmo_mg",
            "/temperature.celsius"} <= plotted
    assert not any(p.startswith(("/raw/", "/corrected/")) for p in plotted)
    assert raw == {"/calibration", "/qc"}
    leaves = json.dumps(layout["layout"])
    assert all(pid in leaves for pid in layout["configById"])  # every panel is placed
    assert cli(["view", str(mcap), "--layout-only"]) == 2
    assert cli(["view", str(mcap), "--layout-only", "--overwrite"]) == 0


def test_view_of_a_file_that_is_not_a_finished_log_is_one_line(tmp_path, capsys):
    bad = tmp_path / "x.mcap"
    bad.write_bytes(b"not an mcap at all")
    assert cli(["view", str(bad), "--layout-only"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(bad) in err and "Traceback" not in err


@pytest.mark.parametrize("argv", [["view", "{mcap}", "--port", "0"],
                                  ["station", "{out}", "--once", "--foxglove", "0"],
                                  ["device", "stream", "1", "-o", "{out}/p.mcap", "--foxglove"]])
def test_the_extra_absent_gives_one_clear_line(logged, tmp_path, argv):
    """Without foxglove-sdk (its import blocked) each live option says what to install, exit 2,
    before anything is touched."""
    out = tmp_path / "out"
    out.mkdir()
    args = [a.format(mcap=logged, out=out) for a in argv]
    code = ("import sys; sys.modules['foxglove'] = None\n"
            "from stillpoint.tools.cli import main\n"
            f"sys.exit(main({args!r}))")
    env = dict(os.environ, STILLPOINT_RUNTIME_DIR=str(tmp_path / "runtime"))
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                       env=env)
    assert r.returncode == 2, r.stderr
    assert r.stderr.count("\n") == 1 and "Traceback" not in r.stderr
    assert "needs the optional extra `live`: pip install 'stillpoint[live]'" in r.stderr
    assert list(out.iterdir()) == []  # nothing written


def test_a_log_damaged_further_on_ends_playback_with_one_line(logged, tmp_path):
    """A chunk that fails its CRC in the middle of the log: what precedes it is served, then the
    player stops with the error naming the file (the command prints it, exit 2)."""
    LiveClient, RecordingPlayer = _sdk()
    bad = tmp_path / "bad.mcap"
    data = bytearray(logged.read_bytes())
    mid = len(data) // 2
    data[mid:mid + 64] = bytes(64)
    bad.write_bytes(bytes(data))
    player = RecordingPlayer(bad, port=0, speed=1e6)
    try:
        c = LiveClient(player.port)
        c.pump(5.0, until=lambda: len(c.channels) >= 7)
        c.subscribe()
        end = time.monotonic() + 30
        while player.error is None and time.monotonic() < end:
            c.pump(0.2)
        assert player.error is not None and str(bad) in player.error
        assert "\n" not in player.error and sum(len(v) for v in c.messages.values()) > 0
        c.close()
    finally:
        player.stop()


def test_view_command_serves_until_interrupted(logged, tmp_path):
    """`stillpoint view LOG --port 0`: prints where it serves, a client gets the channels, Ctrl-C
    stops it with exit code 0."""
    import re
    import signal
    LiveClient, _ = _sdk()
    p = subprocess.Popen([sys.executable, "-m", "stillpoint.tools", "view", str(logged), "--port", "0"],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = p.stdout.readline()
        port = int(re.search(r"ws://127\.0\.0\.1:(\d+)", line).group(1))
        c = LiveClient(port)
        c.pump(5.0, until=lambda: len(c.channels) == 7)
        assert "/view/accel" in c.topics()
        c.close()
    finally:
        p.send_signal(signal.SIGINT)
        rc = p.wait(30)
    assert rc == 0, p.stderr.read()


def test_view_serves_clients_that_speak_only_foxglove_websocket_v1(logged, caplog):
    """Older Foxglove and Lichtblick offer only the protocol's first name; the front renames it
    both ways and the session is the same. A client offering neither name is refused and the
    log says why."""
    LiveClient, RecordingPlayer = _sdk()
    import logging
    from websockets.exceptions import InvalidStatus
    with open(logged, "rb") as f:
        n_chans = len(read_channels(f))
    player = RecordingPlayer(logged, port=0, speed=5000)
    try:
        c = LiveClient(player.port, subprotocols=["foxglove.websocket.v1"])
        assert c.subprotocol == "foxglove.websocket.v1"
        c.pump(5.0, until=lambda: len(c.channels) == n_chans)
        assert c.server_info and c.server_info["name"].startswith("stillpoint view")
        c.subscribe()
        c.pump(30.0, until=lambda: sum(len(v) for v in c.messages.values()) > 10)
        assert sum(len(v) for v in c.messages.values()) > 10
        c.close()
        with caplog.at_level(logging.WARNING, logger="stillpoint.live"):
            with pytest.raises(InvalidStatus):
                LiveClient(player.port, subprotocols=["ros.bridge.v9"])
            deadline = time.monotonic() + 5
            while time.monotonic() < deadline and not any(
                    "ros.bridge.v9" in r.getMessage() for r in caplog.records):
                time.sleep(0.05)
        msgs = [r.getMessage() for r in caplog.records if r.name == "stillpoint.live"]
        assert any("offers the subprotocol(s) ros.bridge.v9" in m and "foxglove.websocket.v1" in m
                   for m in msgs), msgs
    finally:
        player.stop()


def test_view_keeps_answering_when_nobody_reads_its_stderr(logged):
    """A client sending thousands of bad messages: the server's log lines (one per message from
    the SDK) are rate-limited and written off the server's threads, so with its stderr a pipe
    nobody reads the server still answers a new client, and the log holds a summary line."""
    import re
    import signal
    LiveClient, _ = _sdk()
    p = subprocess.Popen([sys.executable, "-m", "stillpoint.tools", "view", str(logged), "--port", "0"],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        port = int(re.search(r"ws://127\.0\.0\.1:(\d+)", p.stdout.readline()).group(1))
        bad = LiveClient(port)
        for i in range(3000):  # unthrottled: ~250 kB of lines, 4 pipes' worth
            bad.ws.send("{not json " + "x" * (i % 50))
            bad.ws.send(b"\x99garbage")
        bad.close()
        c = LiveClient(port)
        c.pump(10.0, until=lambda: len(c.channels) == 7)
        assert len(c.channels) == 7
        c.close()
    finally:
        p.send_signal(signal.SIGINT)
        try:
            rc = p.wait(30)
        finally:
            err = p.stderr.read()
    assert rc == 0, err
    lines = err.splitlines()
    assert len(lines) <= 60 and "Traceback" not in err, err[:2000]
    assert any("more like" in ln for ln in lines) or len(lines) <= 10, err[:2000]
