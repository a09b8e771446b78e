"""Axivity's own OmApi (the C library OMGui uses) drives the emulated AX3 and AX6, call for call.

tests/omapi/harness.c is built with gcc together with libomapi's portable sources (vendored at
``<shared>/vendor/libomapi``, BSD-2, a test client only) and our device finder (tests/omapi/finder.c,
in place of the udev finder), which reports the emulated device's USB serial, pseudo-terminal and
drive folder to OmApi's ``OmDeviceDiscovery``. The harness then runs OMGui's read phase, a full
download, OMGui's Clear (``FORMAT QC``) with the data file read back, and OMGui's Record sequence
with every setting read back, printing one line per call. This module asserts on those lines:
every call succeeds, each value equals what the emulator holds or what was set, the download
has the SHA-256 of the emulated data file, and nothing is left unread on the port beyond what
the firmware itself leaves (see ``expected_unread``).

Where the vendored sources are: $STILLPOINT_SHARED, else the folder two above
$STILLPOINT_REAL_DATA (``<shared>/data/real``), else ``../shared`` beside the repository. Without
gcc or the sources the tests fail in CI (CI or STILLPOINT_REAL_DATA set) and skip elsewhere.
"""

from __future__ import annotations

import datetime as dt
import fcntl
import hashlib
import os
import re
import shutil
import struct
import subprocess
import tempfile
import termios
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from stillpoint.drivers import constants as C
from stillpoint.drivers.ax import firmware_shell as FS
from stillpoint.drivers.ax import firmware_text as FT
from stillpoint.drivers.ax.emulator import EmulatedDevice
from stillpoint.engine.sim.record import device_recording
from stillpoint.drivers.cwa_layout import parse_header

REPO = Path(__file__).resolve().parents[3]
OUR_SOURCES = ("tests/omapi/harness.c", "tests/omapi/finder.c", "tests/omapi/finder.h")
VENDOR_SOURCES = tuple(f"src/omapi-{m}.c"
                       for m in ("main", "internal", "status", "settings", "download", "reader"))
VENDOR_HEADERS = ("include/omapi.h", "src/omapi-internal.h")
CFLAGS = ("-O1", "-w", "-pthread")
HARNESS_TIMEOUT_S = 60  # a run takes ~6 s; a silent device costs OmApi 2 s per command

# OmApi's return codes and download status (include/omapi.h)
OM_OK = 0
OM_DOWNLOAD_COMPLETE = 3


@dataclass(frozen=True)
class Device:
    """An emulated device and the settings OMGui's Record dialog gives it."""

    device_id: int
    session: int
    record_session: int
    record_rate_hz: int
    record_range_g: int
    record_gyro_dps: int  # 0: the Record dialog's gyro off (the AX3 has none)
    record_debug: int  # OMGui: 3 with "flash during recording", else 0
    metadata: str = "_sc=OMAPI&_se=left_wrist&_p=P01&_sn=conformance"


DEVICES = {
    # an AX3 id above 65535: firmware V50 keeps 32-bit ids but writes only the low 16 bits of the id
    # into the data file's header (see cwa_layout / constants.CWA_UPPER_ID_UNSET)
    "AX3": Device(device_id=123456, session=4242, record_session=123456, record_rate_hz=50,
                  record_range_g=4, record_gyro_dps=0, record_debug=3),
    "AX6": Device(device_id=601234, session=77, record_session=C.AX_SESSION_MAX, record_rate_hz=200,
                  record_range_g=16, record_gyro_dps=500, record_debug=3),
}

# Calls that never touch the port (OmApi's own state, the drive, or the download thread); "header" is
# the harness reading the data file's header fields itself.
PORTLESS = {"OmStartup", "OmShutdown", "OmGetDeviceIds", "OmGetDeviceSerial", "OmGetDevicePort",
            "OmGetDevicePath", "OmGetDataFileSize", "OmGetDataRange", "OmBeginDownloading",
            "OmWaitForDownload", "OmReaderOpen", "OmReaderMetadata", "header"}


# ----------------------------------------------------------------------------- finding and building
def shared_dir() -> Path:
    if os.environ.get("STILLPOINT_SHARED"):
        return Path(os.environ["STILLPOINT_SHARED"])
    real = os.environ.get("STILLPOINT_REAL_DATA")
    if real:
        p = Path(real)
        return (p if p.is_absolute() else REPO / p).parent.parent  # <shared>/data/real
    return REPO.parent / "shared"


