"""The AX3/AX6 serial command protocol (usb-protocols.md A3-A7), host side.

``AxClient(port, name)`` wraps an open pyserial port (a real ``/dev/ttyACM*``, a pseudo-terminal or
an ``axemu://`` URL). Framing as OmApi/axconfig: send ``"\\r\\n" + COMMAND + "\\r\\n"``, read CR LF
lines until one starts with the expected prefix (success), one starts with ``ERROR:`` (a typed
``DeviceCommandError``; ``ERROR: Locked.`` is ``DeviceLocked``) or the command's timeout passes
(``DeviceTimeout``); other lines are ignored. After ``ERROR: Locked.`` the setter's ``<KEY>=<old>``
line is read too, so it is never taken as a later reply. The factory/destructive commands listed in
``constants.AX_FORBIDDEN_COMMANDS`` are refused before anything is sent.

Delayed activation: after ``COMMIT`` or ``FORMAT QC``/``WC`` the device ejects its drive,
rewrites it and re-inserts it. The client waits for the bare ``COMMIT`` line (a ``...: Delayed
activation.`` line also starts with ``COMMIT`` and must not end the wait) and then for the caller's
``wait_volume()`` to see the drive again; nothing reads the drive meanwhile.
"""

from __future__ import annotations

import datetime as _dt
import re
import time
from dataclasses import dataclass
from typing import Callable, Iterator, Optional

from .. import constants as C
from .errors import (DeviceCommandError, DeviceError, DeviceGone, DeviceLocked, DeviceTimeout,
                     ForbiddenCommand)

_TIME_RE = re.compile(r"(\d+)\D+(\d+)\D+(\d+)\D+(\d+)\D+(\d+)\D+(\d+)(?:\.(\d+))?")


@dataclass(frozen=True)
class Identity:
    """The ``ID`` reply: ``ID=<type>,<hw hex>,<fw>,<device id>,<session id>``."""

    device_type: str  # "AX3" | "AX6"
    hardware: str
    firmware: int
    device_id: int
    session_id: int


@dataclass(frozen=True)
class Battery:
    """``SAMPLE 1``: ``$BATT=<adc>,<mV>,mV,<percent>,<chargeComplete>``."""

    millivolts: int
    percent: int
    charged: bool


def format_time(t: _dt.datetime) -> str:
    """Device date/time argument ``YYYY/MM/DD,hh:mm:ss`` (usb-protocols.md A4)."""
    return t.strftime("%Y/%m/%d,%H:%M:%S")


def display_time(text: str) -> str:
    """A device date/time as a person reads it beside the other times: ISO 8601
    (``2026-11-29T07:23:36``, the device's local clock, no offset); ``0`` is ``at once`` and
    ``-1`` ``never``; text that is not a device time is returned as it is."""
    t = str(text).strip()
    if t == C.AX_DATETIME_ALWAYS:
        return "at once"
    if t == C.AX_DATETIME_NEVER:
        return "never"
    try:
        dt = parse_time(t)
    except ValueError:
        return t
    return t if dt is None else dt.isoformat(timespec="seconds")


# a device date/time as the firmware writes it, inside other text (a recorded line)
_FIRMWARE_TIME_IN_TEXT = re.compile(r"\b\d{4}/\d{2}/\d{2},\d{2}:\d{2}:\d{2}(?:\.\d+)?\b")


def display_times(text: str) -> str:
    """``text`` with every firmware-style date/time in it (``2026/11/29,07:23:36``) given as
    ``display_time`` gives it (ISO 8601): lines a ledger recorded before the station spoke ISO."""
    return _FIRMWARE_TIME_IN_TEXT.sub(lambda m: display_time(m.group(0)), str(text))


def parse_time(text: str) -> Optional[_dt.datetime]:
    """A device date/time (``YYYY/MM/DD,hh:mm:ss[.mmm]``); ``None`` for ``0`` / ``-1``."""
    text = text.strip()
    if text in (C.AX_DATETIME_ALWAYS, C.AX_DATETIME_NEVER) or text.startswith("-"):
        return None
    m = _TIME_RE.search(text)
    if not m:
        raise ValueError(f"not a device time: {text!r}")
    y, mo, d, h, mi, s = (int(x) for x in m.groups()[:6])
    ms = int((m.group(7) or "0")[:3].ljust(3, "0"))
    return _dt.datetime(y if y >= 100 else 2000 + y, mo, d, h, mi, s, ms * 1000)


