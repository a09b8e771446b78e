"""The station's web dashboard over plain HTTP: every endpoint, live and from the ledger alone, and
every refusal (no token, not confirmed, read-only, before a verified download, a path outside the
output folder, a non-loopback address without the token)."""

from __future__ import annotations

import http.client
import json
import os
import sqlite3
import threading
import time
import urllib.parse

import pytest

from stillpoint.engine.station.flow import StationOptions
from stillpoint.engine.station.ledger import LEDGER_NAME
from stillpoint.engine.station.station import Station
from stillpoint.engine.station.web import Dashboard
from stillpoint.tools.cli import main

from station_fixtures import emu, request, runtime, wait  # noqa: F401


def actions(out):
    db = sqlite3.connect(out / LEDGER_NAME)
    try:
        return db.execute("SELECT device_id, action, who, origin, result, reason, detail FROM "
                          "actions ORDER BY id").fetchall()
    finally:
        db.close()


@pytest.fixture
def ledger_only(emu, tmp_path):
    """An output folder a finished station left: three devices, one with a bit misread in the
    copy, all cleared."""
    for i, f in ((10001, ()), (10002, ("bit-flip",)), (10003, ())):
        emu(i, faults=f)
    out = tmp_path / "out"
    out.mkdir()
    with Station(StationOptions(str(out), clear_after_verify=True, inline=True), tty=False,
                 out=open(os.devnull, "w")) as st:
        assert st.run(once=True) == 0
    return out


def test_from_the_ledger_every_page(ledger_only, tmp_path):
    out = ledger_only
    dash = Dashboard(out)
    dash.start()
    try:
        s, h, body = request(dash, "GET", "/")
        assert s == 200 and "read-only" in body and "from the ledger" in body
        for i in (10001, 10002, 10003):
            assert f"data-device='AX3-{i}' data-state='cleared'" in body
        assert "<form" not in body  # no action offered from the ledger alone
        s, h, body = request(dash, "GET", "/api/dock")
        got = json.loads(body)
        assert s == 200 and got["live"] is False and got["read_only"] is True
        assert sorted((d["device_id"], d["state"]) for d in got["devices"]) == \
            [(10001, "cleared"), (10002, "cleared"), (10003, "cleared")]
        assert got["disk"]["from_ledger"] and got["disk"]["downloads_fit"] > 0

        s, h, body = request(dash, "GET", "/device/AX3-10002")
        assert s == 200 and "Downloads and verification" in body and "FORMAT QC" in body
        sha = sqlite3.connect(out / LEDGER_NAME).execute(
            "SELECT sha256 FROM downloads WHERE device_id=10002").fetchone()[0]
        assert sha[:16] in body
        assert body.count("<svg") == 4 and "battery at return" in body
        assert "/files/AX3-10002_1.cwa" in body and "/files/AX3-10002_1.mcap" in body
        s, h, body = request(dash, "GET", "/device/AX3-10002/sheet")
        assert s == 200 and "handover sheet" in body.lower() and "FORMAT QC" in body
        s, h, raw = request(dash, "GET", "/files/AX3-10002_1.cwa")
        assert s == 200 and int(h["Content-Length"]) == (out / "AX3-10002_1.cwa").stat().st_size
        s, h, _ = request(dash, "GET", "/static/dashboard.js")
        assert s == 200 and h["Content-Type"] == "text/javascript"
        assert request(dash, "GET", "/events")[0] == 204  # no station: nothing will change

        # refused: unknown pages, devices and files; paths outside the folder, also by a link
        (tmp_path / "secret.txt").write_text("outside")
        os.symlink(tmp_path / "secret.txt", out / "link.txt")
        for path in ("/nope", "/device/AX3-99999", "/device/XYZ-1", "/device/AX3-10001/x",
                     "/files/../secret.txt", "/files/%2e%2e/secret.txt", "/files/link.txt",
                     "/files/" + urllib.parse.quote(str(tmp_path / "secret.txt")),
                     "/files/missing.cwa", "/static/../records.py"):
            s, h, body = request(dash, "GET", path)
            assert s == 404, path
            assert "outside" not in body
        # read-only: even with the token, no action
        s, h, body = request(dash, "POST", "/action/retry/AX3-10001",
                             {"token": dash.token, "confirm": "yes"})
        assert s == 403 and "read-only" in body
    finally:
        dash.close()
    assert actions(out) == []


