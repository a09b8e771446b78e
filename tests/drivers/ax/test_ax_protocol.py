"""The AX3/AX6 serial protocol client against the emulator (axemu:// URL) and fake ports."""

from __future__ import annotations

import datetime as dt
import time

import pytest

from stillpoint.drivers.ax.errors import (DeviceCommandError, DeviceGone, DeviceLocked,
                                          DeviceTimeout, ForbiddenCommand)
from stillpoint.drivers.ax.protocol import AxClient, check_allowed, format_time, parse_time

from station_fixtures import emu, runtime  # noqa: F401


class SilentPort:
    """A port that records writes and never answers."""

    def __init__(self):
        self.written = b""
        self.timeout = 0.01

    def write(self, b):
        self.written += b

    def flush(self):
        pass

    def read(self, n):
        return b""


def test_time_format_roundtrip():
    t = dt.datetime(2026, 2, 28, 23, 59, 7)
    assert format_time(t) == "2026/02/28,23:59:07"
    assert parse_time("2026/02/28,23:59:07.250") == t.replace(microsecond=250000)
    assert parse_time("26-2-28 23:59:07") == t  # any separators, 2-digit year
    assert parse_time("0") is None and parse_time("-1") is None


def test_identify_and_settings(emu):
    d = emu(12345)
    with AxClient.open(f"axemu://{d.serial}") as c:
        ident = c.identify()
        assert (ident.device_type, ident.device_id, ident.session_id, ident.firmware) == ("AX3", 12345, 1, 50)
        assert c.rate() == (74, 100, None)
        assert c.session(7) == 7 and c.session() == 7
        assert c.annotate(3, "study=abc").rstrip() == "study=abc"
        assert c.hibernate("2030/01/02,03:04:05") == "2030/01/02,03:04:05"
        assert c.stop("-1") == "-1"
        b = c.battery()
        assert 0 <= b.percent <= 100 and b.millivolts > 3000
        assert abs((c.time() - d.device_now()).total_seconds()) < 2
        assert c.status()[0].startswith("TEST=")


def test_ax6_rate_gyro(emu):
    d = emu(20001, "AX6")
    with AxClient.open(f"axemu://{d.serial}") as c:
        assert c.identify().device_type == "AX6"
        assert c.rate(74, 500) == (74, 100, 500)
        assert c.rate(74) == (74, 100, None)  # omitting the gyro range switches the gyro off


def test_error_replies_are_typed(emu):
    d = emu(12345, faults=("locked",))
    with AxClient.open(f"axemu://{d.serial}") as c:
        with pytest.raises(DeviceCommandError, match="Unknown command"):
            c.command("BOGUS", "BOGUS")
        with pytest.raises(DeviceLocked):
            c.session(9)
        assert c.session() == 1  # reads still work on a locked device


def test_timeout_is_typed_and_bounded():
    c = AxClient(SilentPort(), "fake", timeout_s=0.2)
    with pytest.raises(DeviceTimeout, match="no reply to 'ID' within 0.2 s"):
        c.identify()


@pytest.mark.parametrize("cmd", ["WRITEL 3", "readraw 1", "FORMAT D", "DEVICE 123", "RESET",
                                 "CLEAR ALL", "LOCK 1234", "exit", "LOGFILE"])
def test_destructive_commands_never_sent(cmd):
    port = SilentPort()
    c = AxClient(port, "fake", timeout_s=0.05)
    with pytest.raises(ForbiddenCommand):
        c.command(cmd, "X")
    assert port.written == b""


def test_allowed_commands_pass_the_check():
    for cmd in ("ID", "LOG", "LED 5", "CLEAR DATA", "FORMAT QC", "SESSION 3", "DEVICE"):
        check_allowed(cmd)


def test_commit_waits_for_bare_commit_and_the_drive(emu):
    d = emu(12345, remount_s=0.3)
    seen = []

    def wait_volume():
        seen.append(c.log[-1])
        end = time.monotonic() + 5  # the firmware prints COMMIT, then re-presents the drive
        while not d.data_file.exists() and time.monotonic() < end:
            time.sleep(0.02)

    with AxClient.open(f"axemu://{d.serial}") as c:
        c.session(42)
        c.commit(wait_volume)
    # the client waited for the drive only after the bare "COMMIT" (not "COMMIT: Delayed
    # activation."), i.e. after the header was rewritten
    assert seen == ["< COMMIT"]
    from stillpoint.drivers.cwa_layout import parse_header
    assert parse_header(d.data_file.read_bytes()[:1024])["session_id"] == 42
    assert any("Delayed activation" in line for line in c.log)


