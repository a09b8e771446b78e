"""The AX3/AX6 firmware's serial command interpreter, reproduced for the emulator.

``FirmwareShell(device)`` holds what the firmware holds in RAM (``Settings``/``Status``) and
answers each input line as ``SettingsCommand`` prints it (AX3/Firmware/src/Settings.c 437-1393;
the AX6 differs in ``ID`` and ``RATE``, AX6/Firmware/src/Settings.c 451, 729-753). ``boot()`` is
``SettingsInitialize`` + ``SETTINGS.INI`` + ``LoggerReadMetadata`` (AX3 main.c 221-232);
``action()`` is ``SettingsAction`` (Settings.c 341-433); ``header()`` is ``LoggerWriteMetadata``
(AX3 Logger.c 395-471, AX6 Logger.c 485-580).

Line references without a file are to AX3/Firmware/src/Settings.c at commit 144ef13 (FW V50) of
digitalinteraction/openmovement. Parsing and printing rules live in ``firmware_text``.

The shell touches the device only through a few calls: ``say`` (bytes to the host), the clock
(``rtc_now``, ``rtc_now_ms``, ``set_rtc``), ``battery_reading``, ``accel_sample``, ``pause``,
``drive_dir`` (the drive's folder, mounted or not), ``disk_mounted`` (the firmware's
``status.diskMounted``), ``delay_action`` and ``run_action`` (delayed or immediate activation),
``format_drive``, ``destroy_drive``, ``start_stream``, ``set_mounted``, ``faults`` and the values
the device keeps in program memory (``config``, ``log_values``, ``log_entries``,
``rom_device_id``).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

from .. import constants as C
from ..cwa_layout import build_header
from . import firmware_text as T

# Settings.h 96-102, 113-118 (AX3) / 97-103, 114-119 (AX6)
FORMAT_CSV, FORMAT_CWA_PACKED, FORMAT_CWA_UNPACKED, FORMAT_SINGLE_FILE = 0x01, 0x02, 0x04, 0x10
ACTION_FORMAT_WIPE, ACTION_FORMAT_QUICK, ACTION_DELETE = 0x01, 0x02, 0x04
ACTION_CREATE, ACTION_REMOUNT, ACTION_RESTART = 0x08, 0x10, 0x20
SETTINGS_FILE = "SETTINGS.INI"  # Settings.h 161
LOG_FILE = "LOG.TXT"  # Settings.c 56
LOG_COUNT = 15  # Settings.h 127
LOG_CATEGORY_USER = 0x0100  # Settings.h 142
CONFIG_LOCK, CONFIG_ECC, CONFIG_FRACTIONAL = 0, 1, 2  # Settings.h 152-154
CONFIG_ECC_DEFAULT, CONFIG_FRACTIONAL_DEFAULT = 1, 1  # Settings.h 89-90
LOG_VALUE_RESTART, LOG_VALUE_BATTERY = 0, 1  # Settings.h 139-140
ANNOTATION_COUNT, ANNOTATION_SIZE = 14, 32  # Settings.h 45-46
ACCEL_DEFAULT_RATE = 0x4A  # Flux.AX3/include/Peripherals/Accel.h 39: ACCEL_RATE_100 | ACCEL_RANGE_8G (the AX6
# takes it from the unpublished Flux tree, AX6 Settings.c 238; assumed the same)
DEFAULT_DEBUGGING = 0  # AX3/Firmware/src/HardwareProfile.h 66
# firmware versions and the header's hardware byte as each firmware writes them
SOFTWARE_VERSION = {"AX3": 50, "AX6": 56}  # AX3 HardwareProfile.h 39; AX6 HardwareProfile.h 73
HARDWARE_VERSION = T.HARDWARE_VERSION
HEADER_HARDWARE_BYTE = {"AX3": 0x00, "AX6": 0x64}  # AX3 Logger.c 447 (performClear); AX6 Logger.c 537
# AX6 Logger.c 549-558: gyro range -> header byte 35
GYRO_SENSOR_CONFIG = {4000: 1, 2000: 2, 1000: 3, 500: 4, 250: 5, 125: 6, 62: 7}
# What the emulated NAND reports: STATUS 1-7 (Settings.c 548-595; FTL string Flux.AX3/src/Ftl/Ftl.c
# 2136-2158: warnings, errors, spare blocks per plane, planes, bad blocks of each plane)
SELF_TEST, BATTERY_HEALTH_DEFAULT, FTL_SPARE, FTL_PLANES = 0x0000, 12, 20, 2
NAND_ID = (0x2C, 0x68, 0x04, 0x4A, 0xA9, 0x00)


@dataclass
class Settings:
    """``Settings`` (Settings.h 31-50): what a COMMIT writes into the data file's header."""

    device_id: int
    session: int = 0
    rate: int = ACCEL_DEFAULT_RATE
    gyro: int = 0
    start: int = T.U32  # loggingStartTime (packed; 0 = always, 0xFFFFFFFF = never)
    stop: int = T.U32  # loggingEndTime
    maxsamples: int = 0
    debug: int = DEFAULT_DEBUGGING
    last_change: int = 0
    tzone: int = -1
    data_mode: int = FORMAT_SINGLE_FILE | FORMAT_CWA_PACKED
    annotation: list = field(default_factory=lambda: [bytes(ANNOTATION_SIZE)] * ANNOTATION_COUNT)