@pytest.fixture
def live(emu, tmp_path):
    """A running station (no clear after verify) with its dashboard: 10001 verified, 10002 in
    error (its read ends early)."""
    emu(10001)
    emu(10002, faults=("short-read",))
    out = tmp_path / "out"
    out.mkdir()
    st = Station(StationOptions(str(out), inline=True), tty=False, out=open(os.devnull, "w"))
    dash = Dashboard(out, st)
    dash.start()
    stop = threading.Event()
    t = threading.Thread(target=st.run, kwargs={"stop": stop}, daemon=True)
    t.start()

    def state(i):
        return {f.att.device_id: f for f in st.flows.values()}.get(i)
    wait(lambda: state(10001) and state(10001).finished.is_set() and
         state(10002) and state(10002).finished.is_set(), what="both flows to end")
    assert state(10001).state == "verified" and state(10002).state == "error"
    yield st, dash, out, state
    stop.set()
    t.join(20)
    dash.close()
    st.close()


def test_live_actions_and_refusals(live):
    st, dash, out, state = live
    tok = dash.token
    s, h, body = request(dash, "GET", f"/?token={tok}")
    assert s == 200 and "stillpoint_token=" in h.get("Set-Cookie", "") and "HttpOnly" in h["Set-Cookie"]
    assert "data-state='verified'" in body and "data-state='error'" in body
    assert body.index("AX3-10002") < body.index("AX3-10001")  # attention first
    assert "/action/clear/AX3-10001" in body and tok in body
    s, h, body = request(dash, "GET", "/")
    assert s == 200 and "<form" not in body  # loopback: readable, but no action without the token
    for host in ("localhost:1", "[::1]:8080", "127.0.0.1"):
        assert request(dash, "GET", "/api/dock", headers={"Host": host})[0] == 200, host
    # a page of another site whose name points at 127.0.0.1 cannot read the dock
    for host in ("evil.example:8080", "", "127.0.0.1.evil.example"):
        s, _, body = request(dash, "GET", "/api/dock", headers={"Host": host})
        assert s == 403 and "token" in body, host
    assert request(dash, "GET", f"/api/dock?token={tok}", headers={"Host": "x.example"})[0] == 200

    # refused before any device is touched
    def post(action, key, **form):
        return request(dash, "POST", f"/action/{action}/{key}", form)
    assert post("clear", "AX3-10001", confirm="yes")[0] == 403  # no token
    assert post("clear", "AX3-10001", token="wrong", confirm="yes")[0] == 403
    s, _, body = request(dash, "GET", "/action/clear/AX3-10001?token=" + tok + "&confirm=yes")
    assert s == 404  # actions only by POST
    assert post("clear", "AX3-10001", token=tok)[0] == 400  # not confirmed
    assert actions(out) == []
    s, _, body = post("clear", "AX3-10002", token=tok, confirm="yes", who="AB")
    assert s == 409 and "only a device whose download is verified" in body  # before verification
    assert post("configure", "AX3-10001", token=tok, confirm="yes")[0] == 409  # no profile
    assert post("explode", "AX3-10001", token=tok, confirm="yes")[0] == 404
    assert post("retry", "AX3-77777", token=tok, confirm="yes")[0] == 409  # not attached
    assert len(st.ledger.clears()) == 0
    rows = actions(out)
    assert [(r[0], r[1], r[4]) for r in rows] == [(10002, "clear", "refused"),
                                                  (10001, "configure", "refused"),
                                                  (77777, "retry", "refused")]
    assert rows[0][2] == "AB" and rows[0][3].startswith("127.0.0.1")

    # verify again: device, copy and ledger agree
    s, h, _ = post("verify", "AX3-10001", token=tok, confirm="yes")
    assert s == 303 and h["Location"].startswith("/?done=")
    wait(lambda: actions(out)[-1][4] == "ok", what="the verification")
    assert "hold the same" in actions(out)[-1][5]

    # the live stream: connected, then a state change arrives within 1 s
    host, port = dash.httpd.server_address[:2]
    c = http.client.HTTPConnection(host, port, timeout=10)
    c.request("GET", "/events", headers={"Cookie": f"stillpoint_token={tok}"})
    r = c.getresponse()
    assert r.status == 200 and r.getheader("Content-Type") == "text/event-stream"
    first = r.fp.readline()
    assert first.startswith(b"data: ") and b"/action/" in first
    r.fp.readline()

    # clear: through the station's clear path, after its byte check; the change is on the
    # page within 1 s of the station's state change
    changed = []
    st.add_listener(lambda f: changed or changed.append(time.monotonic()))
    s, h, _ = post("clear", "AX3-10001", token=tok, confirm="yes")
    assert s == 303
    seen = b""
    while b"data-device='AX3-10001' data-state='verified'" in seen or not seen.startswith(b"data"):
        seen = r.fp.readline()
    assert time.monotonic() - changed[0] < 1.0  # the first change after the POST, on the page
    c.close()
    wait(lambda: state(10001).finished.is_set() and state(10001).state == "cleared",
         what="the clear")
    clears = st.ledger.clears(10001)
    assert len(clears) == 1 and clears[0][4] == "ok" and clears[0][6] == "FORMAT QC"
    # after the clear: a second clear or verification is refused (nothing verified to clear)
    assert post("clear", "AX3-10001", token=tok, confirm="yes")[0] == 409
    assert post("verify", "AX3-10001", token=tok, confirm="yes")[0] == 409

    # retry of the device in error: its flow runs again
    before = len(st.ledger.events(10002))
    assert post("retry", "AX3-10002", token=tok, confirm="yes")[0] == 303
    wait(lambda: len(st.ledger.events(10002)) > before + 1, what="the retry")
    wait(lambda: state(10002).finished.is_set(), what="the retried flow")
    acts = [(r[1], r[4]) for r in actions(out)]
    assert ("clear", "started") in acts and ("retry", "started") in acts

    # the device page shows the clear, the verification and the actions
    s, _, body = request(dash, "GET", "/device/AX3-10001")
    assert s == 200 and "FORMAT QC" in body and "hold the same" in body and "127.0.0.1" in body


