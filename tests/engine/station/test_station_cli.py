"""The CLI: `stillpoint devices`, `device ...`, `station`, and one end-to-end run over real
pseudo-terminals with `device emulate` in another process."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time

import pytest

from stillpoint.tools.cli import main

from station_fixtures import STUDY_PROFILE, emu, runtime  # noqa: F401

PROFILE = STUDY_PROFILE + '[metadata]\nstudy = "trial"\n'


def test_devices_json(emu, capsys):
    emu(10001)
    emu(20002, "AX6")
    assert main(["devices", "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert [(r["id"], r["type"], r["session"], r["state"]) for r in rows] == [
        (10001, "AX3", 1, "has data (recording window still open)"),
        (20002, "AX6", 1, "has data (recording window still open)")]
    assert all(abs(r["clock_offset_s"] - 2.5) < 0.5 and r["data_bytes"] > 1024 for r in rows)


def test_devices_none_attached(runtime, capsys):
    assert main(["devices"]) == 0
    assert "no AX3/AX6 device attached" in capsys.readouterr().out


def test_device_download_verify_clear_configure(emu, tmp_path, capsys):
    d = emu(10001)
    out = tmp_path / "out"
    out.mkdir()
    assert main(["device", "clear", "10001", "-o", str(out)]) == 2  # nothing verified yet
    assert "no verified download" in capsys.readouterr().err
    assert d.clears == []
    assert main(["device", "download", "10001", "-o", str(out)]) == 0
    assert (out / "AX3-10001_1.cwa").exists() and (out / "AX3-10001_1.mcap").exists()
    assert main(["device", "verify", "10001", "-o", str(out)]) == 0
    assert "matches the verified copy" in capsys.readouterr().out
    assert main(["device", "clear", "10001", "-o", str(out)]) == 0
    assert len(d.clears) == 1 and d.data_file.stat().st_size == 1024
    prof = tmp_path / "study.toml"
    prof.write_text(PROFILE)
    assert main(["device", "configure", "10001", "--profile", str(prof), "-o", str(out)]) == 0
    o = capsys.readouterr().out
    assert "configured session 2, rate 50 Hz +-4 g" in o
    from stillpoint.drivers.cwa_layout import parse_header
    h = parse_header(d.data_file.read_bytes()[:1024])
    assert (h["session_id"], h["sample_rate_hz"], h["accel_range_g"]) == (2, 50.0, 4)
    assert h["metadata"].get("study") == "trial" or "study=trial" in h["annotation"]


def test_device_errors_are_one_line_exit_2(emu, tmp_path, capsys):
    emu(10001, faults=("change-between-reads",))
    out = tmp_path / "out"
    out.mkdir()
    assert main(["device", "download", "10001", "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "error: device 10001: verification failed" in err and "Traceback" not in err
    assert main(["device", "download", "99", "-o", str(out)]) == 2
    assert "device 99: not attached" in capsys.readouterr().err
    assert main(["device", "download", "10001", "-o", str(tmp_path / "missing")]) == 2
    assert "does not exist" in capsys.readouterr().err


def test_configure_refuses_a_device_with_data_and_low_battery(emu, tmp_path, capsys):
    emu(10001, battery_pct=5)
    prof = tmp_path / "study.toml"
    prof.write_text(PROFILE)
    assert main(["device", "configure", "10001", "--profile", str(prof)]) == 2
    assert "battery 5 % is below the profile's minimum 10 %" in capsys.readouterr().err
    prof.write_text(PROFILE.replace("min_battery_pct = 10", "min_battery_pct = 0"))
    assert main(["device", "configure", "10001", "--profile", str(prof)]) == 2
    assert "still holds data" in capsys.readouterr().err


def test_sync_time_and_stream(emu, tmp_path, capsys):
    d = emu(10001, clock_offset_s=-30.0)
    assert main(["device", "sync-time", "10001"]) == 0
    assert "-30." in capsys.readouterr().out
    assert abs((d.device_now() - __import__("datetime").datetime.now()).total_seconds()) < 1.5
    live = tmp_path / "live.mcap"
    assert main(["device", "stream", "10001", "-o", str(live), "--seconds", "0.5"]) == 0
    assert "preview only" in capsys.readouterr().out
    assert not d.streaming  # stopped before the port closed
    from mcap.reader import make_reader
    with open(live, "rb") as f:
        r = make_reader(f)
        msgs = [json.loads(m.data) for _, _, m in r.iter_messages(topics=["/preview/accel"])]
        meta = {m.name: m.metadata for m in r.iter_metadata()}
    assert 10 <= len(msgs) <= 60 and "not analysis data" in meta["preview"]["kind"]
    assert abs(msgs[-1]["g"][2] - 1.0) < 0.1


def test_station_refuses_second_instance(emu, tmp_path, capsys):
    from stillpoint.engine.station.ledger import acquire_station_lock
    out = tmp_path / "out"
    out.mkdir()
    fd = acquire_station_lock(out)
    try:
        assert main(["station", str(out), "--once"]) == 2
        assert "another station is already using this folder" in capsys.readouterr().err
    finally:
        os.close(fd)


def test_emulate_bad_fault_name(runtime, capsys):
    assert main(["device", "emulate", "--count", "1", "--faults", "gremlins"]) == 2
    assert "unknown fault 'gremlins'" in capsys.readouterr().err


def test_end_to_end_emulate_and_station_over_pty(tmp_path, runtime):
    """`device emulate` in one process (pseudo-terminal ports), `devices` and `station` in
    others find it with no flags; one device with a fault ends in ERROR, the other is downloaded,
    verified, cleared and configured."""
    env = dict(os.environ, STILLPOINT_RUNTIME_DIR=str(runtime))
    emu_p = subprocess.Popen([sys.executable, "-m", "stillpoint.tools", "device", "emulate", "--count", "2",
                              "--days", "0.02", "--faults", "io-error:2", "--seconds", "60",
                              "--dir", str(tmp_path / "emu")],
                             stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    try:
        line = ""
        end = time.monotonic() + 40
        while time.monotonic() < end and "attached" not in line:
            line = emu_p.stdout.readline()
        assert "2 emulated device(s) attached" in line
        r = subprocess.run([sys.executable, "-m", "stillpoint.tools", "devices", "--json"], env=env,
                           capture_output=True, text=True, timeout=60)
        rows = json.loads(r.stdout)
        assert [x["id"] for x in rows] == [10001, 10002]
        assert all(x["port"].startswith("/dev/") for x in rows)  # real pseudo-terminals
        prof = tmp_path / "study.toml"
        prof.write_text(PROFILE)
        out = tmp_path / "out"
        out.mkdir()
        r = subprocess.run([sys.executable, "-m", "stillpoint.tools", "station", str(out), "--profile",
                            str(prof), "--clear-after-verify", "--configure-after", "--once"],
                           env=env, capture_output=True, text=True, timeout=120)
        assert r.returncode == 2, r.stdout + r.stderr
        assert "Traceback" not in r.stderr
        assert "10001 [emu-1] configured: session 2" in r.stdout
        assert "10002 [emu-2] error: reading" in r.stdout and "Input/output error" in r.stdout
        assert (out / "AX3-10001_1.cwa").exists() and (out / "AX3-10001_1.mcap").exists()
        assert (out / "AX3-10002_1.cwa.part").exists() and not (out / "AX3-10002_1.cwa").exists()
    finally:
        emu_p.terminate()
        emu_p.wait(10)


def test_live_table_on_a_terminal(emu, tmp_path, capsys, monkeypatch):
    import io
    monkeypatch.setenv("COLUMNS", "400")  # a wide terminal: each line whole
    from stillpoint.drivers.ax.discovery import EmulatedBackend
    from stillpoint.engine.station.flow import StationOptions
    from stillpoint.engine.station.station import Station
    emu(10001)
    emu(10002, faults=("io-error",))
    out = tmp_path / "out"
    out.mkdir()
    buf = io.StringIO()
    with Station(StationOptions(str(out), inline=True), EmulatedBackend(), tty=True, out=buf,
                 poll_s=0.05) as st:
        assert st.run(once=True) == 2
    text = buf.getvalue()
    assert "\x1b[2K" in text and "\x1b[" in text  # redrawn in place
    last = text.split("\x1b[2K")[-3:]
    assert "verified" in last[1] and "[####################]" in last[1]
    assert "outputs: tables written, report written" in last[1]
    assert "error" in last[2] and "Input/output error" in last[2]
    assert main(["devices", "--ledger", str(out), "--json"]) == 0
    rows = {r["id"]: r["state"] for r in json.loads(capsys.readouterr().out)}
    assert rows[10001] == "verified"
    assert rows[10002].startswith("has data (last download failed: reading")


def test_clean_lists_and_removes_only_superseded_partial_files(emu, tmp_path, capsys):
    emu(10001)
    out = tmp_path / "out"
    out.mkdir()
    assert main(["device", "download", "10001", "-o", str(out)]) == 0
    copy = (out / "AX3-10001_1.cwa").read_bytes()
    stamp = "20260101T000000Z"
    plant = {f"AX3-10001_1.cwa.part.{stamp}": copy[:4096],  # a prefix: superseded
             f"AX3-10001_1.cwa.part.{stamp}-1": b"MD" + b"\x07" * 4094,  # other bytes: kept
             f"AX3-10001_1.unverified.mcap.part.{stamp}": b"x",  # a derived log: superseded
             f"AX3-99_1.cwa.part.{stamp}": copy[:512]}  # no verified copy: kept
    for n, b in plant.items():
        (out / n).write_bytes(b)
    capsys.readouterr()
    assert main(["clean", str(out)]) == 0
    text = capsys.readouterr().out
    assert "2 superseded, 2 kept; nothing removed" in text
    assert all((out / n).exists() for n in plant)
    (out / "AX3-10001_1.cwa").write_bytes(copy[:-512])  # the verified copy damaged: nothing goes
    assert main(["clean", str(out), "--delete"]) == 0
    assert "0 file(s) removed" in capsys.readouterr().out and all((out / n).exists() for n in plant)
    (out / "AX3-10001_1.cwa").write_bytes(copy)
    assert main(["clean", str(out), "--delete"]) == 0
    assert "2 file(s) removed" in capsys.readouterr().out
    assert sorted(n for n in plant if (out / n).exists()) == [f"AX3-10001_1.cwa.part.{stamp}-1",
                                                               f"AX3-99_1.cwa.part.{stamp}"]
    assert main(["clean", str(tmp_path)]) == 2  # no ledger there: one line, nothing removed
    assert "no station ledger" in capsys.readouterr().err


def test_clean_knows_the_raw_copy_of_an_inbox_log(tmp_path, capsys):
    """A set-aside log of an inbox recording is superseded by its verified .bin (the raw copy the
    ledger names for that log), not looked for as a .cwa."""
    from stillpoint.engine.sim.record import simulate_recording
    from stillpoint.engine.station.inbox import Inbox
    from stillpoint.engine.station.ledger import Ledger
    inbox, out = tmp_path / "inbox", tmp_path / "out"
    inbox.mkdir()
    out.mkdir()
    simulate_recording(inbox / "p01.bin", device="geneactiv", days=0.01, truth_path=False)
    lg = Ledger(out)
    assert Inbox(inbox, out, stable_s=0.0, ledger=lg).ingest(inbox / "p01.bin").startswith("ingested")
    log = os.path.basename(lg.downloads()[0].mcap_path)
    lg.close()
    planted = log[: -len(".mcap")] + ".unverified.mcap.part.20260101T000000Z"
    (out / planted).write_bytes(b"x")
    capsys.readouterr()
    assert main(["clean", str(out)]) == 0
    assert f"superseded {planted}  (by {log})" in capsys.readouterr().out


@pytest.fixture
def same_id_pair(emu, tmp_path):
    """An emulated AX3 and AX6 that share id 10001 and session 1, and an empty output folder."""
    from stillpoint.drivers.ax.emulator import EmulatedDevice
    from stillpoint.engine.sim.record import device_recording
    a = emu(10001)
    b = EmulatedDevice(tmp_path / "ax6", 10001, "AX6", make_recording=device_recording, days=0.01, remount_s=0.05, slot="emu-2")
    try:
        b.plug()
        out = tmp_path / "out"
        out.mkdir()
        yield a, b, out
    finally:
        b.shutdown()


def test_an_ax3_and_an_ax6_with_the_same_id_and_session_both_download(same_id_pair, capsys):
    a, b, out = same_id_pair
    assert main(["station", str(out), "--once", "--clear-after-verify", "--plain"]) == 0, \
        capsys.readouterr()
    assert (out / "AX3-10001_1.cwa").read_bytes() != (out / "AX6-10001_1.cwa").read_bytes()
    assert len(a.clears) == 1 and len(b.clears) == 1


def test_device_commands_refuse_an_id_two_devices_share(same_id_pair, capsys):
    """An AX3 and an AX6 with the same id: `device verify 10001` names both and asks for the USB
    serial; the serial picks one."""
    a, b, out = same_id_pair
    capsys.readouterr()
    assert main(["device", "download", "10001", "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"2 attached devices have this id (AX3 {a.serial}, AX6 {b.serial})" in err
    assert main(["device", "download", b.serial, "-o", str(out)]) == 0
    assert (out / "AX6-10001_1.cwa").exists() and not (out / "AX3-10001_1.cwa").exists()
