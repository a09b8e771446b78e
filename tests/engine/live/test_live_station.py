"""The station live in Foxglove: a loopback WebSocket client sees each device's state, progress,
battery, clock offset and, while it downloads, the online pipeline's corrected stream and
calibration estimates; a client that disconnects mid-stream leaves the station's outputs as they
would be without it."""

from __future__ import annotations

import io
import json
import threading
import time
from collections import Counter

import pytest

from live_client import LiveClient, need_live  # noqa: E402

need_live()
from station_fixtures import emu, runtime  # noqa: E402,F401
from stillpoint.drivers.ax.discovery import EmulatedBackend  # noqa: E402
from stillpoint.engine.mcap.stream import iter_messages  # noqa: E402
from stillpoint.engine.station.flow import StationOptions  # noqa: E402
from stillpoint.engine.station.station import Station  # noqa: E402


def _run_station(out, live=None):
    with Station(StationOptions(str(out), inline=True), EmulatedBackend(), tty=False,
                 out=io.StringIO(), poll_s=0.05) as st:
        if live is not None:
            st.add_listener(live.on_change)
        return st.run(once=True)


def _subscriber(c, done):
    """A pump condition that subscribes to every channel the station advertises, as Foxglove
    does, once it has been advertised for a moment (the SDK registers a new channel for its
    clients just after it sends the advertisement); true once ``done()``."""
    subscribed: set = set()
    seen: dict = {}

    def step():
        now = time.monotonic()
        for cid in c.channels:
            seen.setdefault(cid, now)
        new = {cid for cid, t0 in seen.items() if cid not in subscribed and now - t0 > 0.1}
        if new:
            subscribed.update(new)
            c.subscribe([c.channels[cid]["topic"] for cid in new])
        return done()
    return step


def test_station_devices_live(emu, tmp_path):
    from stillpoint.engine.live.station import StationLive
    emu(10001, days=0.03, read_bps=300_000, clock_offset_s=-7.5, battery_pct=64.0)  # 2 reads, ~4 s
    out = tmp_path / "out"
    out.mkdir()
    live = StationLive(out, port=0)
    try:
        c = LiveClient(live.port)
        c.pump(2.0, until=lambda: c.server_info is not None)
        assert c.subprotocol == "foxglove.sdk.v1"
        assert "assets" in c.server_info["capabilities"]
        rc_box = {}
        t = threading.Thread(target=lambda: rc_box.setdefault("rc", _run_station(out, live)))
        t.start()
        resubscribe = _subscriber(c, lambda: not t.is_alive())
        while t.is_alive():
            c.pump(0.2, until=resubscribe)
        c.pump(0.5)
        resubscribe()
        c.pump(2.0, until=lambda: bool(c.messages.get("/device/AX3-10001/calibration")))
        t.join()
        assert rc_box["rc"] == 0
        topics = c.topics()
        dev = "/device/AX3-10001"
        for name in ("state", "progress", "battery", "clock_offset"):
            assert topics[f"{dev}/{name}"]["schemaEncoding"] == "jsonschema"
        assert topics[f"{dev}/view/accel"]["encoding"] == "cdr"
        assert topics[f"{dev}/view/accel"]["schemaName"] == "stillpoint/msg/AccelSample"
        assert f"{dev}/raw/accel" not in topics  # the raw copy is the record, not served
        states = [json.loads(p)["state"] for _t, p in c.messages[f"{dev}/state"]]
        assert "downloading" in states and states[-1] == "verified"
        assert json.loads(c.messages[f"{dev}/battery"][0][1])["percent"] == 64
        assert abs(json.loads(c.messages[f"{dev}/clock_offset"][0][1])["seconds"] + 7.5) < 1.0
        prog = [json.loads(p) for _t, p in c.messages[f"{dev}/progress"]]
        assert prog[-1]["percent"] == pytest.approx(100.0)
        assert any(0 < (p["percent"] or 0) < 100 for p in prog)  # seen while it ran
        # the followed stream: exactly the messages of the log the station kept, data times
        final = next(out.glob("AX3-10001_*.mcap"))
        logged = {}
        for topic, _i, m in iter_messages(final):
            logged.setdefault(topic, []).append((m.log_time, bytes(m.data)))
        for topic in ("/view/accel", "/corrected/accel", "/metrics/epoch"):
            got = c.messages[f"{dev}{topic}"]
            k = logged[topic].index(got[0])  # what was logged before the client subscribed is not sent
            assert len(got) > 10 and got == logged[topic][k:k + len(got)], topic
        got = c.messages[f"{dev}/calibration"]  # sent again on subscribe: every one is the log's
        assert got and all(m in logged["/calibration"] for m in got)
        assert got[-1] == logged["/calibration"][-1]
        # the station's layout: a tab for the device, panels on its topics
        c.fetch_asset("package://stillpoint/layout.json", 3)
        c.pump(2.0, until=lambda: 3 in c.assets)
        status, data = c.assets[3]
        layout = json.loads(data)
        assert status == 0 and layout["configById"]["Tab!devices"]["tabs"][0]["title"] == "AX3-10001"
        assert f"{dev}/state.state" in json.dumps(layout)
        c.close()
        # a client arriving after the download gets each station topic's last message
        late = LiveClient(live.port)
        late.pump(2.0, until=lambda: f"{dev}/battery" in late.topics())
        late.subscribe([f"{dev}/state", f"{dev}/battery"])
        late.pump(5.0, until=lambda: len(late.messages) == 2)
        assert json.loads(late.messages[f"{dev}/state"][-1][1])["state"] == "verified"
        assert json.loads(late.messages[f"{dev}/battery"][-1][1])["percent"] == 64
        late.close()
    finally:
        live.close()


