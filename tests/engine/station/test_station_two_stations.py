"""Two stations on one computer (two studies, two output folders) and two emulated devices on
pseudo-terminal ports, one of whose data changes between two reads: started together or one
after the other, each device is held by one station at a time (the other shows it busy), the
changed device is cleared by neither (the verdict is host-wide), the other device is
downloaded, verified, cleared and configured exactly once across both ledgers, and no station
meets a port error."""

from __future__ import annotations

import os
import sqlite3
import subprocess
import sys
import threading

import pytest

from stillpoint.engine.station.flow import StationOptions
from stillpoint.engine.station.hostlock import (DeviceLock, changed_record, device_key,
                                                forget_changed)
from stillpoint.engine.station.station import Station

from station_fixtures import STUDY_PROFILE, emu, runtime  # noqa: F401

CHANGED = 10002


def _rows(out, sql):
    db = sqlite3.connect(out / "stillpoint-ledger.sqlite")
    try:
        return db.execute(sql).fetchall()
    finally:
        db.close()


def _station(out, prof, env):
    return subprocess.Popen([sys.executable, "-m", "stillpoint.tools", "station", str(out),
                             "--profile", str(prof), "--clear-after-verify", "--configure-after",
                             "--once", "--plain"],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


@pytest.mark.parametrize("start", ["together", "one after the other"])
def test_two_stations_share_two_devices(emu, tmp_path, start):
    devs = {i: emu(i, faults=("change-between-reads",) if i == CHANGED else (), pty=True)
            for i in (10001, 10002)}
    held = {i: d.data_file.read_bytes() for i, d in devs.items()}
    prof = tmp_path / "study.toml"
    prof.write_text(STUDY_PROFILE)
    outs = [tmp_path / "study-a", tmp_path / "study-b"]
    for o in outs:
        o.mkdir()
    env = dict(os.environ)
    if start == "together":
        procs = [_station(o, prof, env) for o in outs]
        texts = [p.communicate(timeout=240)[0] for p in procs]
    else:
        texts = [_station(o, prof, env).communicate(timeout=240)[0] for o in outs]
    both = "\n".join(texts)
    assert "Traceback" not in both, both
    assert "no reply" not in both and "port" not in both.lower().replace("report", ""), both

    for i, d in devs.items():
        verified = sum(_rows(o, f"SELECT COUNT(*) FROM downloads WHERE device_id={i} AND "
                                "state='verified'")[0][0] for o in outs)
        cleared = sum(_rows(o, f"SELECT COUNT(*) FROM clears WHERE device_id={i} AND "
                               "result='ok'")[0][0] for o in outs)
        configured = sum(_rows(o, f"SELECT COUNT(*) FROM configurations WHERE device_id={i} "
                                  "AND result='ok'")[0][0] for o in outs)
        if i == CHANGED:  # never cleared, by either station, and never configured over its data
            assert d.clears == [] and cleared == 0 and configured == 0, both
            assert d.data_file.stat().st_size == len(held[i])
            continue
        assert len(d.clears) == 1 and cleared == 1, (i, both)
        assert verified == 1 and configured == 1, (i, verified, configured, both)
        assert d.session_id == 2, (i, d.session_id)  # configured once: 1 -> 2, never 3
        copies = [o / f"AX3-{i}_1.cwa" for o in outs if (o / f"AX3-{i}_1.cwa").exists()]
        assert len(copies) == 1 and copies[0].read_bytes() == held[i]
    # the verdict stays on record for every station of this computer until a person clears it
    rec = changed_record(device_key("AX3", CHANGED, True, str(devs[CHANGED].root)))
    assert rec is not None and rec["session"] == 1
    refusals = [line for line in both.splitlines()
                if f"{CHANGED} [" in line and "not cleared" in line]
    assert refusals, both
    if start == "one after the other":
        # the second station leaves what the first did: the changed verdict, the configurations
        assert "found its data changed between two reads of session 1" in texts[1], texts[1]
        assert "10001 [emu-" in texts[1] and "not configured again" in texts[1], texts[1]


def test_a_held_device_is_busy_until_released(emu, tmp_path):
    """A device whose lock another station holds is shown ``busy`` with that station's folder
    and pid, and untouched; once released the flow goes on by itself."""
    d = emu(10001)
    other = tmp_path / "other-study"
    lock = DeviceLock(device_key("AX3", 10001, True, str(d.root)), other).acquire()
    out = tmp_path / "out"
    out.mkdir()
    seen = []
    st = Station(StationOptions(str(out), clear_after_verify=True, inline=True, products=False),
                 poll_s=0.05, tty=False, out=open(os.devnull, "w"))
    released = threading.Event()

    def listen(flow):
        seen.append((flow.state, flow.reason))
        if flow.state == "busy" and not released.is_set():
            released.set()
            threading.Timer(0.3, lock.release).start()
    st.add_listener(listen)
    try:
        assert st.run(once=True) == 0
    finally:
        st.close()
        lock.release()
    busy = [r for s, r in seen if s == "busy"]
    assert busy and busy[0] == f"held by the station on {other.resolve()} (pid {os.getpid()})"
    states = [s for s, _ in seen]
    assert states.index("busy") < states.index("identifying") < states.index("cleared")
    assert len(d.clears) == 1


def test_device_clear_settles_the_changed_verdict(emu, tmp_path, capsys):
    """The host-wide verdict is settled only by a person's `device clear` (after a verified
    download of the session)."""
    from stillpoint.tools.cli import main
    d = emu(10001, faults=("change-between-reads",))
    out = tmp_path / "out"
    out.mkdir()
    assert main(["device", "download", "10001", "-o", str(out)]) == 2
    key = device_key("AX3", 10001, True, str(d.root))
    assert changed_record(key)["session"] == 1
    out2 = tmp_path / "out2"
    out2.mkdir()
    # another station downloads the (now steady) data but honours the verdict: not cleared
    assert main(["station", str(out2), "--once", "--clear-after-verify", "--plain"]) == 2
    text = capsys.readouterr().out
    assert "not cleared: the station on" in text and "found its data changed" in text
    assert changed_record(key) is not None
    assert main(["device", "clear", "10001", "-o", str(out2)]) == 0
    said = capsys.readouterr().out
    assert "cleared by FORMAT QC" in said and "changed" in said
    assert changed_record(key) is None
    forget_changed(key)  # idempotent


def test_devices_and_device_commands_leave_a_held_device_alone(emu, tmp_path, capsys):
    """`stillpoint devices` lists a device a station holds as busy without asking it anything;
    a `device` command on it stops with one line naming the holder, exit 2."""
    import json

    from stillpoint.tools.cli import main
    d = emu(10001)
    other = tmp_path / "other-study"
    lock = DeviceLock(device_key("AX3", 10001, True, str(d.root)), other).acquire()
    out = tmp_path / "out"
    out.mkdir()
    try:
        assert main(["devices", "--json"]) == 0
        [row] = json.loads(capsys.readouterr().out)
        assert row["state"] == "busy"
        assert row["problem"] == f"held by the station on {other.resolve()} (pid {os.getpid()})"
        assert "firmware" not in row  # its port was not opened
        for args in (["device", "download", "10001", "-o", str(out)],
                     ["device", "clear", "10001", "-o", str(out)],
                     ["device", "sync-time", "10001"]):
            assert main(args) == 2, args
            err = capsys.readouterr().err.strip().splitlines()
            assert "busy: held by the station on" in err[-1], (args, err)
            assert "Traceback" not in "\n".join(err)
    finally:
        lock.release()
    assert d.clears == [] and not (out / "AX3-10001_1.cwa").exists()
    assert main(["devices", "--json"]) == 0
    [row] = json.loads(capsys.readouterr().out)
    assert row["state"] != "busy" and "firmware" in row


def test_device_keys():
    """A real device is known by type and id on the whole computer; an emulated one also by its
    emulator session and folder, so a fresh emulator run's devices (the same ids) inherit no
    verdict of the last run's."""
    assert device_key("AX3", 10001) == "AX3-10001"
    assert device_key("AX6", 10001) != device_key("AX3", 10001)
    a = device_key("AX3", 10001, True, "/tmp/run-a/10001")
    assert a.startswith("emulated.") and a.endswith(".AX3-10001")
    assert a != device_key("AX3", 10001, True, "/tmp/run-b/10001")
