"""A configured device is never configured again silently: a retry leaves it as it is, the
dashboard configures it again only when the request names the new session (the confirmation
states it), `device configure` only with --reconfigure; the handover sheet of the superseded
session says so and the new sheet names the one it voids."""

from __future__ import annotations

import os
import threading

from stillpoint.engine.station.flow import StationOptions
from stillpoint.engine.station.profile import StudyProfile
from stillpoint.engine.station.station import Station
from stillpoint.engine.station.web import Dashboard
from stillpoint.engine.station.web.records import Records
from stillpoint.tools.cli import main

from station_fixtures import STUDY_PROFILE, emu, request, runtime, wait  # noqa: F401


def _post(dash, action, key, **form):
    return request(dash, "POST", f"/action/{action}/{key}", dict(form, token=dash.token,
                                                                 confirm="yes"))


def _ok_sessions(out):
    return [c["session_id"] for c in Records(out).history("AX3", 10001)["configurations"]
            if c["result"] == "ok"]


def test_retry_never_reconfigures_and_a_new_session_is_asked_for_by_name(emu, tmp_path):
    d = emu(10001)
    out = tmp_path / "out"
    out.mkdir()
    prof = StudyProfile(rate_hz=50, range_g=4, start="+2h", stop="+7d", min_battery_pct=10)
    st = Station(StationOptions(str(out), profile=prof, clear_after_verify=True,
                                configure_after=True, inline=True),
                 tty=False, out=open(os.devnull, "w"), poll_s=0.05)
    dash = Dashboard(out, st)
    dash.start()
    stop = threading.Event()
    t = threading.Thread(target=st.run, kwargs={"stop": stop}, daemon=True)
    t.start()
    try:
        def flow():
            return next(iter(st.flows.values()), None)
        wait(lambda: flow() and flow().finished.is_set(), timeout=60, what="the first flow")
        assert flow().state == "configured" and d.session_id == 2, flow().reason
        # the start in ISO 8601 like every other time a user reads, not the firmware's form
        import re
        assert re.search(r"start \d{4}-\d\d-\d\dT\d\d:\d\d:\d\d", flow().reason), flow().reason

        # a retry runs the flow again: the device is left configured for session 2
        first = flow()
        s, h, body = _post(dash, "retry", "AX3-10001")
        assert s == 303, body
        wait(lambda: flow() is not first and flow().finished.is_set(), timeout=30,
             what="the retry")
        assert flow().state == "configured", flow().reason
        assert "already configured for session 2" in flow().reason
        assert "not configured again" in flow().reason
        assert d.session_id == 2 and _ok_sessions(out) == [2]

        # the dock offers "Configure again" with a confirmation naming the new session
        s, _, dock = request(dash, "GET", f"/?token={dash.token}")
        assert "Configure again" in dock and "again as session 3?" in dock
        assert "name=reconfigure value='3'" in dock
        # without naming it (or naming another) the request is refused, the device untouched
        for asked in ({}, {"reconfigure": "4"}):
            s, _, body = _post(dash, "configure", "AX3-10001", **asked)
            assert s == 409 and "makes session 3" in body and "reconfigure=3" in body, body
        assert d.session_id == 2 and _ok_sessions(out) == [2]
        # named: configured again, session 3
        before = flow()
        s, h, body = _post(dash, "configure", "AX3-10001", reconfigure="3", who="AB")
        assert s == 303, body
        assert "superseding%20session%202" in h["Location"]
        wait(lambda: flow() is not before and flow().finished.is_set(), timeout=30,
             what="the configuration")
        assert flow().state == "configured", flow().reason
        assert d.session_id == 3 and _ok_sessions(out) == [2, 3]

        # the sheets: the current one names the sheet it voids, the old one says it is void
        s, _, sheet = request(dash, "GET", "/device/AX3-10001/sheet")
        assert s == 200 and "Supersedes" in sheet and "the sheet of session 2" in sheet
        assert "SUPERSEDED" not in sheet
        s, _, old = request(dash, "GET", "/device/AX3-10001/sheet?session=2")
        assert s == 200 and "SUPERSEDED: this device was configured again as session 3" in old
        s, _, page = request(dash, "GET", "/device/AX3-10001")
        assert "/device/AX3-10001/sheet?session=2" in page and "(superseded)" in page
        assert request(dash, "GET", "/device/AX3-10001/sheet?session=9")[0] == 404
    finally:
        stop.set()
        t.join(20)
        dash.close()
        st.close()


def test_device_configure_refuses_a_configured_device_unless_asked(emu, tmp_path, capsys):
    d = emu(10001)
    prof = tmp_path / "study.toml"
    prof.write_text(STUDY_PROFILE)
    out = tmp_path / "out"
    out.mkdir()
    assert main(["device", "download", "10001", "-o", str(out)]) == 0
    assert main(["device", "clear", "10001", "-o", str(out)]) == 0
    assert main(["device", "configure", "10001", "--profile", str(prof), "-o", str(out)]) == 0
    first = d.session_id
    capsys.readouterr()
    assert main(["device", "configure", "10001", "--profile", str(prof), "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"already configured for session {first}" in err[0]
    assert "--reconfigure" in err[0] and d.session_id == first
    assert main(["device", "configure", "10001", "--profile", str(prof), "-o", str(out),
                 "--reconfigure"]) == 0
    assert d.session_id == first + 1