def test_a_client_leaving_mid_stream_does_not_disturb_the_station(emu, tmp_path):
    from stillpoint.engine.live.station import StationLive
    emu(10001, days=0.03, read_bps=300_000)
    out_live, out_plain = tmp_path / "live", tmp_path / "plain"
    out_live.mkdir()
    out_plain.mkdir()
    live = StationLive(out_live, port=0)
    try:
        c = LiveClient(live.port)
        rc_box = {}
        t = threading.Thread(target=lambda: rc_box.setdefault("rc", _run_station(out_live, live)))
        t.start()
        c.pump(20.0, until=_subscriber(c, lambda: len(c.messages.get("/device/AX3-10001/view/accel", ())) >= 5))
        assert t.is_alive(), "the download ended before the client left: slow the emulated read"
        c.ws.close()  # mid-stream
        t.join(120)
        assert rc_box["rc"] == 0
    finally:
        live.close()
    assert _run_station(out_plain) == 0
    a, b = next(out_live.glob("AX3-10001_*.mcap")), next(out_plain.glob("AX3-10001_*.mcap"))
    ca = Counter((t, m.log_time, bytes(m.data)) for t, _i, m in iter_messages(a) if t != "/qc")
    cb = Counter((t, m.log_time, bytes(m.data)) for t, _i, m in iter_messages(b) if t != "/qc")
    assert ca == cb
    assert next(out_live.glob("AX3-10001_*.cwa")).read_bytes() == next(out_plain.glob("AX3-10001_*.cwa")).read_bytes()


def test_device_stream_preview_live_corrected_by_the_stored_calibration(emu, tmp_path, monkeypatch):
    """`device stream ID --foxglove`: each preview reading the MCAP logs is served live, raw and
    corrected by the device's stored calibration ((g + offset) * scale)."""
    import numpy as np

    from stillpoint.engine.calibration.estimate import CalibrationEstimate
    from stillpoint.engine.calibration.store import CalibrationStore
    from stillpoint.engine.live import preview as live_preview
    from stillpoint.tools.cli import main
    monkeypatch.setenv("STILLPOINT_HOME", str(tmp_path / "home"))
    est = CalibrationEstimate(offset=np.array([0.02, -0.01, 0.03]), scale=np.array([1.01, 0.99, 1.02]),
                              status="ok", reason="test", method="autocal-c1", error_before_mg=20.0,
                              error_after_mg=2.0, windows=50, fit_start_ns=1, fit_end_ns=2)
    CalibrationStore().add(est, device_key="AX3-10001")
    emu(10001)
    made = []
    real_init = live_preview.PreviewLive.__init__

    def init(self, *a, **kw):
        real_init(self, *a, **kw)
        made.append(self)
    monkeypatch.setattr(live_preview.PreviewLive, "__init__", init)
    out = tmp_path / "p.mcap"
    rc = {}
    t = threading.Thread(target=lambda: rc.setdefault("rc", main(
        ["device", "stream", "10001", "-o", str(out), "--seconds", "4", "--foxglove", "0"])))
    t.start()
    end = time.monotonic() + 30
    while not made and time.monotonic() < end:
        time.sleep(0.05)
    c = LiveClient(made[0].port)
    assert "/preview/corrected.norm" in made[0].layout_text  # its layout plots the corrected reading
    c.pump(5.0, until=lambda: len(c.channels) == 2)
    assert set(c.topics()) == {"/preview/accel", "/preview/corrected"}
    c.subscribe()
    c.pump(10.0, until=lambda: not t.is_alive())
    t.join()
    assert rc["rc"] == 0
    logged = {m.log_time: json.loads(bytes(m.data)) for _t, _i, m in iter_messages(out)}
    raw, cor = c.messages["/preview/accel"], c.messages["/preview/corrected"]
    assert len(raw) >= 10 and len(cor) == len(raw)
    for (lt, payload), (lt2, cp) in zip(raw, cor):
        assert lt == lt2 and json.loads(payload) == logged[lt]
        d = json.loads(cp)
        want = (np.array(logged[lt]["g"]) + est.offset) * est.scale
        assert np.allclose(d["g"], want) and d["calibration"] == "autocal-c1"
    c.close()


def test_station_command_with_foxglove(emu, tmp_path, capsys):
    """`stillpoint station OUT --once --foxglove 0`: the address is printed, the device is
    downloaded as without the option."""
    from stillpoint.tools.cli import main
    emu(10001)
    out = tmp_path / "out"
    out.mkdir()  # the station never creates its output folder
    assert main(["station", str(out), "--once", "--plain", "--foxglove", "0"]) == 0
    text = capsys.readouterr().out
    assert "foxglove: ws://127.0.0.1:" in text and "verified" in text
    assert next(out.glob("AX3-10001_*.mcap")).is_file()
