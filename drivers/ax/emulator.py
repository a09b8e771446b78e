"""A firmware-faithful AX3/AX6 in pure Python, so the station runs (and is tested) without hardware.

``EmulatedDevice(root, device_id, kind="AX3", ...)`` has

* a drive: the folder ``<root>/media/<label>`` (label ``AX317_<id>`` / ``AX664_<id>``, longer ids
  ``AX3_<7 digits>``) holding a ``CWA-DATA.CWA``: a copy of ``recording``, or written by the
  caller's ``make_recording`` (the project's is ``stillpoint.engine.sim.record.device_recording``;
  the emulator receives it, as pyserial receives its URL handlers, rather than importing the
  engine) with the device's id and session, its header laid out as the firmware writes it (an AX3
  keeps only the low 16 bits of the id); ``COMMIT``/``CLEAR DATA``/``FORMAT`` drop the drive (the folder
  moves aside), act on it and re-present it after ``remount_s`` per countdown second (delayed
  activation); ``FORMAT`` removes every file and rebuilds the label;
* the firmware's command interpreter (``firmware_shell``): every reply as the AX3/AX6 firmware
  source prints it, its line editor (CR ends a line, LF ignored, BS/DEL edit, 127 characters kept,
  optional echo) with its static input buffer, a drifting real-time clock (``clock_ppm``), a
  battery charged by default (``BATTERY_PCT``; ``battery_pct`` or the ``low-battery`` fault: a
  low one that charges 1 %/min), ``STREAM`` paced at 100 Hz and stopped by any line, which is then executed;
  the RAM settings are reloaded at every plug-in, as the firmware does at boot (defaults, the
  drive's ``SETTINGS.INI``, then the data file's header);
* a serial port: in-process through the ``axemu://<serial>`` pyserial URL (``emulator_url``), or a
  pseudo-terminal (``plug(pty=True)``) that any program opens as a real serial port;
* a registry entry (``registry``) so discovery in any process finds it while it is plugged in.

Faults (kebab-case names, ``FAULTS``) make it misbehave the way a real device or cable can. Those
that concern reading the drive (``unplug-mid-copy``, ``short-read``, ``io-error``, ``hang``,
``hang-before-clear``, ``bit-flip``, ``change-between-reads``) are applied by the emulated
volume's file layer (``volume.open_data_file``), which signals the device through
``<root>/control/``; the rest are applied here.

The folder ``root`` can be used again: leftovers of an earlier run (a drive moved aside, a
half-written simulation, stale control signals) are put back or removed on start and on
``shutdown``.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import os
import shutil
import threading
import time
from pathlib import Path
from typing import Optional, Protocol

import numpy as np

from .. import constants as C
from . import firmware_text as T
from . import registry
from .firmware_shell import (ACTION_DELETE, ACTION_FORMAT_QUICK, ACTION_FORMAT_WIPE,
                             ACTION_REMOUNT, CONFIG_LOCK, FORMAT_CWA_UNPACKED, LOG_VALUE_BATTERY,
                             LOG_VALUE_RESTART, FirmwareShell)

FAULTS = {
    "unplug-mid-copy": "the cable is pulled while the data file is being copied (re-plugged after a few s)",
    "short-read": "the data file read ends early (fewer bytes than its size)",
    "io-error": "an I/O error at an offset in the data file",
    "hang": "a read of the data file never returns",
    "hang-before-clear": "a cache-bypassing re-read after the download's verification read (the "
                         "re-read just before a clear) never returns",
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
    "low-battery": "the battery is nearly flat when plugged in (LOW_BATTERY_PCT, then charging at "
                   "1 %/min), below a study profile's usual minimum",
}
# The battery of a device as it comes back to be set up: charged (a device is charged before it
# is configured for a wear, and sits on the dock's charger while downloaded), so a profile's
# min_battery_pct (e.g. 80 %) is met; ``low-battery`` (or ``battery_pct``) gives a flat one.
BATTERY_PCT = 100.0
LOW_BATTERY_PCT = 15.0
FAULT_LOCK_CODE = 4321  # the lock code the ``locked`` fault sets (LOCK 4321; UNLOCK 4321 lifts it)
INPUT_BUFFER = 128  # SERIAL_BUFFER_SIZE (Flux.AX3/src/Utils/Util.c 46)
RESTARTS_AT_START, BATTERY_HEALTH_AT_START = 3, 12  # the emulated unit's program-memory counters

EMULATORS: dict[str, "EmulatedDevice"] = {}  # serial -> device, for the axemu:// URL handler


def serial_number(kind: str, device_id: int) -> str:
    """USB serial ``CWA17_<id>`` / ``AX664_<id>`` (``firmware_text.serial_number``)."""
    return T.serial_number(kind, device_id)


def volume_label(kind: str, device_id: int) -> str:
    """Volume label ``AX317_<id>`` / ``AX3_<7 digits>`` (``firmware_text.volume_label``)."""
    return T.volume_label(kind, device_id)


class RecordingMaker(Protocol):
    """Writes a device's .cwa recording at ``path`` (the emulator patches the identity bytes)."""

    def __call__(self, path: Path, *, device: str, days: float, hz: float, seed: int,
                 device_id: int, session_id: int, gyro_range_dps: Optional[float],
                 packed: Optional[bool]) -> object: ...