def in_ci() -> bool:
    return bool(os.environ.get("CI") or os.environ.get("STILLPOINT_REAL_DATA"))


def missing(reason: str):
    if in_ci():
        pytest.fail(f"OmApi conformance cannot run: {reason}")
    pytest.skip(f"OmApi conformance skipped: {reason}")


@pytest.fixture(scope="session")
def harness() -> Path:
    """The harness executable, built once per source hash (tempdir/stillpoint-omapi-<hash>)."""
    gcc = shutil.which("gcc")
    if gcc is None:
        missing("gcc is not installed")
    vendor = shared_dir() / "vendor" / "libomapi"
    absent = [n for n in VENDOR_SOURCES + VENDOR_HEADERS if not (vendor / n).is_file()]
    if absent:
        missing(f"the vendored OmApi sources are not in {vendor} ({', '.join(absent)} missing)")
    version = subprocess.run([gcc, "-dumpfullversion"], capture_output=True, text=True, timeout=30).stdout
    h = hashlib.sha256(version.encode() + " ".join(CFLAGS).encode())
    for path in [vendor / n for n in VENDOR_SOURCES + VENDOR_HEADERS] + [REPO / n for n in OUR_SOURCES]:
        h.update(path.name.encode() + b"\0" + path.read_bytes())
    out = Path(tempfile.gettempdir()) / f"stillpoint-omapi-{h.hexdigest()[:16]}"
    exe = out / "harness"
    if exe.is_file():
        return exe
    out.mkdir(parents=True, exist_ok=True)
    tmp = out / f"harness.{os.getpid()}.tmp"
    cmd = [gcc, *CFLAGS, f"-I{vendor / 'include'}", f"-I{vendor / 'src'}", f"-I{REPO / 'tests/omapi'}",
           "-o", str(tmp), str(REPO / "tests/omapi/harness.c"), str(REPO / "tests/omapi/finder.c"),
           *[str(vendor / n) for n in VENDOR_SOURCES]]
    built = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    if built.returncode != 0 and re.search(r"fatal error: (stdio|stdlib|string)\.h", built.stderr):
        missing("gcc has no C library headers (libc6-dev)")
    assert built.returncode == 0, f"building the OmApi harness failed:\n{built.stderr}"
    os.replace(tmp, exe)
    return exe


# ----------------------------------------------------------------------------- one run per device type
@dataclass
class Run:
    kind: str
    device: Device
    emu: EmulatedDevice
    calls: dict = field(default_factory=dict)  # (phase, call) -> {"rc": int, key: str}
    lines: list = field(default_factory=list)
    stderr: str = ""
    before: dict = field(default_factory=dict)  # what the emulator held before OmApi's first call
    after: dict = field(default_factory=dict)
    download: bytes = b""
    data_after: bytes = b""
    files_after: list = field(default_factory=list)  # the drive's root after the last phase
    pending_at_end: tuple = (0, 0)  # (bytes queued on the pty, bytes the emulator has not sent)

    def call(self, phase: str, name: str) -> dict:
        assert (phase, name) in self.calls, (
            f"{self.kind}: no '{phase} {name}' line; the harness printed:\n" + "\n".join(self.lines)
            + f"\nstderr:\n{self.stderr}")
        return self.calls[(phase, name)]


def unescape(value: str) -> str:
    return value.encode("ascii").decode("unicode_escape")


def parse_lines(text: str) -> tuple[dict, list]:
    calls, lines = {}, []
    for line in text.splitlines():
        lines.append(line)
        phase, name, *items = line.split(" ")
        values = {}
        for item in items:
            key, _, value = item.partition("=")
            values[key] = unescape(value)
        values["rc"] = int(values["rc"])
        calls[(phase, name)] = values
    return calls, lines


def pty_queued(path: str) -> int:
    fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    try:
        return struct.unpack("i", fcntl.ioctl(fd, termios.FIONREAD, b"\0\0\0\0"))[0]
    finally:
        os.close(fd)


def emulator_state(emu: EmulatedDevice) -> dict:
    s = emu.settings
    return {"session": emu.session_id, "rate_code": int(s["rate"]), "gyro": int(s.get("gyro") or 0),
            "hibernate": s["hibernate"], "stop": s["stop"], "maxsamples": int(s["maxsamples"]),
            "debug": int(s["debug"]), "metadata": "".join(s["annotate"]).rstrip(" "),
            "battery_pct": emu.battery()[2], "time": emu.device_now(),
            "battery_health": emu.log_values[FS.LOG_VALUE_BATTERY], "ecc": emu.shell.ecc,
            "locked": int(emu.locked), "last_change": FT.rtc_to_string(emu.shell.s.last_change),
            "accel": tuple(emu.accel_sample()[:3]), "gyro_sample": emu.accel_sample()[3]}


