"""A firmware-faithful AX3/AX6 in pure Python, so the station runs (and is tested) without hardware.

``EmulatedDevice(root, device_id, kind="AX3", ...)`` has

* a drive: the folder ``<root>/media/<label>`` (label ``AX317_<id>`` / ``AX664_<id>``) holding a
  ``CWA-DATA.CWA`` written by the project's simulator (engine/sim) with the device's id and
  session; ``COMMIT``/``CLEAR DATA``/``FORMAT QC`` eject the drive (the folder moves away), write
  it, and re-insert it after ``remount_s`` (delayed activation, usb-protocols.md A5);
* the serial command set of usb-protocols.md A5 (case-insensitive prefix keywords, CR-terminated
  input, LF ignored, 127 characters kept, CR LF output, ``ERROR:`` lines), a drifting real-time
  clock (``clock_ppm``), a charging battery, ``STREAM`` paced at 100 Hz and stopped by any line;
* a serial port: in-process through the ``axemu://<serial>`` pyserial URL (``emulator_url``), or a
  pseudo-terminal (``serve_pty()``) that any program opens as a real serial port;
* a registry entry (``registry``) so discovery in any process finds it while it is plugged in.

Faults (kebab-case names, ``FAULTS``) make it misbehave the way a real device or cable can. Those
that concern reading the drive (``unplug-mid-copy``, ``short-read``, ``io-error``, ``hang``,
``bit-flip``, ``change-between-reads``) are applied by the emulated volume's file layer
(``volume.open_data_file``), which signals the device through ``<root>/control/``; the rest are
applied here.
"""

from __future__ import annotations

import datetime as _dt
import os
import shutil
import threading
import time
from pathlib import Path
from typing import Optional

import numpy as np

from .. import constants as C
from ..cwa_layout import TS_ALWAYS, TS_NEVER, build_header, pack_timestamp
from . import registry

FAULTS = {
    "unplug-mid-copy": "the cable is pulled while the data file is being copied (re-plugged after a few s)",
    "short-read": "the data file read ends early (fewer bytes than its size)",
    "io-error": "an I/O error at an offset in the data file",
    "hang": "a read of the data file never returns",
    "bit-flip": "one bit of the data differs in the first read",
    "change-between-reads": "the data file changes between the copy and the verification read",
    "swap-before-clear": "another device takes the slot between verification and clear",
    "id-mismatch": "the ID reply names a different device id than the USB serial",
    "session-mismatch": "the SESSION reply differs from the data file's session",
    "commit-no-remount": "after COMMIT/CLEAR the drive never comes back",
    "no-automount": "after COMMIT/CLEAR/FORMAT the drive comes back present but not mounted (a "
                    "headless host): the host must mount it",
    "locked": "settings are locked (ERROR: Locked.)",
    "stream-left-running": "the device is streaming its preview when the host opens the port",
}
READ_FAULTS = ("unplug-mid-copy", "short-read", "io-error", "hang", "bit-flip", "change-between-reads")

EMULATORS: dict[str, "EmulatedDevice"] = {}  # serial -> device, for the axemu:// URL handler
_HW = {"AX3": ("CWA", "17", 50, 0x17), "AX6": ("AX6", "64", 56, 0x64)}  # [USB] A1/A5 examples


def serial_number(kind: str, device_id: int) -> str:
    """USB serial: ``CWA17_<id>`` (AX3) / ``AX664_<id>`` (AX6), 5 digits up to 99999."""
    prefix = "CWA17_" if kind == "AX3" else "AX664_"
    return prefix + (f"{device_id:05d}" if device_id <= 99999 else f"{device_id:07d}")


def volume_label(kind: str, device_id: int) -> str:
    """MSD label ``AX317_<5 digits>`` (``AX3_<7 digits>`` for longer ids) [USB] A1."""
    if kind == "AX3":
        return f"AX317_{device_id:05d}" if device_id <= 99999 else f"AX3_{device_id:07d}"
    return f"AX664_{device_id:05d}" if device_id <= 99999 else f"AX6_{device_id:07d}"


def _fmt(t: Optional[_dt.datetime], raw: Optional[str] = None) -> str:
    if raw is not None:
        return raw
    return t.strftime("%Y/%m/%d,%H:%M:%S")