def check_allowed(command: str) -> None:
    """Refuse the factory/destructive commands (usb-protocols.md A5, last paragraph). The firmware
    matches keywords by prefix, so a word that starts with a forbidden keyword is refused too."""
    up = " ".join(command.strip().upper().split())
    word = up.split(" ")[0] if up else ""
    for bad in C.AX_FORBIDDEN_COMMANDS:
        if " " in bad:  # a phrase ("FORMAT D") or a keyword with an argument ("DEVICE ")
            hit = up.startswith(bad)
        else:
            hit = word.startswith(bad)
        if hit:
            raise ForbiddenCommand("-", f"the command {command!r} is never sent by stillpoint "
                                        "(factory or destructive)")


class AxClient:
    """Commands to one AX3/AX6 over an open serial port (see module docstring)."""

    def __init__(self, port, name: str = "?", *, timeout_s: float = C.AX_TIMEOUT_S):
        self.port = port
        self.name = name
        self.timeout_s = timeout_s
        self._buf = b""
        self.log: list[str] = []  # every line sent and received (for diagnostics)
        try:
            self.port.timeout = 0.05
        except Exception:  # pragma: no cover - some ports have a fixed timeout
            pass

    @classmethod
    def open(cls, url: str, name: Optional[str] = None) -> "AxClient":
        import serial
        from . import emulator_url  # noqa: F401  registers the axemu:// scheme
        try:
            port = serial.serial_for_url(url, baudrate=9600, timeout=0.05)
        except (serial.SerialException, OSError, ValueError) as e:
            raise DeviceGone(name or url, f"cannot open the serial port {url}: {e}") from None
        return cls(port, name or url)

    def close(self) -> None:
        try:
            self.port.close()
        except Exception:
            pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # ------------------------------------------------------------------ framing
    def _write(self, data: bytes) -> None:
        try:
            self.port.write(data)
            self.port.flush()
        except Exception as e:  # serial.SerialException, OSError
            raise DeviceGone(self.name, f"serial write failed (unplugged?): {e}") from None

    def _readline(self, deadline: float) -> Optional[str]:
        while True:
            i = self._buf.find(b"\n")
            j = self._buf.find(b"\r")
            cut = min(x for x in (i, j, len(self._buf) + 1) if x >= 0)
            if cut <= len(self._buf) - 1:
                line, self._buf = self._buf[:cut], self._buf[cut + 1:]
                if line:
                    return line.decode("ascii", "replace")
                continue
            if time.monotonic() >= deadline:
                return None
            try:
                n = max(1, getattr(self.port, "in_waiting", 0) or 0)
                data = self.port.read(n)
            except Exception as e:
                raise DeviceGone(self.name, f"serial read failed (unplugged?): {e}") from None
            if data:
                self._buf += data

    def drain(self, quiet_s: float = 0.2, limit_s: float = 5.0) -> int:
        """Read and drop input until ``quiet_s`` of silence (at most ``limit_s``); returns the
        number of lines dropped."""
        n = 0
        end = time.monotonic() + limit_s
        while time.monotonic() < end:
            if self._readline(time.monotonic() + quiet_s) is None:
                return n
            n += 1
        return n

    def command(self, cmd: str, expect: str, timeout_s: Optional[float] = None,
                until: Optional[Callable[[str], bool]] = None) -> str:
        """Send ``cmd``; return the first line starting with ``expect`` (or, with ``until``, the
        first line for which ``until(line)`` is true)."""
        check_allowed(cmd)
        self._write(b"\r\n" + cmd.encode("ascii") + b"\r\n")
        self.log.append("> " + cmd)
        deadline = time.monotonic() + (timeout_s or self.timeout_s)
        while True:
            line = self._readline(deadline)
            if line is None:
                raise DeviceTimeout(self.name, f"no reply to {cmd!r} within "
                                               f"{timeout_s or self.timeout_s:g} s")
            self.log.append("< " + line)
            if line.startswith("ERROR:"):
                if "Locked" in line:
                    self._drop_locked_echo(expect)
                    raise DeviceLocked(self.name, cmd, line)
                raise DeviceCommandError(self.name, cmd, line)
            if (until(line) if until else line.upper().startswith(expect.upper())):
                return line

    def _drop_locked_echo(self, expect: str) -> None:
        """After ``ERROR: Locked.`` a setter prints its unchanged value (``<KEY>=<old>``,
        conformance spec §1, HIBERNATE row); read it now so that a later command with the same
        prefix never takes it as its reply. Any other line is put back."""
        line = self._readline(time.monotonic() + C.AX_LOCKED_ECHO_S)
        if line is None:
            return
        self.log.append("< " + line)
        if not (expect and line.upper().startswith(expect.upper())):
            self._buf = line.encode("ascii", "replace") + b"\r\n" + self._buf

    def _value(self, cmd: str, key: str, timeout_s: Optional[float] = None) -> str:
        line = self.command(cmd, key + "=", timeout_s)
        return line.split("=", 1)[1]

    # ------------------------------------------------------------------ reads
    def identify(self) -> Identity:
        v = self._value("ID", "ID").split(",")
        if len(v) < 5:
            raise DeviceError(self.name, f"ID reply has {len(v)} fields, expected 5: {v}")
        kind = C.AX_ID_TYPES.get(v[0].strip())
        if kind is None:
            raise DeviceError(self.name, f"ID reply names an unknown device type {v[0]!r}")
        try:
            return Identity(kind, v[1].strip(), int(v[2]), int(v[3]), int(v[4]))
        except ValueError:
            raise DeviceError(self.name, f"ID reply is not numeric: {','.join(v)}") from None

    def time(self) -> _dt.datetime:
        line = self.command("TIME", "$TIME=")
        t = parse_time(line.split("=", 1)[1])
        if t is None:
            raise DeviceError(self.name, f"device clock is not set ({line})")
        return t

    def sample_time(self) -> _dt.datetime:
        """``SAMPLE 4``: the clock with milliseconds."""
        t = parse_time(self._value("SAMPLE 4", "$TIME"))
        if t is None:
            raise DeviceError(self.name, "device clock is not set")
        return t

    def battery(self) -> Battery:
        """``SAMPLE 1``; a device that reports 0 % (older firmware does not compute it) gets the
        percentage OmApi models from the raw ADC (``constants.ax_battery_pct_from_adc``)."""
        v = self._value("SAMPLE 1", "$BATT").split(",")
        try:
            pct = int(v[3])
            if pct == 0:
                pct = C.ax_battery_pct_from_adc(int(v[0]))
            return Battery(int(v[1]), pct, v[4].strip() == "1")
        except (IndexError, ValueError):
            raise DeviceError(self.name, f"cannot parse the battery reply {v}") from None

    def temperature_c(self) -> float:
        v = self._value("SAMPLE 3", "$TEMP").split(",")
        return int(v[1]) / 10.0

    def session(self, value: Optional[int] = None) -> int:
        cmd = "SESSION" if value is None else f"SESSION {int(value)}"
        return int(self._value(cmd, "SESSION"))

    def rate(self, code: Optional[int] = None, gyro_dps: Optional[int] = None) -> tuple:
        """``RATE``: returns (code, Hz, gyro dps or None)."""
        if code is None:
            cmd = "RATE"
        else:
            cmd = f"RATE {int(code)}" + (f",{int(gyro_dps)}" if gyro_dps else "")
        v = self._value(cmd, "RATE").split(",")
        gyro = int(v[2]) if len(v) > 2 and int(v[2]) else None
        return int(v[0]), int(v[1]), gyro

    def hibernate(self, value: Optional[str] = None) -> str:
        return self._value("HIBERNATE" if value is None else f"HIBERNATE {value}", "HIBERNATE")

    def stop(self, value: Optional[str] = None) -> str:
        return self._value("STOP" if value is None else f"STOP {value}", "STOP")

    def maxsamples(self, value: Optional[int] = None) -> int:
        return int(self._value("MAXSAMPLES" if value is None else f"MAXSAMPLES {value}", "MAXSAMPLES"))

    def debug(self, value: Optional[int] = None) -> int:
        return int(self._value("DEBUG" if value is None else f"DEBUG {value}", "DEBUG"))

    def annotate(self, slot: int, text: Optional[str] = None) -> str:
        key = f"ANNOTATE{slot:02d}"
        return self._value(key if text is None else f"{key}={text}", key)

    def led(self, n: int) -> int:
        return int(self._value(f"LED {int(n)}", "LED"))

    def status(self) -> list[str]:
        """``STATUS`` lines, ended by the ``ECHO=`` sentinel (axconfig's trick)."""
        check_allowed("STATUS")
        self._write(b"\r\nSTATUS\r\nECHO\r\n")
        out: list[str] = []
        deadline = time.monotonic() + self.timeout_s
        while True:
            line = self._readline(deadline)
            if line is None:
                raise DeviceTimeout(self.name, "no end to the STATUS reply")
            if line.startswith("ECHO="):
                return out
            out.append(line)

    def event_log(self) -> list[str]:
        """``LOG``: the device's event log lines (up to ``OK``)."""
        self._write(b"\r\nLOG\r\n")
        out: list[str] = []
        deadline = time.monotonic() + self.timeout_s
        while True:
            line = self._readline(deadline)
            if line is None:
                raise DeviceTimeout(self.name, "no end to the LOG reply")
            if line == "OK":
                return out
            if line.startswith("LOG,"):
                out.append(line)

    # ------------------------------------------------------------------ writes
    def set_time(self, t: _dt.datetime) -> _dt.datetime:
        line = self.command(f"TIME {format_time(t)}", "$TIME=")
        got = parse_time(line.split("=", 1)[1])
        if got is None:
            raise DeviceError(self.name, f"time was not set ({line})")
        return got

    def _delayed(self, cmd: str, timeout_s: float, wait_volume: Optional[Callable[[], None]]) -> None:
        self.command(cmd, "COMMIT", timeout_s, until=lambda line: line.strip() == "COMMIT")
        if wait_volume is not None:
            wait_volume()

    def commit(self, wait_volume: Optional[Callable[[], None]] = None) -> None:
        """Write the settings into the data file header; waits for the bare ``COMMIT`` and the
        drive's return."""
        self._delayed("COMMIT", C.AX_TIMEOUT_COMMIT_S, wait_volume)

    def erase(self, level: str = "quick", wait_volume: Optional[Callable[[], None]] = None) -> None:
        """``FORMAT QC`` (``level="quick"``) or ``FORMAT WC`` (``"wipe"``): the filesystem, label
        and every file rebuilt, the data file re-created from the settings in RAM. Waits for
        ``FORMAT: Complete.`` and the bare ``COMMIT`` (the firmware prints them in that order; an
        ``ERROR: Problem during ... format`` line is a ``DeviceCommandError``), then for the
        drive's return. Call only through the station's clear rule (engine.station.clearing)."""
        if level not in C.AX_ERASE_COMMANDS:
            raise ValueError(f"erase level must be one of {', '.join(C.AX_ERASE_COMMANDS)}, not {level!r}")
        seen = set()

        def done(line: str) -> bool:
            text = line.strip()
            if text == C.AX_FORMAT_COMPLETE:
                seen.add("complete")
            elif text == "COMMIT":
                seen.add("commit")
            return seen == {"complete", "commit"}

        self.command(C.AX_ERASE_COMMANDS[level], "", C.AX_TIMEOUT_FORMAT_WIPE_S if level == "wipe"
                     else C.AX_TIMEOUT_COMMIT_S, until=done)
        if wait_volume is not None:
            wait_volume()

    # ------------------------------------------------------------------ stream preview
    def stream_start(self) -> None:
        check_allowed("STREAM")
        self._write(b"\r\nSTREAM\r\n")

    def stream_lines(self, seconds: float) -> Iterator[tuple[float, list[int]]]:
        """Yield (host receive time, values) for each preview line during ``seconds``."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            line = self._readline(min(end, time.monotonic() + 0.5))
            if line is None:
                continue
            try:
                vals = [int(x) for x in line.split(",")]
            except ValueError:
                continue
            if len(vals) in (3, 6):
                yield time.time(), vals

    def stream_stop(self) -> None:
        """Any CR-terminated line stops the stream; then drop what was in flight."""
        self._write(b"\r\n")
        self.drain(quiet_s=0.15, limit_s=C.AX_STREAM_STOP_S)