class EmulatedDevice:
    """One emulated AX3/AX6 (see module docstring)."""

    def __init__(self, root, device_id: int, kind: str = "AX3", *, session_id: int = 1,
                 days: float = 0.02, hz: float = 100.0, seed: int = 1, faults=(),
                 clock_offset_s: float = 2.5, clock_ppm: float = 40.0,
                 battery_pct: Optional[float] = None,
                 remount_s: float = 0.4, replug_s: float = 1.5, slot: str = "emu-1",
                 stream_hz: float = C.AX_STREAM_HZ, recording: Optional[Path] = None,
                 make_recording: Optional[RecordingMaker] = None,
                 read_bps: Optional[float] = None):
        self.kind = kind.upper()
        if self.kind not in ("AX3", "AX6"):
            raise ValueError(f"kind must be AX3 or AX6, not {kind!r}")
        bad = [f for f in faults if f not in FAULTS]
        if bad:
            raise ValueError(f"unknown fault {bad[0]!r}; known: {', '.join(FAULTS)}")
        if not 0 <= int(device_id) <= T.U32:
            raise ValueError(f"device id must fit 32 bits, got {device_id}")
        self.root = Path(root)
        self.device_id = int(device_id)  # the id the USB serial was made from (at the last boot)
        self.rom_device_id = int(device_id)  # the id in program memory (DEVICE n changes it)
        self._initial_session = int(session_id) & T.U32
        self._label = volume_label(self.kind, self.device_id)
        self.days, self.hz, self.seed = days, hz, seed
        self.faults = set(faults)
        self.remount_s, self.replug_s = remount_s, replug_s
        self.slot = slot
        self.stream_hz = stream_hz
        self.read_bps = read_bps  # the drive's read speed (USB full speed ~1.2e6); None: unlimited
        self.clock_ppm = clock_ppm
        self._clock_base_host = time.time()
        self._clock_base_dev = self._host_local(self._clock_base_host) + clock_offset_s
        # charged unless told (``battery_pct``) or the ``low-battery`` fault
        self._battery0 = float(battery_pct) if battery_pct is not None else (
            LOW_BATTERY_PCT if "low-battery" in faults else BATTERY_PCT)
        self._attached_at = time.monotonic()
        # what the firmware keeps in program memory across restarts
        self.config: dict[int, int] = {}  # SettingsSetConfigValue: lock code, ECC, fractional
        self.log_values = {LOG_VALUE_RESTART: RESTARTS_AT_START, LOG_VALUE_BATTERY: BATTERY_HEALTH_AT_START}
        self.log_entries: list[tuple] = []  # (status, packed time, text), newest first
        self.plugged = False
        self.mounted = False  # the host sees the drive folder at ``volume``
        self.disk_mounted = True  # the firmware presents its medium (status.diskMounted)
        self.streaming = False
        self._streamer = False  # a stream thread is running
        self.events: list[str] = []
        self.clears: list[tuple] = []  # (device id, header session, SHA-256 of the file) per erase  # what happened (for tests and the emulate command's log)
        self._out = bytearray()
        self._cv = threading.Condition()
        self._lock = threading.RLock()  # one command or action at a time, as on the device
        self._inbuf = bytearray(INPUT_BUFFER)  # the firmware's static line buffer
        self._inlen = 0
        self._pending: Optional[threading.Timer] = None  # the delayed action (one at a time)
        self._timers: list[threading.Timer] = []
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
        self._make_recording = make_recording
        self._clean_leftovers()
        self.shell = FirmwareShell(self)
        self._make_drive()
        self._boot()

    # ------------------------------------------------------------------ identity and drive
    @property
    def serial(self) -> str:
        return serial_number(self.kind, self.device_id)

    @property
    def label(self) -> str:
        """The drive's volume label (FORMAT rebuilds it from the device id)."""
        return self._label

    @property
    def volume(self) -> Path:
        return self.media / self.label

    @property
    def data_file(self) -> Path:
        return self.volume / C.AX_DATA_FILE

    @property
    def session_id(self) -> int:
        """The session in the firmware's RAM (what ``SESSION`` answers)."""
        return self.shell.s.session

    @session_id.setter
    def session_id(self, value: int) -> None:
        self.shell.s.session = int(value) & T.U32

    @property
    def locked(self) -> bool:
        return self.shell.lock_code != 0

    @locked.setter
    def locked(self, value: bool) -> None:
        self.shell.lock_code = (self.shell.lock_code or FAULT_LOCK_CODE) if value else 0

    @property
    def settings(self) -> dict:
        """The RAM settings as text: rate code, gyro, start/stop as the firmware prints them,
        max samples, debug, the 14 annotation slots (as ``ANNOTATEnn`` shows them)."""
        s = self.shell.s
        return {"rate": s.rate, "gyro": s.gyro, "hibernate": T.rtc_to_string(s.start),
                "stop": T.rtc_to_string(s.stop), "maxsamples": s.maxsamples, "debug": s.debug,
                "annotate": ["".join(" " if c < 32 else chr(c) for c in a) for a in s.annotation]}

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

    def drive_dir(self) -> Path:
        """Where the drive's files are now: mounted, present but unmounted, or dropped."""
        for p in (self.volume, self._unmounted(), self._ejected()):
            if p.is_dir():
                return p
        self._ejected().mkdir(parents=True)
        return self._ejected()

    def _clean_leftovers(self) -> None:
        """Put back the drive an earlier run left aside, remove half-written simulations, stale
        control signals and the leftovers of other labels."""
        for p in self.root.glob(".sim-*"):
            p.unlink(missing_ok=True)
        for p in self.control.iterdir():
            if p.is_file():
                p.unlink(missing_ok=True)
        for prefix in (".unmounted-", ".ejected-"):
            for p in sorted(self.root.glob(prefix + "*")):
                if p.name == prefix + self.label and p.is_dir() and not self.volume.exists():
                    os.replace(p, self.volume)
                elif p.is_dir():
                    shutil.rmtree(p, ignore_errors=True)
                else:
                    p.unlink(missing_ok=True)

    def _make_drive(self) -> None:
        self.volume.mkdir(parents=True, exist_ok=True)
        if self.data_file.exists():
            return
        if self._recording is not None:
            shutil.copyfile(self._recording, self.data_file)
            return
        # the recording the device made with its SETTINGS.INI (DATAMODE=20: AX3 unpacked)
        self.shell.initialize()
        self.shell.run_settings_file()
        packed = None
        if self.kind == "AX3" and self.shell.s.data_mode & 0x0F == FORMAT_CWA_UNPACKED:
            packed = False
        if self._make_recording is None:
            raise ValueError(f"emulated {self.kind} {self.device_id} has no recording: give it "
                             "recording= (a .cwa to copy) or make_recording= (a function that "
                             "writes one, e.g. stillpoint.engine.sim.record.device_recording)")
        tmp = self.root / f".sim-{self.label}.cwa"
        self._make_recording(tmp, device=self.kind.lower(), days=self.days, hz=self.hz,
                             seed=self.seed, device_id=self.device_id,
                             session_id=self._initial_session,
                             gyro_range_dps=2000.0 if self.kind == "AX6" else None, packed=packed)
        with open(tmp, "r+b") as f:  # the identity bytes as this firmware writes them
            f.seek(4)
            f.write(bytes([self.shell.header()[4]]))
            f.seek(11)
            f.write(b"\xff\xff" if self.kind == "AX3" else (self.device_id >> 16).to_bytes(2, "little"))
        os.replace(tmp, self.data_file)

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

    def rtc_now(self) -> int:
        return T.datetime_to_packed(self.device_now())

    def rtc_now_ms(self) -> tuple[int, int]:
        t = self.device_now()
        return T.datetime_to_packed(t), t.microsecond // 1000

    def set_rtc(self, packed: int) -> None:
        """``RtcWrite``; an all-ones date (``TIME -...``) is echoed but not modelled: the clock
        keeps running."""
        if packed == T.U32:
            return
        self._clock_base_host = time.time()
        self._clock_base_dev = (T.packed_to_datetime(packed) - _dt.datetime(1970, 1, 1)).total_seconds()

    def battery(self) -> tuple[int, int, int]:
        pct = min(100.0, self._battery0 + (time.monotonic() - self._attached_at) / 60.0)
        mv = int(3500 + 7 * pct)
        return int(mv * 1024 / 6000), mv, int(pct)

    def battery_reading(self) -> tuple[int, int, int, bool]:
        adc, mv, pct = self.battery()
        return adc, mv, pct, pct >= 100

    def accel_sample(self) -> tuple:
        return 0, 0, 256, ((0, 0, 0) if self.kind == "AX6" else None)

    def pause(self, seconds: float) -> None:
        time.sleep(seconds)

    # ------------------------------------------------------------------ plug / unplug
    def _boot(self) -> None:
        """The firmware starts: RAM settings from defaults, SETTINGS.INI and the header."""
        with self._lock:
            self.shell.boot()
            if "locked" in self.faults:
                self.shell.lock_code = FAULT_LOCK_CODE
            self.device_id = self.rom_device_id & 0xFFFF if self.rom_device_id >> 16 == 0xFFFF \
                else self.rom_device_id

    def plug(self, pty: Optional[bool] = None) -> None:
        """Attach to the host: the firmware boots, the drive mounts, the port appears, the
        registry lists it."""
        if pty is not None:
            self._use_pty = pty
        with self._lock:
            self._boot()
            # an "initial lock" (ILOCK) keeps the drive unmounted until UNLOCK (Settings.c 285-294)
            self.disk_mounted = self.config.get(CONFIG_LOCK, 0xFFFF) in (0, 0xFFFF)
            if self._ejected().exists() and not self.volume.exists() and self.disk_mounted:
                os.replace(self._ejected(), self.volume)
            self.mounted = self.volume.exists()
            self.plugged = True
            self._attached_at = time.monotonic()
            self._inlen = 0
            with self._cv:
                self._out.clear()
        EMULATORS[self.serial] = self
        if self._use_pty:
            self._open_pty()
        if "stream-left-running" in self.faults:
            self._start_stream()
        if not any(t.name == f"ctl-{id(self)}" and t.is_alive() for t in self._threads):
            self._spawn(self._watch_control, f"ctl-{id(self)}")  # one watcher, whatever the serial
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
        """Pull the cable: the port and the drive vanish (the drive folder moves aside); the
        device restarts into logging mode (its restart counter counts it)."""
        with self._lock:
            self._cancel_pending()
            was = self.plugged
            self.plugged = False
            self.streaming = False
            registry.unregister(self.serial)
            EMULATORS.pop(self.serial, None)
            self._set_aside()
            self.mounted = False
            if was:
                self.log_values[LOG_VALUE_RESTART] += 1  # RunLogging (AX3 main.c 509)
        self._close_pty()
        with self._cv:
            self._cv.notify_all()
        self.events.append("unplugged")

    def _set_aside(self) -> None:
        if self.volume.exists():
            os.replace(self.volume, self._ejected())
        elif self._unmounted().exists():
            os.replace(self._unmounted(), self._ejected())

    def shutdown(self) -> None:
        """Stop the device and leave its drive in ``media/<label>`` for the next run."""
        self._stop.set()
        if self.plugged:
            self.unplug()
        with self._lock:
            self._cancel_pending()
            for t in self._timers:
                t.cancel()
        for th in self._threads:
            th.join(timeout=2)
        with self._lock:
            for p in (self._ejected(), self._unmounted()):
                if p.is_dir() and not self.volume.exists():
                    os.replace(p, self.volume)
        self._clean_leftovers()

    def _spawn(self, fn, name) -> None:
        t = threading.Thread(target=fn, name=name, daemon=True)
        t.start()
        self._threads.append(t)

    def _later(self, seconds: float, fn) -> threading.Timer:
        t = threading.Timer(seconds, fn)
        t.daemon = True
        self._timers = [x for x in self._timers if x.is_alive()] + [t]
        t.start()
        return t

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
                        self._later(self.replug_s, self._replug)
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
        self.rom_device_id = self.device_id
        self._initial_session += 1
        self._label = volume_label(self.kind, self.device_id)
        self._recording = None
        self._make_drive()
        self.plug()
        self.events.append(f"swapped to {self.device_id}")

    # ------------------------------------------------------------------ serial byte stream
    def host_write(self, data: bytes) -> None:
        """Bytes from the host, edited as ``_user_gets`` does (Flux.AX3/src/Utils/Util.c 56-102):
        CR ends a line, LF ignored, BS/DEL edit, NUL dropped, 127 characters kept; with ECHO 1
        the characters are echoed."""
        if not self.plugged:
            raise OSError(5, "device unplugged")
        buf = self._inbuf
        for b in data:
            echo = self.shell.echo
            if b == 0:
                continue
            if b == 0x0D:
                if echo:
                    self.say(b"\r")
                buf[self._inlen] = 0
                line = bytes(buf[:self._inlen]).decode("latin-1")
                beyond = bytes(buf[self._inlen + 1:]).decode("latin-1")
                self._inlen = 0
                if echo:
                    self.say(b"\n")
                self._on_line(line, beyond)
            elif b in (0x08, 0x7F):
                if self._inlen > 0:
                    if echo:
                        self.say(b"\x08 \x08")
                    self._inlen -= 1
                    buf[self._inlen] = 0
            elif b == 0x0A:
                continue
            elif self._inlen + 1 < INPUT_BUFFER:
                if echo:
                    self.say(bytes([b]))
                buf[self._inlen] = b
                self._inlen += 1
                buf[self._inlen] = 0
            elif echo:
                self.say(b"\x07")

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

    def say(self, data: bytes) -> None:
        with self._cv:
            self._out += data
            self._cv.notify_all()

    def _say(self, *lines: str) -> None:
        self.say(b"".join(line.encode("ascii", "replace") + b"\r\n" for line in lines))

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
    def _on_line(self, line: str, beyond: str = "") -> None:
        """A line from the host: a running stream stops and the line is then executed (AX3
        main.c 291-297)."""
        with self._lock:
            self.streaming = False
            self.shell.command(line, beyond)

    # ------------------------------------------------------------------ delayed activation
    def delay_action(self, flags: int, countdown: int) -> None:
        """``status.actionFlags``/``actionCountdown``: with ACTION_REMOUNT the drive is dropped
        now; the action runs ``countdown`` ticks later (``remount_s`` each). A new delayed action
        replaces a pending one, as the firmware's single countdown does."""
        with self._lock:
            if flags & ACTION_REMOUNT:
                self.disk_mounted = False
                self._set_aside()
                self.mounted = False
            self._cancel_pending()
            self._pending = self._later(self.remount_s * countdown, lambda: self._finish(flags))

    def _cancel_pending(self) -> None:
        if self._pending is not None:
            self._pending.cancel()
            self._pending = None

    def _finish(self, flags: int) -> None:
        with self._lock:
            self._pending = None
            if not self.plugged or self._stop.is_set():
                return
            if self.run_action(flags):
                self._later(0.0, self._restart)

    def run_action(self, flags: int) -> bool:
        """``SettingsAction`` now, on the drive wherever it is; erased recordings are noted in
        ``clears`` (device id, the header's session, SHA-256)."""
        with self._lock:
            if flags & (ACTION_DELETE | ACTION_FORMAT_QUICK | ACTION_FORMAT_WIPE):
                f = self.drive_dir() / C.AX_DATA_FILE
                if f.is_file():
                    data = f.read_bytes()
                    self.clears.append((self.device_id, int.from_bytes(data[7:11], "little"),
                                        hashlib.sha256(data).hexdigest()))
                self.events.append("cleared" if flags & ACTION_DELETE else
                                   "wiped" if flags & ACTION_FORMAT_WIPE else "formatted")
            return self.shell.action(flags)

    def set_mounted(self, value: bool) -> None:
        """``status.diskMounted`` (ACTION_REMOUNT, ``MOUNT 0|1``): the drive is presented to the
        host or dropped."""
        with self._lock:
            if not value:
                self.disk_mounted = False
                self._set_aside()
                self.mounted = False
                return
            self.disk_mounted = True
            if not self.plugged or not self._ejected().exists():
                return
            if "commit-no-remount" in self.faults:  # the reply came; the drive never does
                self.events.append("drive not re-inserted")
            elif "no-automount" in self.faults:
                os.replace(self._ejected(), self._unmounted())  # back, but nothing mounts it
            else:
                os.replace(self._ejected(), self.volume)
                self.mounted = True

    def format_drive(self, wipe: bool, label: str) -> bool:
        """``FsFtlFormat``: a new empty filesystem labelled ``label`` (every file removed)."""
        with self._lock:
            where = self.drive_dir()
            for p in where.iterdir():
                if p.is_dir() and not p.is_symlink():
                    shutil.rmtree(p)
                else:
                    p.unlink()
            if label != self._label:
                kind = [self.volume, self._unmounted(), self._ejected()].index(where)
                self._label = label
                os.replace(where, [self.volume, self._unmounted(), self._ejected()][kind])
            return True

    def destroy_drive(self) -> None:
        """``FtlDestroy`` (FORMAT D): every block erased; the drive holds no files."""
        with self._lock:
            for p in self.drive_dir().iterdir():
                if p.is_dir() and not p.is_symlink():
                    shutil.rmtree(p)
                else:
                    p.unlink()
            self.events.append("destroyed")

    def _restart(self) -> None:
        """RESET: the device restarts; the port and the drive drop and come back."""
        if self.plugged and not self._stop.is_set():
            self.unplug()
            self.log_values[LOG_VALUE_RESTART] -= 1  # a reset while attached does not log
            self._later(self.replug_s, self._replug)

    # ------------------------------------------------------------------ stream
    def start_stream(self) -> None:
        self._start_stream()

    def _start_stream(self) -> None:
        with self._lock:  # one stream at a time, as the firmware has one status.stream
            self.streaming = True
            if not self._streamer:
                self._streamer = True
                self._threads = [t for t in self._threads if t.is_alive()]
                self._spawn(self._stream_loop, f"stream-{self.serial}")

    def _stream_loop(self) -> None:
        rng = np.random.default_rng(self.device_id)
        period = 1.0 / self.stream_hz
        nxt = time.monotonic()
        scale = C.AX_STREAM_COUNTS_PER_G_AX3 if self.kind == "AX3" else C.AX_STREAM_COUNTS_PER_G_AX6
        while True:
            a = np.rint((np.array([0.02, -0.05, 1.0]) + rng.normal(0, 0.01, 3)) * scale).astype(int)
            vals = list(a)
            if self.kind == "AX6":
                vals += list(np.rint(rng.normal(0, 20, 3)).astype(int))
            with self._lock:
                if not (self.streaming and self.plugged) or self._stop.is_set():
                    self._streamer = False
                    break
                self._say(",".join(str(int(v)) for v in vals))
            nxt += period
            if nxt < time.monotonic() - 2 * period:  # more than two intervals behind: resync
                nxt = time.monotonic()
            time.sleep(max(0.0, nxt - time.monotonic()))

