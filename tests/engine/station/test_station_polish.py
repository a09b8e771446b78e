"""The station and emulator as a first-time user meets them: charged emulated devices (a low
battery is a fault), the README's profile configures them, the live table fits the terminal,
`devices` has a header and says recording windows in words, one rule for a missing output
folder, read-only said as read-only, the emulator's drives removed on exit, its registry per user
and per session."""

from __future__ import annotations

import io
import os
import re
import signal
import subprocess
import sys
import time

import pytest

from stillpoint.drivers.ax.discovery import EmulatedBackend, discover
from stillpoint.drivers.ax.emulator import EmulatedDevice
from stillpoint.engine.sim.record import device_recording
from stillpoint.drivers.ax.protocol import AxClient
from stillpoint.engine.station.flow import StationOptions
from stillpoint.engine.station.profile import load_profile
from stillpoint.engine.station.station import Station
from stillpoint.engine.station.status import recording_window
from stillpoint.tools.cli import main

from station_fixtures import emu, runtime  # noqa: F401

# the README's study profile (its `type = "AX6"` line left out: every key is optional, and the
# example's three devices are two AX3s and an AX6)
README_PROFILE = """\
[device]
rate_hz = 100
range_g = 8
gyro_dps = 0
start = "+1h"
stop = "+8d"
session = "increment"
min_battery_pct = 80
[metadata]
study = "ABC"
[station]
clear_after_verify = true
configure_after = true
erase = "quick"
"""


def test_emulated_devices_are_charged_and_a_low_battery_is_a_fault(emu):
    for d, want in ((emu(10001), (100, 100)), (emu(10002, faults=("low-battery",)), (15, 16)),
                    (emu(10003, battery_pct=40), (40, 41))):
        with AxClient.open(f"axemu://{d.serial}") as c:
            assert want[0] <= c.battery().percent <= want[1], d.serial


def test_the_readme_profile_configures_the_emulated_devices(emu, tmp_path):
    emu(10001)
    emu(10002, faults=("bit-flip",))
    emu(10003, "AX6")
    emu(10004, faults=("low-battery",))
    prof = tmp_path / "study.toml"
    prof.write_text(README_PROFILE)
    out = tmp_path / "out"
    out.mkdir()
    buf = io.StringIO()
    with Station(StationOptions(str(out), profile=load_profile(prof), clear_after_verify=True,
                                configure_after=True, inline=True, products=False),
                 EmulatedBackend(), tty=False, out=buf, poll_s=0.05) as st:
        assert st.run(once=True) == 2
        states = {f.att.device_id: (f.state, f.reason) for f in st.flows.values()}
    assert all(states[i][0] == "configured" for i in (10001, 10002, 10003)), states
    assert states[10004][0] == "error" and "battery 1" in states[10004][1] \
        and "below the profile's minimum 80 %" in states[10004][1]


def test_the_live_table_fits_a_narrow_terminal(emu, tmp_path, monkeypatch):
    monkeypatch.setenv("COLUMNS", "40")
    emu(10001)
    emu(10002, faults=("io-error",))
    out = tmp_path / "out"
    out.mkdir()
    buf = io.StringIO()
    with Station(StationOptions(str(out), inline=True, products=False), EmulatedBackend(),
                 tty=True, out=buf, poll_s=0.05) as st:
        assert st.run(once=True) == 2
    lines = re.sub(r"\x1b\[(\d+A|2K)", "", buf.getvalue()).split("\n")
    assert len(lines) > 6 and max(len(x) for x in lines) == 39
    assert any(x.startswith("emu-2") and x.endswith(">") for x in lines)  # cut, and says so