@pytest.fixture(scope="module", params=sorted(DEVICES))
def run(request, harness, tmp_path_factory) -> Run:
    kind = request.param
    dev = DEVICES[kind]
    root = tmp_path_factory.mktemp(f"omapi-{kind}")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("STILLPOINT_RUNTIME_DIR", str(root / "runtime"))
        emu = EmulatedDevice(root / "device", dev.device_id, kind, session_id=dev.session, make_recording=device_recording, days=0.005,
                             seed=7, remount_s=0.2)
        r = Run(kind, dev, emu)
        try:
            emu.plug(pty=True)
            (emu.volume / "NOTES.TXT").write_text("a file a user left on the drive\r\n")
            r.before = emulator_state(emu)
            data = emu.data_file.read_bytes()
            r.before.update(size=len(data), sha256=hashlib.sha256(data).hexdigest())
            destination = root / "download.cwa"
            args = [str(harness), emu.serial, emu.pty_path, str(emu.volume), str(destination),
                    str(dev.record_session), dev.metadata, str(dev.record_rate_hz), str(dev.record_range_g),
                    str(dev.record_gyro_dps), str(dev.record_debug)]
            try:
                proc = subprocess.run(args, capture_output=True, text=True, timeout=HARNESS_TIMEOUT_S,
                                      env={k: v for k, v in os.environ.items() if k != "OMDEBUG"})
            except subprocess.TimeoutExpired as e:
                out = e.stdout.decode() if isinstance(e.stdout, bytes) else (e.stdout or "")
                pytest.fail(f"{kind}: the OmApi harness did not finish in {HARNESS_TIMEOUT_S} s; "
                            f"it printed:\n{out}")
            r.calls, r.lines = parse_lines(proc.stdout)
            r.stderr = proc.stderr
            assert proc.returncode == 0, (
                f"{kind}: harness exit {proc.returncode}\n{proc.stdout}\n{proc.stderr}")
            r.pending_at_end = (pty_queued(emu.pty_path), emu.pending())
            r.after = emulator_state(emu)
            r.download = destination.read_bytes() if destination.exists() else b""
            r.data_after = emu.data_file.read_bytes()
            r.files_after = sorted(p.name for p in emu.volume.iterdir())
        finally:
            emu.shutdown()
    return r


# ----------------------------------------------------------------------------- helpers for expectations
def omapi_time(setting: str) -> str:
    """An emulator start/stop setting as the harness prints OmApi's OM_DATETIME ("0", "-1", ISO)."""
    if setting in ("0", "-1"):
        return setting
    return dt.datetime.strptime(setting, "%Y/%m/%d,%H:%M:%S").strftime("%Y-%m-%dT%H:%M:%S")


def expected_unread(run: Run, name: str) -> str:
    """What the firmware itself leaves on the port once OmApi has returned from a call.

    OmApi's line reader (omapi-internal.c OmPortReadLine) returns at the CR of a reply's CR LF, so
    the LF of the last line read stays queued; the next command's read skips it as an empty line.
    ``SAMPLE 5`` prints ``$ACCEL=`` and then ``$GYRO=`` (Firmware/AX3/Firmware/src/Settings.c 515-537,
    Firmware/AX6/Firmware/src/Settings.c 506-528): OmGetAccelerometer stops at the first, so the
    ``$GYRO=`` line stays too (empty on an AX3, the gyro sample on an AX6). After OmCommit the
    harness has taken the firmware's second line (``COMMIT``) off the port itself (late=).
    """
    if name in PORTLESS or name == "OmCommit":
        return ""
    if name == "OmGetAccelerometer":
        gyro = run.before["gyro_sample"]
        return "\n$GYRO=" + (",".join(str(v) for v in gyro) if gyro else "") + "\r\n"
    return "\n"


# ----------------------------------------------------------------------------- the tests
def test_every_omapi_call_returns_ok(run):
    assert ("end", "OmShutdown") in run.calls, "the harness did not reach the end:\n" + "\n".join(run.lines)
    failed = [line for line in run.lines if line.split(" ")[2] != "rc=0"]
    assert not failed, f"{run.kind}: OmApi calls that failed against the emulator:\n" + "\n".join(failed)