def test_not_loopback_needs_the_token(live):
    st, _, out, _ = live
    dash = Dashboard(out, st, host="0.0.0.0", port=0, read_only=True)
    dash.start()
    try:
        assert not dash.loopback and len(dash.token) >= 16
        for path in ("/", "/api/dock", "/device/AX3-10001", "/files/AX3-10001_1.cwa", "/events"):
            s, _, body = request(dash, "GET", path)
            assert s == 403 and "token" in body, path
        s, h, body = request(dash, "GET", f"/?token={dash.token}")
        assert s == 200 and "<form" not in body  # read-only: no action even with the token
        cookie = h["Set-Cookie"].split(";")[0]
        assert request(dash, "GET", "/api/dock", headers={"Cookie": cookie})[0] == 200
        s, _, body = request(dash, "POST", "/action/retry/AX3-10002",
                             {"token": dash.token, "confirm": "yes"})
        assert s == 403 and "read-only" in body
    finally:
        dash.close()


def test_given_token_and_cli_refusals(tmp_path, capsys, monkeypatch):
    out = tmp_path / "empty"
    out.mkdir()
    assert main(["dashboard", str(out)]) == 2
    err = capsys.readouterr().err
    assert "holds no station ledger" in err and len(err.strip().splitlines()) == 1
    assert main(["dashboard", str(tmp_path / "missing")]) == 2
    assert "does not exist" in capsys.readouterr().err
    for bad in ("127.0.0.1:99999", "host:port", ":-1"):
        assert main(["station", str(out), "--web", bad, "--once", "--plain"]) == 2
        err = capsys.readouterr().err
        assert "--web" in err and "Traceback" not in err, bad
    # a port already taken: one line naming it, exit code 2
    import socket
    monkeypatch.setenv("STILLPOINT_RUNTIME_DIR", str(tmp_path / "runtime"))
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen(1)
        port = taken.getsockname()[1]
        assert main(["station", str(out), "--web", f"127.0.0.1:{port}", "--once", "--plain"]) == 2
        err = capsys.readouterr().err
        assert f"127.0.0.1:{port}: cannot serve there" in err and len(err.strip().splitlines()) == 1
    # a given token is the one used
    dash = Dashboard(tmp_path / "empty", token="my-secret-token-123")
    assert dash.token == "my-secret-token-123"
    dash.httpd.server_close()