def test_devices_has_a_header_row_and_windows_in_words(emu, capsys):
    emu(10001)
    d = emu(10002)
    with AxClient.open(f"axemu://{d.serial}") as c:
        c.hibernate("-1")
        c.stop("-1")
    assert main(["devices"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].split() == ["slot", "id", "type", "fw", "session", "battery", "clock",
                                "window", "data", "state"]
    assert "always" in lines[1] and "never" in lines[2] and "..-1" not in "".join(lines)
    assert lines[1].index("always") == lines[0].index("window")  # the columns line up


@pytest.mark.parametrize("start,stop,said", [
    ("0", "-1", "always"),
    ("-1", "-1", "never"),  # the vendor's "never log"
    ("0", "0", "never"),
    ("0", "2030/01/02,03:04:05", "until 2030-01-02 03:04:05"),
    ("2030/01/02,03:04:05", "-1", "from 2030-01-02 03:04:05"),
    ("2030/01/02,03:04:05", "2030/01/09,03:04:05", "2030-01-02 03:04:05 to 2030-01-09 03:04:05"),
    ("2030/01/09,03:04:05", "2030/01/02,03:04:05", "never"),
])
def test_recording_windows_in_words(start, stop, said):
    assert recording_window(start, stop) == said


def test_a_missing_output_folder_is_refused_alike_and_never_created(emu, tmp_path, capsys):
    emu(10001)
    missing = tmp_path / "study-out"
    for args in (["station", str(missing), "--once"], ["device", "download", "10001", "-o",
                                                       str(missing)]):
        assert main(args) == 2
        err = capsys.readouterr().err
        assert f"{missing}: the output folder does not exist; it is never created" in err, args
        assert "Traceback" not in err and not missing.exists()


@pytest.mark.parametrize("read_only_fs,said", [
    (True, "output folder is read-only (on a read-only file system)"),
    (False, "output folder is read-only for this user (permission denied)")])
def test_a_read_only_folder_is_said_as_read_only(emu, tmp_path, capsys, monkeypatch, read_only_fs,
                                                  said):
    emu(10001)
    out = tmp_path / "out"
    out.mkdir()
    real_access, real_statvfs = os.access, os.statvfs

    class Vfs:
        f_flag = os.ST_RDONLY if read_only_fs else 0

    monkeypatch.setattr(os, "access", lambda p, mode, **k: False if str(p) == str(out)
                        else real_access(p, mode, **k))
    monkeypatch.setattr(os, "statvfs", lambda p: Vfs() if str(p) == str(out) else real_statvfs(p))
    for args in (["station", str(out), "--once"], ["device", "download", "10001", "-o", str(out)]):
        assert main(args) == 2
        err = capsys.readouterr().err
        assert f"{out}: {said}" in err and "does not exist" not in err, args


def _emulate(runtime, *extra, session=None):
    env = dict(os.environ, STILLPOINT_RUNTIME_DIR=str(runtime))
    env.pop("STILLPOINT_EMULATOR_SESSION", None)
    p = subprocess.Popen([sys.executable, "-m", "stillpoint.tools", "device", "emulate", "--count",
                          "2", "--days", "0.002", *extra], env=env, stdout=subprocess.PIPE,
                         stderr=subprocess.STDOUT, text=True)
    text = ""
    end = time.monotonic() + 60
    while time.monotonic() < end and "attached" not in text:
        text += p.stdout.readline()
    assert "2 emulated device(s) attached" in text, text
    drives = re.findall(r"drive (\S+)", text)
    assert len(drives) == 2 and all(os.path.isdir(x) for x in drives)
    return p, drives


@pytest.mark.parametrize("how", [signal.SIGINT, signal.SIGTERM])
def test_the_emulator_removes_its_drives_when_it_stops(runtime, how):
    p, drives = _emulate(runtime)
    p.send_signal(how)
    out, _ = p.communicate(timeout=30)
    assert p.returncode == 0, out
    assert "Traceback" not in out and not any(os.path.exists(x) for x in drives)
    sessions = runtime / "sessions" / "default"
    assert not list(sessions.glob("emulated-*"))  # the run's own folder too
    assert not list((sessions / "devices").glob("*.json"))  # unregistered


def test_the_emulator_keeps_its_drives_when_asked(runtime):
    p, drives = _emulate(runtime, "--keep")
    p.send_signal(signal.SIGINT)
    out, _ = p.communicate(timeout=30)
    assert "the emulated drives are kept in" in out
    assert all(os.path.isfile(os.path.join(x, "CWA-DATA.CWA")) for x in drives)


def test_emulated_devices_are_seen_in_their_own_session_only(tmp_path, runtime, monkeypatch):
    monkeypatch.setenv("STILLPOINT_EMULATOR_SESSION", "alice")
    d = EmulatedDevice(tmp_path / "a", 10001, make_recording=device_recording, days=0.002)
    try:
        d.plug()
        assert [a.device_id for a in discover(EmulatedBackend())] == [10001]
        monkeypatch.setenv("STILLPOINT_EMULATOR_SESSION", "bob")
        assert discover(EmulatedBackend()) == []
        monkeypatch.delenv("STILLPOINT_EMULATOR_SESSION")
        monkeypatch.delenv("XDG_SESSION_ID", raising=False)
        assert discover(EmulatedBackend()) == []  # the default session: not alice's
    finally:
        d.shutdown()


def test_a_second_emulator_cannot_take_a_live_devices_name(tmp_path, runtime, capsys):
    """Two emulators of one session with the same ids: the second says so in one line."""
    import json
    from stillpoint.drivers.ax import registry
    from stillpoint.drivers.ax.emulator import serial_number
    d = registry.devices_dir()
    d.mkdir(parents=True)
    (d / f"{serial_number('AX3', 10001)}.json").write_text(json.dumps(
        {"serial": serial_number("AX3", 10001), "owner_pid": os.getppid()}))
    assert main(["device", "emulate", "--count", "1", "--days", "0.002", "--seconds", "1"]) == 2
    err = capsys.readouterr().err
    assert "is already emulated in session 'default' by process" in err and "--first-id" in err
    assert main(["device", "emulate", "--count", "1", "--days", "0.002", "--seconds", "0.2",
                 "--first-id", "10002"]) == 0


def test_the_shared_temp_registry_is_private_to_its_user(tmp_path, monkeypatch):
    import tempfile
    from stillpoint.drivers.ax import registry
    monkeypatch.delenv("STILLPOINT_RUNTIME_DIR", raising=False)
    monkeypatch.delenv("XDG_RUNTIME_DIR", raising=False)
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    d = registry.runtime_dir()
    assert d == tmp_path / f"stillpoint-{os.getuid()}" and (d.stat().st_mode & 0o777) == 0o700
    d.chmod(0o777)  # as another user could have made it first
    with pytest.raises(registry.RegistryError, match="may be written by other users"):
        registry.runtime_dir()