def test_nothing_is_left_unread_on_the_port(run):
    wrong = []
    for (phase, name), values in run.calls.items():
        unread, expected = values.get("unread", ""), expected_unread(run, name)
        if unread != expected:
            wrong.append(f"{phase} {name}: left {unread!r}, the firmware leaves {expected!r}")
    assert not wrong, f"{run.kind}: bytes left on the port after a call:\n" + "\n".join(wrong)
    # OmCommit returns at "COMMIT: Delayed activation."; the firmware's "COMMIT" follows once done
    assert run.call("record", "OmCommit")["late"] == "\nCOMMIT\r\n"
    assert run.pending_at_end == (0, 0), f"{run.kind}: bytes still queued at the end (pty, emulator)"


def test_read_phase_values_are_what_the_emulator_holds(run):
    dev, b = run.device, run.before
    assert run.call("read", "OmGetDeviceIds")["count"] == "1"
    assert int(run.call("read", "OmGetDeviceIds")["first"]) == dev.device_id
    assert run.call("read", "OmGetDeviceSerial")["serial"] == run.emu.serial
    assert run.call("read", "OmGetDevicePort")["port"] == run.emu.pty_path
    assert run.call("read", "OmGetDevicePath")["path"] == str(run.emu.volume)
    # OmGetVersion: the ID reply prints the hardware version in hex and OmApi reads it with atoi,
    # adding the digit of an "AX#" type in the high word (omapi-status.c OmGetVersion)
    hardware = int(f"{FS.HARDWARE_VERSION[run.kind]:x}") | (6 << 16 if run.kind == "AX6" else 0)
    version = run.call("read", "OmGetVersion")
    assert (int(version["firmware"]), int(version["hardware"])) == (FS.SOFTWARE_VERSION[run.kind], hardware)
    assert int(run.call("read", "OmGetBatteryHealth")["value"]) == b["battery_health"]
    # OmGetMemoryHealth: spare blocks - the worst plane's bad blocks - 6 (omapi-status.c); no bad blocks
    assert int(run.call("read", "OmGetMemoryHealth")["value"]) == FS.FTL_SPARE - 6
    lock = run.call("read", "OmIsLocked")
    assert (int(lock["locked"]), int(lock["has_code"])) == (b["locked"], 0)
    assert run.call("read", "OmGetLastConfigTime")["time"] == omapi_time(b["last_change"])
    assert int(run.call("read", "OmGetEcc")["value"]) == b["ecc"]
    xyz = run.call("read", "OmGetAccelerometer")
    assert (int(xyz["x"]), int(xyz["y"]), int(xyz["z"])) == b["accel"]
    level = int(run.call("read", "OmGetBatteryLevel")["value"])
    assert b["battery_pct"] <= level <= run.after["battery_pct"]
    t = dt.datetime.fromisoformat(run.call("read", "OmGetTime")["time"])
    assert b["time"] - dt.timedelta(seconds=1) <= t <= run.after["time"]
    delays = run.call("read", "OmGetDelays")
    assert (delays["start"], delays["stop"]) == (omapi_time(b["hibernate"]), omapi_time(b["stop"]))
    assert int(run.call("read", "OmGetSessionId")["session"]) == dev.session == b["session"]
    assert int(run.call("read", "OmGetMaxSamples")["value"]) == b["maxsamples"]
    assert run.call("read", "OmGetMetadata")["metadata"] == b["metadata"]
    accel = run.call("read", "OmGetAccelConfig")
    assert int(accel["rate"]) == C.cwa_rate_hz(b["rate_code"])
    assert int(accel["range"]) == C.cwa_range_g(b["rate_code"])
    assert int(accel["gyro"]) == (b["gyro"] if run.kind == "AX6" else 0)
    assert int(run.call("read", "OmSelfTest")["value"]) == 0
    assert int(run.call("read", "OmGetDataFileSize")["size"]) == b["size"]
    rng = run.call("read", "OmGetDataRange")
    assert int(rng["block"]) == C.CWA_SECTOR_BYTES
    assert int(rng["offset"]) * C.CWA_SECTOR_BYTES == C.CWA_HEADER_BYTES
    assert int(rng["blocks"]) == (b["size"] - C.CWA_HEADER_BYTES) // C.CWA_SECTOR_BYTES


def test_full_download_has_the_data_files_sha256(run):
    wait = run.call("download", "OmWaitForDownload")
    assert (int(wait["status"]), int(wait["value"])) == (OM_DOWNLOAD_COMPLETE, 100)
    assert len(run.download) == run.before["size"]
    assert hashlib.sha256(run.download).hexdigest() == run.before["sha256"]


