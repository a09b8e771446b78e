"""Fixtures for the station tests: emulated devices in this process (axemu:// ports), each test
with its own runtime registry and calibration store, short simulated recordings; the study profile the station tests
configure with (the kill trials' own); waiting for an emulated drive to come back, or for a
condition; one HTTP request to a running dashboard."""

from __future__ import annotations

import http.client
import time
import urllib.parse

import pytest

from stillpoint.drivers.ax.emulator import EmulatedDevice
from stillpoint.drivers.ax.errors import DeviceError
from stillpoint.engine.sim.record import device_recording
from stillpoint.tools.kill_station import PROFILE as STUDY_PROFILE  # noqa: F401 - for the tests

DAYS = 0.01  # ~15 min at 100 Hz: 0.37 MB per AX3


def wait_for(d, timeout_s: float = 10.0):
    """The emulated drive's data file once the drive is back (after COMMIT/FORMAT), as a flow's
    ``wait_volume``."""
    def w():
        end = time.monotonic() + timeout_s
        while not d.data_file.exists():
            if time.monotonic() > end:
                raise DeviceError(d.device_id, "the drive did not come back")
            time.sleep(0.02)
        return str(d.data_file)
    return w


@pytest.fixture
def runtime(tmp_path, monkeypatch):
    """This test's own emulator registry, and its own calibration store (the station's default
    store is the user's)."""
    d = tmp_path / "runtime"
    monkeypatch.setenv("STILLPOINT_RUNTIME_DIR", str(d))
    monkeypatch.setenv("STILLPOINT_HOME", str(tmp_path / "home"))
    return d


@pytest.fixture
def emu(tmp_path, runtime):
    made = []

    def make(device_id=10001, kind="AX3", faults=(), plug=True, pty=False, **kw):
        kw.setdefault("days", DAYS)
        kw.setdefault("make_recording", device_recording)
        kw.setdefault("remount_s", 0.05)
        kw.setdefault("replug_s", 0.3)
        d = EmulatedDevice(tmp_path / f"dev{device_id}", device_id, kind, faults=faults,
                           slot=f"emu-{len(made) + 1}", **kw)
        made.append(d)
        if plug:
            d.plug(pty=pty)  # pty: a pseudo-terminal port other processes open
        return d

    yield make
    for d in made:
        d.shutdown()


def request(dash, method, path, body=None, headers=None):
    """One HTTP request to a running dashboard: (status, headers, body text); ``body`` a form."""
    host, port = dash.httpd.server_address[:2]
    c = http.client.HTTPConnection("127.0.0.1" if host == "0.0.0.0" else host, port, timeout=10)
    h = dict(headers or {})
    if body is not None:
        body = urllib.parse.urlencode(body)
        h["Content-Type"] = "application/x-www-form-urlencoded"
    c.request(method, path, body=body, headers=h)
    r = c.getresponse()
    data = r.read()
    c.close()
    return r.status, dict(r.getheaders()), data.decode("utf-8", "replace")


def wait(cond, timeout=20.0, what="condition"):
    """``cond()``'s first true value, polled every 50 ms; fails after ``timeout`` seconds."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        v = cond()
        if v:
            return v
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}")