class EmulatedDevice:
    """One emulated AX3/AX6 (see module docstring)."""

    def __init__(self, root, device_id: int, kind: str = "AX3", *, session_id: int = 1,
                 days: float = 0.02, hz: float = 100.0, seed: int = 1, faults=(),
                 clock_offset_s: float = 2.5, clock_ppm: float = 40.0, battery_pct: float = 72.0,
                 remount_s: float = 0.4, replug_s: float = 1.5, slot: str = "emu-1",
                 stream_hz: float = C.AX_STREAM_HZ, recording: Optional[Path] = None,
                 read_bps: Optional[float] = None):
        self.kind = kind.upper()
        if self.kind not in _HW:
            raise ValueError(f"kind must be AX3 or AX6, not {kind!r}")
        bad = [f for f in faults if f not in FAULTS]
        if bad:
            raise ValueError(f"unknown fault {bad[0]!r}; known: {', '.join(FAULTS)}")
        self.root = Path(root)
        self.device_id = int(device_id)
        self.session_id = int(session_id)
        self.days, self.hz, self.seed = days, hz, seed
        self.faults = set(faults)
        self.remount_s, self.replug_s = remount_s, replug_s
        self.slot = slot
        self.stream_hz = stream_hz
        self.read_bps = read_bps  # the drive's read speed (USB full speed ~1.2e6); None: unlimited
        self.clock_ppm = clock_ppm
        self._clock_base_host = time.time()
        self._clock_base_dev = self._host_local(self._clock_base_host) + clock_offset_s
        self._battery0 = battery_pct
        self._attached_at = time.monotonic()
        self.settings = {"rate": 74, "gyro": 0 if self.kind == "AX3" else 2000, "hibernate": "0",
                         "stop": "-1", "maxsamples": 0, "debug": 0, "led": -1,
                         "annotate": [" " * 32] * 14}
        self._raw_line = ""
        self.locked = "locked" in self.faults
        self.plugged = False
        self.mounted = False
        self.streaming = False
        self.events: list[str] = []
        self.clears: list[tuple] = []  # (device id, header session, SHA-256 of the file) per erase  # what happened (for tests and the emulate command's log)
        self._out = bytearray()
        self._cv = threading.Condition()
        self._line = bytearray()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self.pty_path: Optional[str] = None
        self._pty_fds: Optional[tuple[int, int]] = None
        self._use_pty = False
        self.control = self.root / "control"
        self.media = self.root / "media"
        self.control.mkdir(parents=True, exist_ok=True)
        self.media.mkdir(parents=True, exist_ok=True)
        self._recording = recording
        self._make_drive()

    # ------------------------------------------------------------------ identity and drive
    @property
    def serial(self) -> str:
        return serial_number(self.kind, self.device_id)

    @property
    def label(self) -> str:
        return volume_label(self.kind, self.device_id)

    @property
    def volume(self) -> Path:
        return self.media / self.label

    @property
    def data_file(self) -> Path:
        return self.volume / C.AX_DATA_FILE

    def _ejected(self) -> Path:
        return self.root / f".ejected-{self.label}"

    def _unmounted(self) -> Path:
        """The drive present but not mounted (``no-automount``): the host mounts it through the
        ``mount`` signal."""
        return self.root / f".unmounted-{self.label}"

    def _mount(self) -> None:
        if self._unmounted().exists() and not self.volume.exists():
            os.replace(self._unmounted(), self.volume)
            self.mounted = True
            self.events.append("mounted by the host")

    def _make_drive(self) -> None:
        self.volume.mkdir(parents=True, exist_ok=True)
        if self.data_file.exists():
            return
        if self._recording is not None:
            shutil.copyfile(self._recording, self.data_file)
            return
        from stillpoint.engine.sim.record import simulate_recording
        tmp = self.root / f".sim-{self.label}.cwa"
        simulate_recording(tmp, device=self.kind.lower(), days=self.days, hz=self.hz, seed=self.seed,
                           truth_path=False, device_id=self.device_id, session_id=self.session_id,
                           effects="default", gyro_range_dps=2000.0 if self.kind == "AX6" else None)
        os.replace(tmp, self.data_file)

    def _header(self) -> bytes:
        hw = _HW[self.kind][3]
        s = self.settings
        start = self._dev_time_field(s["hibernate"], TS_ALWAYS)
        stop = self._dev_time_field(s["stop"], TS_NEVER)
        sensor = 0x00
        if self.kind == "AX6" and s["gyro"]:
            sensor = {2000: 2, 1000: 3, 500: 4, 250: 5, 125: 6}.get(int(s["gyro"]), 2)
        h = bytearray(build_header(hardware_type=hw, device_id=self.device_id, session_id=self.session_id,
                                   rate_code=int(s["rate"]), firmware=_HW[self.kind][2],
                                   sensor_config=sensor, logging_start=start, logging_end=stop,
                                   last_change=pack_timestamp(int(self._device_epoch()))))
        h[26] = int(s["debug"]) & 0xFF
        h[64:512] = "".join(s["annotate"]).encode("latin-1")[:448].ljust(448, b" ")
        return bytes(h)

    def _dev_time_field(self, value: str, default: int) -> int:
        if value == "0":
            return TS_ALWAYS
        if value.startswith("-"):
            return TS_NEVER
        from .protocol import parse_time
        t = parse_time(value)
        if t is None:
            return default
        return pack_timestamp(int(t.replace(tzinfo=_dt.timezone.utc).timestamp()))

    # ------------------------------------------------------------------ clock and battery
    @staticmethod
    def _host_local(t: float) -> float:
        """Host wall-clock (local time) as seconds of a naive epoch."""
        lt = time.localtime(t)
        return t + lt.tm_gmtoff

    def _device_epoch(self) -> float:
        el = time.time() - self._clock_base_host
        return self._clock_base_dev + el * (1.0 + self.clock_ppm * 1e-6)

    def device_now(self) -> _dt.datetime:
        return _dt.datetime(1970, 1, 1) + _dt.timedelta(seconds=self._device_epoch())

    def battery(self) -> tuple[int, int, int]:
        pct = min(100.0, self._battery0 + (time.monotonic() - self._attached_at) / 60.0)
        mv = int(3500 + 7 * pct)
        return int(mv * 1024 / 6000), mv, int(pct)

    # ------------------------------------------------------------------ plug / unplug
    def plug(self, pty: Optional[bool] = None) -> None:
        """Attach to the host: the drive mounts, the port appears, the registry lists it."""
        if pty is not None:
            self._use_pty = pty
        if self._ejected().exists() and not self.volume.exists():
            os.replace(self._ejected(), self.volume)
        self.mounted = self.volume.exists()
        self.plugged = True
        self._attached_at = time.monotonic()
        self._line.clear()
        with self._cv:
            self._out.clear()
        EMULATORS[self.serial] = self
        if self._use_pty:
            self._open_pty()
        if "stream-left-running" in self.faults:
            self._start_stream()
        if not any(t.name == f"ctl-{self.serial}" and t.is_alive() for t in self._threads):
            self._spawn(self._watch_control, f"ctl-{self.serial}")
        self._register()
        self.events.append("plugged")

    def _register(self) -> None:
        registry.register({
            "serial": self.serial, "manufacturer": C.AX_MANUFACTURER.ljust(24),
            "product": f"{self.kind} Composite Device", "vid": C.AX_USB_VID, "pid": C.AX_USB_PID,
            "port": self.pty_path if self._use_pty else f"axemu://{self.serial}",
            "media": str(self.media), "slot": self.slot, "owner_pid": os.getpid(),
            "faults": sorted(self.faults), "control": str(self.control), "read_bps": self.read_bps,
            "unmounted": str(self._unmounted())})

    def unplug(self) -> None:
        """Pull the cable: the port and the drive vanish (the drive folder moves aside)."""
        self.plugged = False
        self.streaming = False
        registry.unregister(self.serial)
        EMULATORS.pop(self.serial, None)
        if self.volume.exists():
            os.replace(self.volume, self._ejected())
        elif self._unmounted().exists():
            os.replace(self._unmounted(), self._ejected())
        self.mounted = False
        self._close_pty()
        with self._cv:
            self._cv.notify_all()
        self.events.append("unplugged")

    def shutdown(self) -> None:
        self._stop.set()
        if self.plugged:
            self.unplug()
        for t in self._threads:
            t.join(timeout=2)

    def _spawn(self, fn, name) -> None:
        t = threading.Thread(target=fn, name=name, daemon=True)
        t.start()
        self._threads.append(t)

    def _watch_control(self) -> None:
        """Signals from the emulated volume's file layer (see ``volume``)."""
        while not self._stop.is_set():
            for sig in ("unplug", "swap", "mount"):
                p = self.control / sig
                if p.exists():
                    try:
                        p.unlink()
                    except OSError:
                        pass
                    if sig == "unplug" and self.plugged:
                        self.faults.discard("unplug-mid-copy")
                        self.unplug()
                        threading.Timer(self.replug_s, self._replug).start()
                    elif sig == "swap":
                        self._swap()
                    elif sig == "mount":
                        self._mount()
            self._stop.wait(0.05)

    def _replug(self) -> None:
        if not self._stop.is_set():
            self.plug()

    def _swap(self) -> None:
        """Another device (id + 50000, another session) takes this dock slot."""
        self.unplug()
        self.faults.discard("swap-before-clear")
        self.device_id += 50000
        self.session_id += 1
        self._recording = None
        self._make_drive()
        self.plug()
        self.events.append(f"swapped to {self.device_id}")

    # ------------------------------------------------------------------ serial byte stream
    def host_write(self, data: bytes) -> None:
        """Bytes from the host: CR ends a line, LF ignored, BS/DEL edit, 127 kept."""
        if not self.plugged:
            raise OSError(5, "device unplugged")
        for b in data:
            if b == 0x0D:
                line = self._line.decode("ascii", "replace")
                self._line.clear()
                self._on_line(line)
            elif b == 0x0A:
                continue
            elif b in (0x08, 0x7F):
                if self._line:
                    self._line.pop()
            elif len(self._line) < C.AX_MAX_LINE:
                self._line.append(b)

    def host_read(self, n: int, timeout: Optional[float]) -> bytes:
        end = None if timeout is None else time.monotonic() + timeout
        with self._cv:
            while not self._out:
                if not self.plugged:
                    raise OSError(5, "device unplugged")
                left = None if end is None else end - time.monotonic()
                if left is not None and left <= 0:
                    return b""
                self._cv.wait(left)
            data = bytes(self._out[:n])
            del self._out[:n]
            return data

    def pending(self) -> int:
        with self._cv:
            return len(self._out)

    def _say(self, *lines: str) -> None:
        with self._cv:
            for line in lines:
                self._out += line.encode("ascii", "replace") + b"\r\n"
            self._cv.notify_all()

    # ------------------------------------------------------------------ pseudo-terminal
    def _open_pty(self) -> None:
        import tty
        master, slave = os.openpty()
        tty.setraw(slave)
        self._pty_fds = (master, slave)
        self.pty_path = os.ttyname(slave)
        self._spawn(self._pty_in, f"pty-in-{self.serial}")
        self._spawn(self._pty_out, f"pty-out-{self.serial}")

    def _close_pty(self) -> None:
        fds, self._pty_fds = self._pty_fds, None
        if fds:
            for fd in fds:
                try:
                    os.close(fd)
                except OSError:
                    pass

    def _pty_in(self) -> None:
        import select
        fds = self._pty_fds
        while fds is not None and self._pty_fds is fds and not self._stop.is_set():
            try:
                r, _, _ = select.select([fds[0]], [], [], 0.1)
                if r:
                    data = os.read(fds[0], 4096)
                    if data:
                        self.host_write(data)
            except OSError:
                return

    def _pty_out(self) -> None:
        fds = self._pty_fds
        while fds is not None and self._pty_fds is fds and not self._stop.is_set():
            try:
                data = self.host_read(4096, 0.1)
                if data:
                    os.write(fds[0], data)
            except OSError:
                return

    # ------------------------------------------------------------------ commands
    def _on_line(self, line: str) -> None:
        if self.streaming:  # any CR-terminated line stops the stream [USB] A6
            self.streaming = False
            return
        line = line.strip()
        if not line:
            return
        up = line.upper()
        self._raw_line = line
        for kw, fn in self._table():
            if up.startswith(kw):
                arg = line[len(kw) + 1:] if len(line) > len(kw) else None
                try:
                    fn(arg)
                except Exception as e:  # a malformed argument: the firmware answers ERROR
                    self._say(f"ERROR: {e}")
                return
        self._say(f"ERROR: Unknown command: {line}")

    def _table(self):
        return (("ID", self._c_id), ("TIME", self._c_time), ("SAMPLE", self._c_sample),
                ("SESSION", self._c_session), ("RATE", self._c_rate), ("HIBERNATE", self._c_hibernate),
                ("STOP", self._c_stop), ("STATUS", self._c_status), ("STREAM", self._c_stream),
                ("MAXSAMPLES", self._c_maxsamples), ("DEBUG", self._c_debug),
                ("ANNOTATE", self._c_annotate), ("LED", self._c_led), ("COMMIT", self._c_commit),
                ("CLEAR", self._c_clear), ("FORMAT", self._c_format), ("ECHO", self._c_echo),
                ("LOG", self._c_log), ("AT", lambda a: self._say("OK")))

    def _refuse_if_locked(self) -> bool:
        if self.locked:
            self._say("ERROR: Locked.")
        return self.locked

    def _c_id(self, arg):
        t, hw, fw, _ = _HW[self.kind]
        dev = self.device_id + (1 if "id-mismatch" in self.faults else 0)
        self._say(f"ID={t},{hw},{fw},{dev},{self.session_id}")

    def _c_time(self, arg):
        if arg:
            if self._refuse_if_locked():
                return
            from .protocol import parse_time
            try:
                t = parse_time(arg)
            except ValueError:
                t = None
            if t is None:
                self._say("ERROR: Problem parsing time.")
                return
            self._clock_base_host = time.time()
            self._clock_base_dev = (t - _dt.datetime(1970, 1, 1)).total_seconds()
        self._say("$TIME=" + _fmt(self.device_now()))

    def _c_sample(self, arg):
        n = int(arg) if arg and arg.strip() else 0
        out = []
        if n in (0, 1):
            adc, mv, pct = self.battery()
            out.append(f"$BATT={adc},{mv},mV,{pct},{1 if pct >= 100 else 0}")
        if n in (0, 2):
            out.append("$LDR=512,512")
        if n in (0, 3):
            out.append("$TEMP=400,231,0.1dC")
        if n in (0, 4):
            t = self.device_now()
            out.append("$TIME=" + t.strftime("%Y/%m/%d,%H:%M:%S") + f".{t.microsecond // 1000:03d}")
        if n in (0, 5):
            out.append("$ACCEL=0,0,256")
            out.append("$GYRO=0,0,0" if self.kind == "AX6" else "$GYRO=")
        self._say(*out)

    def _c_session(self, arg):
        if arg and arg.strip():
            if self._refuse_if_locked():
                return
            self.session_id = int(arg)
        s = self.session_id + (1 if "session-mismatch" in self.faults else 0)
        self._say(f"SESSION={s}")

    def _c_rate(self, arg):
        if arg and arg.strip():
            if self._refuse_if_locked():
                return
            parts = [int(x) for x in arg.replace(" ", "").split(",") if x]
            self.settings["rate"] = parts[0]
            if self.kind == "AX6":
                self.settings["gyro"] = parts[1] if len(parts) > 1 else 0  # omitted: gyro off
        code = self.settings["rate"]
        hz = int(C.cwa_rate_hz(code))
        tail = f",{self.settings['gyro']}" if self.kind == "AX6" else ""
        self._say(f"RATE={code},{hz}{tail}")

    def _time_setting(self, key, arg, name):
        if arg and arg.strip():
            if self._refuse_if_locked():
                return
            a = arg.strip()
            if a == "0" or a.startswith("-"):
                self.settings[key] = "0" if a == "0" else "-1"
            else:
                from .protocol import parse_time
                t = parse_time(a)
                self.settings[key] = _fmt(t)
        self._say(f"{name}={self.settings[key]}")

    def _c_hibernate(self, arg):
        self._time_setting("hibernate", arg, "HIBERNATE")

    def _c_stop(self, arg):
        self._time_setting("stop", arg, "STOP")

    def _c_status(self, arg):
        self._say("TEST=0000", "BATTHEALTH=12", "FTL=0,0,20,2,0", "CHECKSUM=0000", "RESTART=3",
                  "NAND=0000", "NANDID=2c,68,04,4a,a9,00,1")

    def _c_echo(self, arg):
        self._say("ECHO=0")

    def _c_log(self, arg):
        self._say(f"LOG,1,0x0001,{_fmt(self.device_now())},attached", "OK")

    def _int_setting(self, key, arg, name):
        if arg and arg.strip():
            if self._refuse_if_locked():
                return
            self.settings[key] = int(arg)
        self._say(f"{name}={self.settings[key]}")

    def _c_maxsamples(self, arg):
        self._int_setting("maxsamples", arg, "MAXSAMPLES")

    def _c_debug(self, arg):
        self._int_setting("debug", arg, "DEBUG")

    def _c_led(self, arg):
        if arg and arg.strip():
            self.settings["led"] = int(arg)
        self._say(f"LED={self.settings['led']}")

    def _c_annotate(self, arg):
        # the keyword is ANNOTATEnn: the two digits follow it directly, the value after one
        # separator character (ANNOTATE03=text)
        raw = self._raw_line[len("ANNOTATE"):]
        if len(raw) < 2 or not raw[:2].isdigit() or int(raw[:2]) > 13:
            self._say(f"ERROR: Unknown command: {self._raw_line}")
            return
        slot = int(raw[:2])
        if len(raw) > 2:
            if self._refuse_if_locked():
                return
            text = "".join(c if c >= " " else " " for c in raw[3:])
            self.settings["annotate"][slot] = text[:32].ljust(32)
        self._say(f"ANNOTATE{slot:02d}={self.settings['annotate'][slot]}")

    def _delayed(self, what: str, action) -> None:
        """Delayed activation: eject, act, re-insert after ``remount_s``, then ``COMMIT``."""
        mounted = self.mounted
        if mounted:
            self._say(f"{what}: Delayed activation.")
            os.replace(self.volume, self._ejected())
            self.mounted = False

        def finish():
            target = self._ejected() if mounted else (
                self._unmounted() if self._unmounted().exists() else self.volume)
            if what in ("CLEAR", "FORMAT"):  # what was on the device when it was erased (tests
                import hashlib  # check it): device id, the file header's session, SHA-256
                data = (target / C.AX_DATA_FILE).read_bytes()
                self.clears.append((self.device_id, int.from_bytes(data[7:11], "little"),
                                    hashlib.sha256(data).hexdigest()))
            action(target / C.AX_DATA_FILE)
            if "commit-no-remount" in self.faults:  # the reply comes, the drive never does
                self.events.append(f"{what.lower()} done; drive not re-inserted")
                self._say("COMMIT")
                return
            if mounted and self.plugged and "no-automount" in self.faults:
                os.replace(self._ejected(), self._unmounted())  # back, but nothing mounts it
            elif mounted and self.plugged:
                os.replace(self._ejected(), self.volume)
                self.mounted = True
            self._say("COMMIT")
            if what == "CLEAR":
                self.events.append("cleared")
            elif what == "FORMAT":
                self._say("FORMAT: Complete.")

        threading.Timer(self.remount_s if mounted else 0.0, finish).start()

    def _write_header(self, path: Path) -> None:
        with open(path, "r+b") as f:
            f.write(self._header())
            f.flush()
            os.fsync(f.fileno())

    def _recreate(self, path: Path) -> None:
        with open(path, "wb") as f:
            f.write(self._header())
            f.flush()
            os.fsync(f.fileno())

    def _c_commit(self, arg):
        if self._refuse_if_locked():
            return
        self._delayed("COMMIT", self._write_header)

    def _c_clear(self, arg):
        if not arg or not arg.strip().upper().startswith("DATA"):
            self._say(f"ERROR: Unknown command: CLEAR {arg or ''}".rstrip())
            return
        if self._refuse_if_locked():
            return
        self._delayed("CLEAR", self._recreate)

    def _c_format(self, arg):
        a = (arg or "").strip().upper()
        if a not in ("QC", "WC", "Q", "W"):
            self._say("ERROR: Must specify 'FORMAT Q' or 'FORMAT W'")
            return
        if self._refuse_if_locked():
            return
        self._delayed("FORMAT", self._recreate)

    def _c_stream(self, arg):
        self._start_stream()

    def _start_stream(self) -> None:
        self.streaming = True
        self._spawn(self._stream_loop, f"stream-{self.serial}")

    def _stream_loop(self) -> None:
        rng = np.random.default_rng(self.device_id)
        period = 1.0 / self.stream_hz
        nxt = time.monotonic()
        scale = C.AX_STREAM_COUNTS_PER_G_AX3 if self.kind == "AX3" else C.AX_STREAM_COUNTS_PER_G_AX6
        while self.streaming and self.plugged and not self._stop.is_set():
            a = np.rint((np.array([0.02, -0.05, 1.0]) + rng.normal(0, 0.01, 3)) * scale).astype(int)
            vals = list(a)
            if self.kind == "AX6":
                vals += list(np.rint(rng.normal(0, 20, 3)).astype(int))
            self._say(",".join(str(int(v)) for v in vals))
            nxt += period
            if nxt < time.monotonic() - 2 * period:  # more than two intervals behind: resync
                nxt = time.monotonic()
            time.sleep(max(0.0, nxt - time.monotonic()))