def test_omgui_clear_leaves_a_header_that_never_records(run):
    assert run.call("cleared", "OmGetSessionId")["session"] == "0"
    delays = run.call("cleared", "OmGetDelays")
    assert (delays["start"], delays["stop"]) == ("-1", "-1")
    accel = run.call("cleared", "OmGetAccelConfig")
    assert (accel["rate"], accel["range"]) == ("100", "8")  # OM_ACCEL_DEFAULT_RATE/RANGE (omapi.h)
    assert run.call("cleared", "OmGetMetadata")["metadata"] == ""
    # FORMAT makes a new filesystem (AX3 Settings.c 387, FsFtlFormat): no other file survives; the record
    # phase after it adds none
    assert run.files_after == [C.AX_DATA_FILE]
    # the data file holds only a header, and that header says "never record", session 0
    assert int(run.call("cleared", "OmGetDataFileSize")["size"]) == C.CWA_HEADER_BYTES
    assert run.call("cleared", "OmGetDataRange")["blocks"] == "0"
    meta = run.call("cleared", "OmReaderMetadata")
    header_id = run.device.device_id & 0xFFFF if run.kind == "AX3" else run.device.device_id
    assert (int(meta["device"]), meta["session"], meta["metadata"]) == (header_id, "0", "")
    header = run.call("cleared", "header")
    assert (header["start_raw"], header["stop_raw"]) == ("0xffffffff", "0xffffffff")
    assert (header["session"], header["rate_code"]) == ("0", str(C.cwa_rate_code(100, 8)))


def test_omgui_record_settings_read_back(run):
    dev = run.device
    code = C.cwa_rate_code(dev.record_rate_hz, dev.record_range_g)
    synced = run.call("record", "OmGetTime")
    assert 0 <= int(synced["delta_s"]) <= 5  # OmDevice.SyncTime: read back within 5 s of the time set
    assert run.call("record", "OmGetTime(tick)")["ticked"] == "1"
    delays = run.call("record", "OmSetDelays")
    # through OmApi
    assert int(run.call("recorded", "OmGetSessionId")["session"]) == dev.record_session
    assert run.call("recorded", "OmGetMetadata")["metadata"] == dev.metadata
    assert run.call("recorded", "OmGetMaxSamples")["value"] == "0"
    accel = run.call("recorded", "OmGetAccelConfig")
    assert (int(accel["rate"]), int(accel["range"]), int(accel["gyro"])) == (
        dev.record_rate_hz, dev.record_range_g, dev.record_gyro_dps)
    got = run.call("recorded", "OmGetDelays")
    assert (got["start"], got["stop"]) == (delays["start"], delays["stop"])
    assert int(run.call("recorded", "OmCommand(DEBUG)")["value"]) == dev.record_debug
    # the commit stamps the header's last-change time with the device clock (AX3 Logger.c 438)
    changed = run.call("recorded", "OmGetLastConfigTime")["time"]
    assert changed == omapi_time(run.after["last_change"])
    changed_at = dt.datetime.fromisoformat(changed)
    assert dt.datetime.fromisoformat(synced["time"]) <= changed_at <= run.after["time"]
    # the header the commit wrote, through OmApi's reader
    meta = run.call("recorded", "OmReaderMetadata")
    assert (meta["session"], meta["metadata"]) == (str(dev.record_session), dev.metadata)
    header = run.call("recorded", "header")
    assert (header["start"], header["stop"]) == (delays["start"], delays["stop"])
    assert (header["rate_code"], header["debug"]) == (str(code), str(dev.record_debug))
    assert int(run.call("recorded", "OmGetDataFileSize")["size"]) == C.CWA_HEADER_BYTES
    # ... through stillpoint's own parser, and in the emulator
    h = parse_header(run.data_after)
    assert (h["session_id"], h["rate_code"], h["flash_led"]) == (dev.record_session, code, dev.record_debug)
    assert h["annotation"] == dev.metadata
    assert (h["logging_start"], h["logging_end"]) == (delays["start"] + "Z", delays["stop"] + "Z")
    if run.kind == "AX6":
        assert h["gyro_range_dps"] == dev.record_gyro_dps
    a = run.after
    assert (a["session"], a["rate_code"], a["maxsamples"], a["debug"], a["metadata"]) == (
        dev.record_session, code, 0, dev.record_debug, dev.metadata)
    if run.kind == "AX6":
        assert a["gyro"] == dev.record_gyro_dps
