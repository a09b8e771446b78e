"""The emulator behaves as the AX3/AX6 firmware does beyond single replies: a session past 2^32,
invalid dates as stored in the header, FORMAT's order and what it removes, the header layout of
each firmware, the settings a device boots with, and a second run on the same folder.

Sources (digitalinteraction/openmovement, commit 144ef13): Firmware/AX3/Firmware/src/Settings.c
(``S3``), Logger.c (``L3``), main.c (``M3``), Firmware/AX6/Firmware/src/Logger.c (``L6``),
Firmware/Flux.AX3/src/Peripherals/Rtc.c (``R``), Firmware/AX3/Firmware/src/usb_descriptors.c.
"""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from stillpoint.drivers import constants as C
from stillpoint.drivers.ax.emulator import EmulatedDevice
from stillpoint.engine.sim.record import device_recording
from stillpoint.drivers.ax.protocol import AxClient
from stillpoint.drivers.cwa_layout import SECTOR_DTYPE, parse_header
from stillpoint.tools.cli import main

from station_fixtures import emu, runtime  # noqa: F401


def _wait_drive(d, timeout_s: float = 5.0):
    def w():
        end = time.monotonic() + timeout_s
        while not (d.volume.is_dir() and d.mounted):
            assert time.monotonic() < end, f"the drive did not come back: {d.events}"
            time.sleep(0.02)
    return w


def _say(d, text: str, end: str = "\r\n", timeout_s: float = 10.0) -> str:
    """Type ``text`` + CR on the device's port; the reply, read until it ends with ``end`` and
    then the port stays quiet for 0.2 s (``timeout_s`` at most)."""
    d.host_read(1 << 20, 0)
    d.host_write(text.encode("latin-1") + b"\r")
    got = ""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            chunk = d.host_read(1 << 20, 0.2).decode("latin-1")
        except OSError:  # the device went away (RESET)
            return got
        got += chunk
        if not chunk and got.endswith(end):
            return got
    return got


def _header(d) -> dict:
    return parse_header(d.data_file.read_bytes()[:1024])


def test_a_session_past_2_32_wraps_and_commit_and_format_still_complete(emu):
    """S3 722-730 with my_atoi's 32-bit wrap (Flux.AX3/src/Utils/Util.c 106-116): the session
    is an unsigned long, so 4294967296 is 0 and every later COMMIT/FORMAT completes."""
    d = emu(12345)
    died = []
    old_hook = threading.excepthook
    threading.excepthook = lambda a: died.append(a.exc_value)
    try:
        with AxClient.open(f"axemu://{d.serial}") as c:
            assert c.session(4294967296) == 0
            c.commit(_wait_drive(d))
        assert _header(d)["session_id"] == 0
        assert _say(d, "SESSION 4294967297") == "SESSION=1\r\n"
        assert _say(d, "FORMAT QC", end="COMMIT\r\n").endswith("FORMAT: Complete.\r\nCOMMIT\r\n")
        _wait_drive(d)()
        assert _header(d)["session_id"] == 1 and d.data_file.stat().st_size == 1024
    finally:
        threading.excepthook = old_hook
    assert died == []


def test_invalid_dates_are_stored_as_the_firmware_stores_them(emu):
    """R 413-469: an unparseable or invalid date is 0; in the header, start 0 = record at once,
    stop 0 = never record (L3 450-451 write the values unchanged)."""
    d = emu(12345)
    with AxClient.open(f"axemu://{d.serial}") as c:
        assert c.hibernate("garbage") == "0"
        assert c.stop("2024/02/30,10:00:00") == "0"
        c.commit(_wait_drive(d))
    h = _header(d)
    assert (h["logging_start_raw"], h["logging_end_raw"]) == (0, 0)
    with AxClient.open(f"axemu://{d.serial}") as c:
        assert c.stop("2023/02/29,12:00:00") == "2023/03/01,12:00:00"  # R 462
        c.commit(_wait_drive(d))
    assert _header(d)["logging_end"] == "2023-03-01T12:00:00Z"


def test_format_prints_complete_before_commit_and_removes_every_file(emu):
    """S3 1153-1186 and SettingsAction 350-412: FORMAT drops the drive, formats it (every file
    gone), prints FORMAT: Complete., then (with C) writes the data file and prints COMMIT."""
    d = emu(12345)
    (d.volume / "SETTINGS.INI").write_text("DATAMODE=20\r\n")
    (d.volume / "LOG.TXT").write_text("old log\r\n")
    (d.volume / "folder").mkdir()
    (d.volume / "folder" / "notes.txt").write_text("x")
    out = _say(d, "FORMAT QC", end="COMMIT\r\n")
    assert out == "FORMAT: Delayed activation.\r\nFORMAT: Complete.\r\nCOMMIT\r\n"
    _wait_drive(d)()
    assert sorted(p.name for p in d.volume.iterdir()) == [C.AX_DATA_FILE]
    assert d.data_file.stat().st_size == 1024
    out = _say(d, "FORMAT Q", end="Complete.\r\n")
    assert out == "FORMAT: Delayed activation.\r\nFORMAT: Complete.\r\n"  # no C: no COMMIT
    _wait_drive(d)()
    assert list(d.volume.iterdir()) == []  # and no data file