class FirmwareShell:
    """The firmware's RAM state and command interpreter for one emulated device."""

    def __init__(self, device):
        self.dev = device
        self.kind = device.kind
        self.atoi = T.my_atoi_ax6 if self.kind == "AX6" else T.my_atoi
        self.s = Settings(device_id=device.rom_device_id)
        self.lock_code = 0
        self.ecc = CONFIG_ECC_DEFAULT
        self.fractional = CONFIG_FRACTIONAL_DEFAULT
        self.echo = 0  # commEcho (Flux.AX3/src/Utils/Util.c 45)
        self.led = -1

    # ------------------------------------------------------------------ boot
    def initialize(self) -> None:
        """``SettingsInitialize`` (Settings.c 233-316)."""
        dev = self.dev
        dev_id = dev.rom_device_id
        dev_id = dev_id & 0xFFFF if dev_id >> 16 == 0xFFFF else dev_id  # SettingsGetDeviceId (79-93)
        session = (10000 * dev_id) & T.U32 if dev_id != T.DEVICEID_UNSET else 0
        session = (session + dev.log_values[LOG_VALUE_RESTART] % 10000) & T.U32
        self.s = Settings(device_id=dev_id, session=session,
                          data_mode=FORMAT_SINGLE_FILE | (FORMAT_CWA_UNPACKED if self.kind == "AX6"
                                                          else FORMAT_CWA_PACKED))
        self.led = -1
        self.echo = 0  # commEcho starts 0 at every reset (Flux.AX3/src/Utils/Util.c 45)
        self.lock_code = 0
        code = dev.config.get(CONFIG_LOCK, 0xFFFF)
        if code not in (0, 0xFFFF):  # "initial lock": locked, and the drive starts unmounted
            self.lock_code = code
        value = dev.config.get(CONFIG_ECC, 0xFFFF)
        self.ecc = T.as_char(value) if value != 0xFFFF else CONFIG_ECC_DEFAULT
        value = dev.config.get(CONFIG_FRACTIONAL, 0xFFFF)
        self.fractional = T.as_char(value) if value != 0xFFFF else CONFIG_FRACTIONAL_DEFAULT

    def boot(self) -> None:
        """Start-up (AX3 main.c 221-232): defaults, the drive's SETTINGS.INI run as a batch,
        then the data file's header."""
        self.initialize()
        self.run_settings_file()
        self.read_metadata()

    def run_settings_file(self) -> None:
        """``SettingsReadFile(SETTINGS_FILE)`` (Settings.c 320-337): each line (``FSfgets`` of at
        most 63 characters, line end included) run as a batch command."""
        ini = self.dev.drive_dir() / SETTINGS_FILE
        if not ini.is_file():
            return
        for line in ini.read_bytes().decode("latin-1").splitlines(keepends=True):
            for k in range(0, len(line), 63):
                self.command(line[k:k + 63], batch=True)

    def read_metadata(self) -> bool:
        """``LoggerReadMetadata`` (AX3 Logger.c 346-390; AX6 Logger.c 416-480)."""
        path = self.dev.drive_dir() / C.AX_DATA_FILE
        try:
            with open(path, "rb") as f:
                b = f.read(512)
        except OSError:
            return False
        if len(b) != 512 or b[0:2] != b"MD":
            return False
        u16 = lambda o: int.from_bytes(b[o:o + 2], "little")  # noqa: E731
        u32 = lambda o: int.from_bytes(b[o:o + 4], "little")  # noqa: E731
        s = self.s
        dev_id = u16(5)
        s.session, s.start, s.stop, s.maxsamples = u32(7), u32(13), u32(17), u32(21)
        s.debug = b[26]
        if self.kind == "AX6":
            if u16(11) != 0xFFFF:
                dev_id |= u16(11) << 16
            cfg = b[35]
            s.gyro = 8000 // (1 << (cfg & 0x07)) if cfg not in (0x00, 0xFF) and cfg & 0x07 else 0
        s.rate = b[36]
        s.last_change = u32(37)
        s.tzone = T.as_int16(u16(42))
        s.annotation = [bytes(b[64 + 32 * i:96 + 32 * i]) for i in range(ANNOTATION_COUNT)]
        return dev_id == s.device_id

    # ------------------------------------------------------------------ header and actions
    def header(self) -> bytes:
        """The 1024 bytes ``LoggerWriteMetadata`` writes (AX3 Logger.c 444-466: the hardware
        byte 0x00 and only the low 16 bits of the id, bytes 11-12 left 0xFF; AX6 Logger.c
        534-566: hardware byte, both id words and the gyro's sensor byte)."""
        s, k = self.s, self.kind
        sensor = GYRO_SENSOR_CONFIG.get(s.gyro, 0) if k == "AX6" else 0xFF
        h = bytearray(build_header(
            hardware_type=HEADER_HARDWARE_BYTE[k], device_id=s.device_id, session_id=s.session,
            rate_code=s.rate, firmware=SOFTWARE_VERSION[k], sensor_config=sensor,
            logging_start=s.start, logging_end=s.stop, last_change=s.last_change,
            upper_id_word=(k == "AX6")))
        h[21:25] = s.maxsamples.to_bytes(4, "little")
        h[25] = 0xFF
        h[26] = s.debug & 0xFF
        h[42:44] = (s.tzone & 0xFFFF).to_bytes(2, "little")
        h[64:512] = b"".join(s.annotation)
        return bytes(h)

    def write_metadata(self, root: Path) -> bool:
        """``LoggerWriteMetadata``: the header over the first 1024 bytes (the file is created if
        missing, data after the header kept), last-change time set to now."""
        self.s.last_change = self.dev.rtc_now()
        path = root / C.AX_DATA_FILE
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
            try:
                os.pwrite(fd, self.header(), 0)
                os.fsync(fd)
            finally:
                os.close(fd)
        except OSError:
            return False
        return True

    def action(self, flags: int) -> bool:
        """``SettingsAction`` (Settings.c 341-433): delete, format, create, in that order, each
        printing as the firmware does. Returns True if the device restarts."""
        root = self.dev.drive_dir()
        if flags & ACTION_DELETE:
            try:
                (root / C.AX_DATA_FILE).unlink()
            except FileNotFoundError:
                pass
        if flags & (ACTION_FORMAT_WIPE | ACTION_FORMAT_QUICK):
            ok = self.dev.format_drive(bool(flags & ACTION_FORMAT_WIPE),
                                       T.volume_label(self.kind, self.s.device_id))
            root = self.dev.drive_dir()
            if ok:
                self.say("FORMAT: Complete.\r\n")
            else:  # Settings.c 391-398: FsFtlFormat/FSInit failed
                wipe = "wipe/" if flags & ACTION_FORMAT_WIPE else "plain-"
                self.say(f"ERROR: Problem during {wipe}format (0x80. 'status 3' for NAND health), "
                         "failed: MNT\r\n")
        if flags & ACTION_CREATE:
            if self.write_metadata(root):
                self.say("COMMIT\r\n")
            else:
                self.say("ERROR: Problem during commit\n")  # LF only (Settings.c 411)
        if flags & ACTION_REMOUNT:
            self.dev.set_mounted(True)
        return bool(flags & ACTION_RESTART)

    # ------------------------------------------------------------------ command interpreter
    def say(self, text: str) -> None:
        if not self._batch:
            self.dev.say(text.encode("latin-1", "replace"))

    _batch = False

    def command(self, line: str, beyond: str = "", batch: bool = False) -> None:
        """``SettingsCommand(line, mode)``. ``beyond`` is what follows the line's terminating
        NUL in the firmware's static input buffer (read by ``ECHO`` without an argument)."""
        if not line:
            return
        self._batch = batch
        try:
            self._command(line, beyond, batch)
        finally:
            self._batch = False

    def _command(self, line: str, beyond: str, batch: bool) -> None:
        locked = not batch and self.lock_code != 0
        low = line.lower()
        at = lambda i: line[i] if i < len(line) else "\0"  # noqa: E731
        for kw, fn, usb_only in self._table():
            if low.startswith(kw) and not (usb_only and batch):
                fn(line, at, locked, beyond)
                return
        self.say(f"ERROR: Unknown command: {line}\r\n")  # Settings.c 1387-1391

    def _table(self):
        # the keywords in source order (case-insensitive prefixes); Settings.c 443-1382
        return (("help", self._help, True), ("echo", self._echo, False), ("id", self._id, False),
                ("sample", self._sample, True), ("status", self._status, False),
                ("time", self._time, False), ("tzone", self._tzone, False),
                ("hibernate", self._hibernate, False), ("stop", self._stop, False),
                ("lastchanged", self._lastchanged, False), ("maxsamples", self._maxsamples, False),
                ("debug", self._debug, False), ("session", self._session, False),
                ("rate", self._rate, False), ("clear", self._clear, False),
                ("commit", self._commit, False), ("device", self._device, False),
                ("annotate", self._annotate, False), ("standby", self._standby, False),
                ("stream", self._stream, False), ("datamode", self._datamode, False),
                ("mount", self._mount, False), ("led", self._led, False),
                ("format", self._format, True), ("logfile", self._logfile, False),
                ("log", self._log, False), ("lock", self._lock, False), ("ilock", self._ilock, True),
                ("unlock", self._unlock, False), ("ecc", self._ecc, False),
                ("fractional", self._fractional, False), ("reset", self._reset, True),
                ("exit", self._exit, False), ("at", self._at, False))

    def _help(self, line, at, locked, beyond):  # 443-447
        self.say("HELP: help|echo|reset\r\n")

    def _echo(self, line, at, locked, beyond):  # 448-457: reads line[5] even past the NUL
        rest = beyond if len(line) == 4 else line[5:]
        if rest[:1] not in ("", "\0"):
            value = T.as_int16(self.atoi(rest.split("\0")[0]))
            if value in (0, 1):
                self.echo = value
        self.say(f"ECHO={self.echo}\r\n")

    def _id(self, line, at, locked, beyond):  # 458-461; AX6 Settings.c 451
        t = "CWA" if self.kind == "AX3" else "AX6"
        dev = self.dev
        dev_id = self.s.device_id + (1 if "id-mismatch" in dev.faults else 0)
        self.say(f"ID={t},{HARDWARE_VERSION[self.kind]:x},{SOFTWARE_VERSION[self.kind]},"
                 f"{dev_id},{self.s.session}\r\n")

    def _digit_arg(self, line, at, n) -> int:
        """``z = line[n+1] - '0'`` if ``line[n] != '\\0'`` (SAMPLE 466-469, STATUS 543-546)."""
        if at(n) == "\0":
            return 0
        return T.as_char(ord(at(n + 1)) - 48)

    def _sample(self, line, at, locked, beyond):  # 462-539
        z = self._digit_arg(line, at, 6)
        out = []
        if z in (0, 1):
            adc, mv, pct, full = self.dev.battery_reading()
            out.append(f"$BATT={adc},{mv},mV,{pct},{1 if full else 0}")
        if z in (0, 2):
            out.append("$LDR=512,512")
        if z in (0, 3):
            out.append("$TEMP=400,231,0.1dC")
        if z in (0, 4):
            packed, ms = self.dev.rtc_now_ms()
            out.append(f"$TIME={T.rtc_to_string(packed)}.{ms:03d}")
        if z in (0, 5):
            x, y, zz, gyro = self.dev.accel_sample()
            out.append(f"$ACCEL={x},{y},{zz}")
            out.append("$GYRO=" + (",".join(str(v) for v in gyro) if gyro else ""))
        self.say("".join(s + "\r\n" for s in out))

    def _status(self, line, at, locked, beyond):  # 540-597: one line per STATUS n
        z = self._digit_arg(line, at, 6)
        dev = self.dev
        out = []
        if z in (0, 1):
            out.append(f"TEST={SELF_TEST:04x}")
        if z in (0, 2):
            out.append(f"BATTHEALTH={dev.log_values[LOG_VALUE_BATTERY]}")
        if z in (0, 3):
            out.append(f"FTL=0,0,{FTL_SPARE},{FTL_PLANES}" + ",0" * FTL_PLANES)
        if z in (0, 4):
            out.append("CHECKSUM=0000")
        if z in (0, 5):
            out.append(f"RESTART={dev.log_values[LOG_VALUE_RESTART]}")
        if z in (0, 6):
            out.append("NAND=0000")
        if z in (0, 7):
            out.append("NANDID=" + ":".join(f"{b:02x}" for b in NAND_ID) + ",1")
        self.say("".join(s + "\r\n" for s in out))

    def _time(self, line, at, locked, beyond):  # 635-663
        if at(4) != "\0":
            t = T.rtc_from_string(line[5:])
            if t != 0:
                if locked:
                    self.say("ERROR: Locked.\r\n")
                else:
                    self.dev.set_rtc(t)
                    self.say(f"$TIME={T.rtc_to_string(t)}\r\n")
            else:
                self.say("ERROR: Problem parsing time.\r\n")
        else:
            self.say(f"$TIME={T.rtc_to_string(self.dev.rtc_now())}\r\n")

    def _tzone(self, line, at, locked, beyond):  # 664-681
        if at(5) != "\0":
            if at(6) == "\0":
                self.s.tzone = -1
            elif locked:
                self.say("ERROR: Locked.\r\n")
            else:
                self.s.tzone = T.as_int16(self.atoi(line[6:]))
        tz = self.s.tzone
        if tz == -1:
            self.say("TZONE=\r\n")
        else:
            self.say(f"TZONE={tz},{'-' if tz < 0 else '+'}{abs(tz) // 60:02d}:{abs(tz) % 60:02d}\r\n")

    def _date_setting(self, line, at, locked, n, attr, name):  # HIBERNATE 682-690, STOP 691-699
        if at(n) != "\0":
            if locked:
                self.say("ERROR: Locked.\r\n")
            else:
                setattr(self.s, attr, T.rtc_from_string(line[n + 1:]))
        self.say(f"{name}={T.rtc_to_string(getattr(self.s, attr))}\r\n")

    def _hibernate(self, line, at, locked, beyond):
        self._date_setting(line, at, locked, 9, "start", "HIBERNATE")

    def _stop(self, line, at, locked, beyond):
        self._date_setting(line, at, locked, 4, "stop", "STOP")

    def _lastchanged(self, line, at, locked, beyond):  # 700-703
        self.say(f"LASTCHANGED={T.rtc_to_string(self.s.last_change)}\r\n")

    def _number_setting(self, line, at, locked, n, attr, mask):
        if at(n) != "\0":
            if locked:
                self.say("ERROR: Locked.\r\n")
            else:
                setattr(self.s, attr, self.atoi(line[n + 1:]) & mask)
        return getattr(self.s, attr)

    def _maxsamples(self, line, at, locked, beyond):  # 704-712 (unsigned long)
        self.say(f"MAXSAMPLES={self._number_setting(line, at, locked, 10, 'maxsamples', T.U32)}\r\n")

    def _debug(self, line, at, locked, beyond):  # 713-721 (unsigned char)
        self.say(f"DEBUG={self._number_setting(line, at, locked, 5, 'debug', 0xFF)}\r\n")

    def _session(self, line, at, locked, beyond):  # 722-730 (unsigned long: wraps at 2^32)
        v = self._number_setting(line, at, locked, 7, "session", T.U32)
        if "session-mismatch" in self.dev.faults:
            v = (v + 1) & T.U32
        self.say(f"SESSION={v}\r\n")

    def _rate(self, line, at, locked, beyond):  # 731-739 (unsigned char); AX6 Settings.c 724-753
        s = self.s
        if at(4) != "\0":
            if locked:
                self.say("ERROR: Locked.\r\n")
            elif self.kind == "AX3":
                s.rate = self.atoi(line[5:]) & 0xFF
            else:
                s.rate = self.atoi(line[4:]) & 0xFF
                s.gyro = 0  # a missing gyro range turns the gyro off
                for i in range(5, 12):  # up to 7 characters past line[4]
                    ch = at(i)
                    if not 32 <= ord(ch) < 128:  # a control code (char is signed)
                        break
                    if "0" <= ch <= "9":
                        continue
                    j = i + 1 if ch == "," else i
                    s.gyro = self.atoi(line[j:]) & 0xFFFF
                    break
        hz = T.accel_frequency_for_rate(s.rate)
        tail = f",{s.gyro}" if self.kind == "AX6" else ""
        self.say(f"RATE={s.rate},{hz}{tail}\r\n")

    def _delayed_or_now(self, flags, countdown, what) -> None:
        """Delayed activation when mounted (the drive is dropped; the action runs after the
        countdown and re-presents it), else the action at once."""
        if self.dev.disk_mounted:
            self.dev.delay_action(flags | ACTION_REMOUNT, countdown)
            self.say(f"{what}: Delayed activation.\r\n")
        else:
            self.dev.run_action(flags)

    def _clear(self, line, at, locked, beyond):  # 740-775
        flags = 0
        low = line.lower()
        if locked:
            self.say("ERROR: Locked.\r\n")
        elif low.startswith("clear data"):
            flags = ACTION_DELETE | ACTION_CREATE
        elif low.startswith("clear all"):
            self.initialize()
            flags = ACTION_FORMAT_WIPE | ACTION_CREATE
        if flags:
            if self.dev.disk_mounted:
                self._delayed_or_now(flags, 2, "CLEAR")
            else:
                self.dev.run_action(flags)
                self.say("CLEAR\r\n")
        else:
            self.say("CLEAR: Use 'clear data' or 'clear all'.\r\n")

    def _commit(self, line, at, locked, beyond):  # 776-793
        if locked:
            self.say("ERROR: Locked.\r\n")
        else:
            self._delayed_or_now(ACTION_CREATE, 1, "COMMIT")

    def _device(self, line, at, locked, beyond):  # 794-804 (the USB serial follows at the next boot)
        if at(6) != "\0":
            new = self.atoi(line[6:])
            if locked:
                self.say("ERROR: Locked.\r\n")
            else:  # SettingsSetDeviceId (the emulated battery is always fit to program)
                self.s.device_id = new
                self.dev.rom_device_id = new
        rom = self.dev.rom_device_id
        rom = rom & 0xFFFF if rom >> 16 == 0xFFFF else rom  # SettingsGetDeviceId (Settings.c 79-93)
        self.say(f"DEVICE={self.s.device_id},{rom}\r\n")

    def _annotate(self, line, at, locked, beyond):  # 805-841
        if "0" <= at(8) <= "9" and "0" <= at(9) <= "9" and at(10) in ("\0", "="):
            n = int(at(8)) * 10 + int(at(9))
            if n < ANNOTATION_COUNT:
                if locked:
                    self.say("ERROR: Locked.\r\n")
                    return
                if at(10) == "=":
                    text = line[11:].encode("latin-1", "replace")[:ANNOTATION_SIZE]
                    self.s.annotation[n] = text + b" " * (ANNOTATION_SIZE - len(text))
                shown = "".join(" " if c < 32 else chr(c) for c in self.s.annotation[n])
                self.say(f"ANNOTATE{n:02d}={shown}\r\n")
            else:
                self.say(f"ERROR: Invalid annotation id {n}\r\n")
        else:
            self.say("ERROR: Usage is ANNOTATE##=\r\n")

    def _standby(self, line, at, locked, beyond):  # 1095
        self.say("STANDBY=0\r\n")

    def _stream(self, line, at, locked, beyond):  # 1096-1104 (no acknowledgement)
        if locked:
            self.say("ERROR: Locked.\r\n")
        else:
            self.stream = True
            self.dev.start_stream()

    def _datamode(self, line, at, locked, beyond):  # 1105-1122 (printed in batch mode too)
        if at(8) != "\0":
            i = T.as_int16(self.atoi(line[9:]))
            if i != -1:
                if locked:
                    self.say("ERROR: Locked.\r\n")
                else:
                    self.s.data_mode = i & 0xFF
        m = self.s.data_mode
        kind = {FORMAT_CSV: "CSV", FORMAT_CWA_PACKED: "CWA/packed",
                FORMAT_CWA_UNPACKED: "CWA/unpacked"}.get(m & 0x0F, "None")
        self.say(f"DATAMODE={m},{'single-file' if m & FORMAT_SINGLE_FILE else 'auto-number'},{kind}\r\n")

    def _mount(self, line, at, locked, beyond):  # 1123-1142
        value = T.as_int16(self.atoi(line[6:])) if at(5) != "\0" else -1
        if value in (0, 1):
            if locked:
                self.say("ERROR: Locked.\r\n")
            else:
                self.dev.set_mounted(bool(value))
        self.say(f"MOUNT={1 if self.dev.disk_mounted else 0}\r\n")

    def _led(self, line, at, locked, beyond):  # 1143-1152 (char ledOverride)
        if at(3) != "\0":
            self.led = T.as_char(T.as_int16(self.atoi(line[4:])))
        self.say(f"LED={self.led}\r\n")

    def _format(self, line, at, locked, beyond):  # 1153-1193
        if locked:
            self.say("ERROR: Locked.\r\n")
        elif at(6) != "\0" and at(7) in "QqWw" and at(7) != "\0":
            flags = ACTION_FORMAT_WIPE if at(7) in "Ww" else ACTION_FORMAT_QUICK
            if at(8) in "Cc" and at(8) != "\0":
                flags |= ACTION_CREATE  # create the data file with the current settings
            self._delayed_or_now(flags, 2, "FORMAT")
        elif at(6) != "\0" and at(7) in "Dd" and at(7) != "\0":
            if at(8) == "\0":  # FtlDestroy: the NAND is erased, no filesystem is left
                self.say("FORMAT: Destroy.\r\n")
                self.dev.destroy_drive()
            elif at(8) == "B":
                self.say("FORMAT: Destroy, including user-marked bad blocks.\r\n")
                self.dev.destroy_drive()
        else:
            self.say("ERROR: Must specify 'FORMAT Q' for quick or 'FORMAT W' for wipe, "
                     "+'C' for COMMIT.\r\n")

    def _logfile(self, line, at, locked, beyond):  # 1194-1217
        if not self.dev.disk_mounted:
            if locked:
                self.say("ERROR: Locked.\r\n")
            elif at(7) != "\0":
                packed, ms = self.dev.rtc_now_ms()
                with open(self.dev.drive_dir() / LOG_FILE, "ab") as f:
                    f.write(f"{T.rtc_to_string(packed)}.{ms:03d},{line[8:]}\r\n".encode("latin-1"))
        else:
            self.say("ERROR: Cannot while attached and mounted.\r\n")

    def _log(self, line, at, locked, beyond):  # 1218-1243
        entries = self.dev.log_entries
        if locked:
            self.say("ERROR: Locked.\r\n")
        elif at(3) != "\0":
            now = self.dev.rtc_now()
            text = line[4:]
            self.say(f"LOG,0,0x{LOG_CATEGORY_USER:04x},{T.rtc_to_string(now)},{text}\r\n")
            entries.insert(0, (LOG_CATEGORY_USER, now, text[:25]))  # LOG_SIZE - 7
            del entries[LOG_COUNT:]
        else:
            out = ""
            for index in range(LOG_COUNT - 1, -1, -1):
                if index < len(entries):
                    st, ts, text = entries[index]
                    out += f"LOG,{index},0x{st:04x},{T.rtc_to_string(ts)},{text}\r\n"
            self.say(out + "OK\r\n")

    def _lock_status(self) -> int:
        code = self.dev.config.get(CONFIG_LOCK, 0xFFFF)
        return (1 if self.lock_code else 0) + (2 if code not in (0, 0xFFFF) else 0)

    def _code_arg(self, line, at, n, limit) -> int:
        """LOCK/ILOCK's "more careful parsing" (1248, 1283)."""
        if at(n) in ":= " and "0" <= at(n + 1) <= "9" and len(line) <= limit:
            return T.as_int16(self.atoi(line[n + 1:])) & 0xFFFF
        return 0xFFFF

    def _lock(self, line, at, locked, beyond):  # 1244-1278
        i = self._code_arg(line, at, 4, 10)
        if i != 0xFFFF:
            if locked:
                self.say("ERROR: Locked.\r\n")
                return
            self.lock_code = i
        self.say(f"LOCK={self._lock_status()}\r\n")

    def _ilock(self, line, at, locked, beyond):  # 1279-1302 (kept in program memory)
        i = self._code_arg(line, at, 5, 11)
        if i != 0xFFFF:
            if locked:
                self.say("ERROR: Locked.\r\n")
            else:
                self.dev.config[CONFIG_LOCK] = i
                self.say(f"ILOCK={0 if i == 0 else 1}\r\n")
        else:
            code = self.dev.config.get(CONFIG_LOCK, 0xFFFF)
            self.say(f"ILOCK={0 if code in (0, 0xFFFF) else 1}\r\n")

    def _unlock(self, line, at, locked, beyond):  # 1303-1331
        if at(6) == "\0":
            return
        i = T.as_int16(self.atoi(line[7:])) & 0xFFFF
        if locked and i != self.lock_code:
            self.dev.pause(1.0)  # DelayMs(1000)
            self.say("ERROR: Locked.\r\n")
            return
        if self.lock_code:
            code = self.dev.config.get(CONFIG_LOCK, 0xFFFF)
            self.lock_code = 0
            if code not in (0, 0xFFFF) and not self.dev.disk_mounted:  # initially locked: mount now
                self.dev.set_mounted(True)
        self.say("LOCK=0\r\n")

    def _config_char(self, line, at, locked, value_at: int, name: str, key: int) -> None:
        """ECC and FRACTIONAL: with text after the command (at ``value_at``) and not locked, the
        value parsed from line + 4 (both handlers parse from there) is kept as a char and in
        program memory (``key``); then ``<NAME>=<value>``."""
        attr = name.lower()
        if at(value_at) != "\0":
            if locked:
                self.say("ERROR: Locked.\r\n")
                return
            setattr(self, attr, T.as_char(self.atoi(line[4:])))
            self.dev.config[key] = getattr(self, attr) & 0xFFFF
        self.say(f"{name}={getattr(self, attr)}\r\n")

    def _ecc(self, line, at, locked, beyond):  # 1332-1349
        self._config_char(line, at, locked, 3, "ECC", CONFIG_ECC)

    def _fractional(self, line, at, locked, beyond):  # 1350-1367 (parses from line + 4)
        self._config_char(line, at, locked, 10, "FRACTIONAL", CONFIG_FRACTIONAL)

    def _reset(self, line, at, locked, beyond):  # 1368-1374: restart 1-2 s later
        self.say("RESET\r\nOK\r\n")
        self.dev.delay_action(ACTION_RESTART, 2)

    def _exit(self, line, at, locked, beyond):  # 1375-1378
        self.say("INFO: You'll have to close the terminal window yourself!\r\n")

    def _at(self, line, at, locked, beyond):  # 1379-1382
        self.say("OK\r\n")