def test_stream_preview_and_stop(emu):
    d = emu(12345, faults=("stream-left-running",))
    with AxClient.open(f"axemu://{d.serial}") as c:
        c.stream_stop()  # a stream left running is stopped before any command
        assert c.identify().device_id == 12345
        c.stream_start()
        lines = list(c.stream_lines(0.4))
        c.stream_stop()
        assert 10 <= len(lines) <= 50  # paced at <= 100 Hz
        assert all(len(v) == 3 for _, v in lines)
        assert abs(lines[-1][1][2] - 256) < 30  # ~1 g on z, AX3 counts


def test_unplugged_port_is_device_gone(emu):
    d = emu(12345)
    c = AxClient.open(f"axemu://{d.serial}")
    d.unplug()
    with pytest.raises(DeviceGone):
        c.identify()
    with pytest.raises(DeviceGone):
        AxClient.open(f"axemu://{d.serial}")


class ScriptedPort:
    """A port that answers each command line with the bytes the script gives for it."""

    def __init__(self, script):
        self.script = script  # command -> reply bytes
        self.written = b""
        self.pending = b""
        self.timeout = 0.01

    def write(self, b):
        self.written += b
        for line in b.split(b"\r\n"):
            cmd = line.decode()
            if cmd in self.script:
                self.pending += self.script[cmd]

    def flush(self):
        pass

    @property
    def in_waiting(self):
        return len(self.pending)

    def read(self, n):
        out, self.pending = self.pending[:n], self.pending[n:]
        return out


def test_locked_setter_echo_is_not_taken_as_a_later_reply():
    """After ``ERROR: Locked.`` the firmware prints the setter's old value; the next command with
    the same prefix must get its own reply, not that line."""
    port = ScriptedPort({"HIBERNATE -1": b"ERROR: Locked.\r\nHIBERNATE=2030/01/01,00:00:00\r\n",
                         "HIBERNATE": b"HIBERNATE=0\r\n"})
    c = AxClient(port, "t")
    with pytest.raises(DeviceLocked):
        c.hibernate("-1")
    assert c.hibernate() == "0"


def test_locked_error_keeps_an_unrelated_line():
    port = ScriptedPort({"STOP -1": b"ERROR: Locked.\r\nRATE=74,100\r\n"})
    c = AxClient(port, "t")
    with pytest.raises(DeviceLocked):
        c.stop("-1")
    assert c._readline(__import__("time").monotonic() + 0.1) == "RATE=74,100"


def test_format_waits_for_complete_then_commit(monkeypatch):
    """The firmware's order: Delayed activation, Complete, COMMIT; the drive is awaited after.
    Either line missing is a timeout (no COMMIT: no data file re-created)."""
    from stillpoint.drivers import constants as C
    port = ScriptedPort({"FORMAT QC": b"FORMAT: Delayed activation.\r\nFORMAT: Complete.\r\nCOMMIT\r\n"})
    waited = []
    AxClient(port, "t").erase("quick", lambda: waited.append(1))
    assert b"\r\nFORMAT QC\r\n" in port.written and waited == [1]
    monkeypatch.setattr(C, "AX_TIMEOUT_COMMIT_S", 0.3)
    for reply in (b"FORMAT: Delayed activation.\r\nFORMAT: Complete.\r\n",
                  b"FORMAT: Delayed activation.\r\nCOMMIT\r\n"):
        c = AxClient(ScriptedPort({"FORMAT QC": reply}), "t")
        with pytest.raises(DeviceTimeout):
            c.erase("quick", lambda: waited.append(2))
    assert waited == [1]
    with pytest.raises(ValueError, match="erase level"):
        c.erase("delete")


def test_format_error_line_is_an_error():
    port = ScriptedPort({"FORMAT QC": b"FORMAT: Delayed activation.\r\n"
                                      b"ERROR: Problem during quick format\r\n"})
    with pytest.raises(DeviceCommandError, match="Problem during quick format"):
        AxClient(port, "t").erase("quick")


@pytest.mark.parametrize("reply, pct", [
    (b"$BATT=697,4083,mV,100,1\r\n", 100),  # the device's own percentage is kept
    (b"$BATT=697,4083,mV,57,0\r\n", 57),
    (b"$BATT=690,4040,mV,0,0\r\n", 82),  # 0 %: modelled from the ADC as OmApi does (678: 150*140>>8)
    (b"$BATT=640,3750,mV,0,0\r\n", 20),  # 628: 375*14>>8
    (b"$BATT=730,4270,mV,0,1\r\n", 100),
    (b"$BATT=600,3500,mV,0,0\r\n", 0),
])
def test_battery_percentage_from_the_adc_when_reported_as_zero(reply, pct):
    assert AxClient(ScriptedPort({"SAMPLE 1": reply}), "t").battery().percent == pct