def test_format_rebuilds_the_label_from_the_device_id(emu):
    """S3 352-382: FORMAT writes the label from the id in program memory; DEVICE n (S3 794-804)
    changes that id, the USB serial follows at the next start (usb_descriptors.c 527-557)."""
    d = emu(12345)
    assert _say(d, "DEVICE 54321") == "DEVICE=54321,54321\r\n"
    d.unplug()
    d.plug()
    assert d.serial == "CWA17_54321" and d.label == "AX317_12345"  # the old label stays
    assert _say(d, "FORMAT QC", end="COMMIT\r\n").endswith("FORMAT: Complete.\r\nCOMMIT\r\n")
    _wait_drive(d)()
    assert d.label == "AX317_54321" and d.volume.name == "AX317_54321"
    assert _header(d)["device_id"] == 54321


def test_ax3_v50_header_keeps_the_low_16_bits_of_a_wide_id(emu):
    """L3 444-448: hardware byte 0x00, the id's low word at 5, bytes 11-12 left 0xFF; the ID reply
    and the USB serial carry the whole id (S3 460; usb_descriptors.c 535-546; label S3 371-378)."""
    d = emu(123456, days=0.003)
    raw = d.data_file.read_bytes()[:1024]
    assert raw[4] == 0x00 and raw[5:7] == (123456 & 0xFFFF).to_bytes(2, "little") and raw[11:13] == b"\xff\xff"
    assert parse_header(raw)["device_id"] == 123456 & 0xFFFF
    assert (d.serial, d.label) == ("CWA17_0123456", "AX3_0123456")
    assert _say(d, "ID") == "ID=CWA,17,50,123456,1\r\n"
    _say(d, "COMMIT", end="\nCOMMIT\r\n")
    _wait_drive(d)()
    raw = d.data_file.read_bytes()[:1024]
    assert raw[4] == 0x00 and raw[11:13] == b"\xff\xff" and raw[25] == 0xFF and raw[35] == 0xFF


def test_ax6_header_writes_both_id_words(emu):
    """L6 537-540: hardware byte, low and high id words; the gyro range in byte 35 (L6 547-559)."""
    d = emu(601234, "AX6", days=0.003)
    assert _say(d, "RATE 74,500") == "RATE=74,100,500\r\n"
    _say(d, "COMMIT", end="\nCOMMIT\r\n")
    _wait_drive(d)()
    raw = d.data_file.read_bytes()[:1024]
    h = parse_header(raw)
    assert raw[4] == 0x64 and h["device_id"] == 601234 and raw[11:13] == (601234 >> 16).to_bytes(2, "little")
    assert raw[35] == 4 and h["gyro_range_dps"] == 500.0
    assert (d.serial, d.label) == ("AX664_0601234", "AX6_0601234")


def test_a_ten_digit_id_has_a_ten_digit_serial_and_a_seven_digit_label(emu):
    """usb_descriptors.c 535-540: 10 digits above 9999999; the label keeps 7 (S3 371-378)."""
    d = emu(1234567890, days=0.002)
    assert (d.serial, d.label) == ("CWA17_1234567890", "AX3_4567890")


def test_settings_are_reloaded_from_the_header_at_every_start(emu):
    """M3 221-232 and L3 346-381: at start the RAM settings come from the header, so a setting
    that was never committed is gone after an unplug, and CLEAR DATA (which writes the RAM
    settings into a new file) keeps the old recording window."""
    d = emu(12345)
    with AxClient.open(f"axemu://{d.serial}") as c:
        c.hibernate("2030/01/01,00:00:00")
        c.stop("2030/01/08,00:00:00")
        c.session(42)
        c.commit(_wait_drive(d))
        c.session(7)  # not committed
    d.unplug()
    d.plug()
    assert _say(d, "SESSION") == "SESSION=42\r\n"
    assert _say(d, "CLEAR DATA", end="COMMIT\r\n") == "CLEAR: Delayed activation.\r\nCOMMIT\r\n"
    _wait_drive(d)()
    h = _header(d)
    assert d.data_file.stat().st_size == 1024
    assert (h["session_id"], h["logging_start"], h["logging_end"]) == (42, "2030-01-01T00:00:00Z",
                                                                       "2030-01-08T00:00:00Z")


def test_without_a_data_file_the_session_is_ten_thousand_times_the_id_plus_restarts(emu):
    """S3 246-247: session = 10000 x id + restart count % 10000 when no header overrides it; the
    restart counter counts each start into logging mode (M3 509, i.e. each unplug)."""
    d = emu(12345)
    restarts = int(_say(d, "STATUS 5").split("=")[1])
    assert _say(d, "FORMAT Q", end="Complete.\r\n").endswith("FORMAT: Complete.\r\n")
    _wait_drive(d)()
    d.unplug()
    d.plug()
    assert _say(d, "STATUS 5") == f"RESTART={restarts + 1}\r\n"
    assert _say(d, "SESSION") == f"SESSION={10000 * 12345 + restarts + 1}\r\n"


def test_settings_ini_datamode_20_makes_the_ax3_record_unpacked_until_format(tmp_path, runtime):
    """M3 230: SETTINGS.INI is run at every start; DATAMODE=20 (S3 1105-1121) is unpacked CWA;
    FORMAT removes the file, so the next start is packed again."""
    from stillpoint.drivers.ax.firmware_text import volume_label
    drive = tmp_path / "dev" / "media" / volume_label("AX3", 12345)
    drive.mkdir(parents=True)
    (drive / "SETTINGS.INI").write_text("DATAMODE=20\r\n")
    d = EmulatedDevice(tmp_path / "dev", 12345, make_recording=device_recording, days=0.002, remount_s=0.05)
    try:
        d.plug()
        sectors = np.frombuffer(d.data_file.read_bytes()[1024:1024 + 512 * 4], SECTOR_DTYPE)
        assert set(sectors["num_axes_bps"]) == {0x32}  # 3 axes, 2 bytes each, unpacked
        assert _say(d, "DATAMODE") == "DATAMODE=20,single-file,CWA/unpacked\r\n"
        _say(d, "FORMAT QC", end="COMMIT\r\n")
        _wait_drive(d)()
        d.unplug()
        d.plug()
        assert _say(d, "DATAMODE") == "DATAMODE=18,single-file,CWA/packed\r\n"
    finally:
        d.shutdown()


@pytest.mark.parametrize("how", ["shutdown", "killed"])
def test_the_same_folder_serves_a_second_run(tmp_path, runtime, how):
    """A drive an earlier run left aside (unplugged at shutdown, or a process that died with the
    drive dropped mid-commit) is put back; the device keeps its data."""
    d = EmulatedDevice(tmp_path / "dev", 12345, make_recording=device_recording, days=0.002, remount_s=30.0)
    d.plug()
    before = d.data_file.read_bytes()
    if how == "killed":
        _say(d, "COMMIT", end="activation.\r\n")  # drive dropped; the process "dies" before it returns
        assert not d.volume.exists()
        d._stop.set()
    else:
        d.shutdown()
    again = EmulatedDevice(tmp_path / "dev", 12345, make_recording=device_recording, days=0.002, remount_s=0.05)
    try:
        again.plug()
        assert again.data_file.read_bytes() == before
        assert [p.name for p in (tmp_path / "dev").iterdir() if p.name.startswith(".")] == []
    finally:
        again.shutdown()
    assert [p.name for p in (tmp_path / "dev").iterdir() if p.name.startswith(".")] == []


def test_device_emulate_runs_twice_on_its_default_folder(runtime, capsys):
    """By default each run's drives are removed when it ends; with --keep in one folder, the
    second run uses the first one's drive again and leaves no leftovers."""
    for _ in range(2):
        assert main(["device", "emulate", "--count", "1", "--days", "0.002", "--seconds", "0.3"]) == 0
    assert [p.name for p in (runtime / "sessions" / "default").iterdir()] == ["devices"]
    assert list((runtime / "sessions" / "default" / "devices").iterdir()) == []
    kept = runtime / "kept"
    for _ in range(2):
        assert main(["device", "emulate", "--count", "1", "--days", "0.002", "--seconds", "0.3",
                     "--dir", str(kept), "--keep"]) == 0
    leftovers = [p for p in kept.rglob(".*")]
    assert leftovers == []
    assert (kept / "10001" / "media" / "AX317_10001" / C.AX_DATA_FILE).is_file()


def test_an_initial_lock_keeps_the_drive_away_until_unlock(emu):
    """S3 285-294: an ILOCK code in program memory locks the device at start and keeps its drive
    unmounted; UNLOCK with the code mounts it (S3 1303-1328); LOCK reports 1 + 2 (S3 1272-1276)."""
    d = emu(12345)
    assert _say(d, "ILOCK 1234") == "ILOCK=1\r\n"
    d.unplug()
    d.plug()
    assert not d.volume.exists() and d.locked
    assert _say(d, "LOCK") == "LOCK=3\r\n"
    assert _say(d, "SESSION 9") == "ERROR: Locked.\r\nSESSION=1\r\n"
    assert _say(d, "UNLOCK 1111") == "ERROR: Locked.\r\n"
    assert _say(d, "UNLOCK 1234") == "LOCK=0\r\n"
    assert d.volume.is_dir() and d.data_file.is_file()
    assert _say(d, "LOCK") == "LOCK=2\r\n"


def test_reset_restarts_the_device(emu):
    """S3 1368-1374: RESET, OK, and 1-2 s later the device restarts (the port and drive drop and
    come back); the RAM settings are those of a fresh start."""
    d = emu(12345, replug_s=0.1)
    assert _say(d, "SESSION 77") == "SESSION=77\r\n"
    assert _say(d, "RESET") == "RESET\r\nOK\r\n"
    end = time.monotonic() + 10
    while d.events.count("plugged") < 2:
        assert time.monotonic() < end, d.events
        time.sleep(0.05)
    assert "unplugged" in d.events and d.volume.is_dir()
    assert _say(d, "SESSION") == "SESSION=1\r\n"  # from the header again
