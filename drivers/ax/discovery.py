"""Finding attached AX3/AX6 devices: serial port + drive, paired through the USB device.

A port counts only if its VID:PID is 04D8:0057 (Microchip's generic composite ID, never enough
alone) and its USB serial number starts ``CWA``/``AX6`` and ends in a device id (usb-protocols.md
A1-A2); the manufacturer string is not checked (on Windows pyserial reports the driver INF's
manufacturer, never "Newcastle University"). The station additionally requires a valid ``ID``
reply naming the same device id before it touches the device.

A drive belongs to a port when both hang below the same USB device: on Linux the same sysfs
device folder (``usb_linux``), on Windows and macOS the same USB serial number (``usb_windows``,
``usb_macos``). The volume label is never used for a drive whose USB device the OS reports, so
relabelled drives and ids above 9,999,999 (a 10-digit serial, a 7-digit label) pair. Only a drive
the OS gives no USB device for (macOS without ``SPUSBDataType``, a Windows disk without a serial,
other systems: the mount table) is paired by the number in its label ``AX3??_<id>`` /
``AX6??_<id>``. A mounted drive counts only if its root holds ``CWA-DATA.CWA``. A port whose
drive is present but not mounted (a headless Linux station after a COMMIT) carries the block
device, which ``mount`` can mount; a port without a drive is reported with the reason.

Backends are injectable: ``SystemBackend`` (this OS's enumeration; ``LinuxBackend``,
``WindowsBackend``, ``MacBackend``, ``LabelBackend``), ``EmulatedBackend`` (the emulator
registry, see ``registry``), ``CombinedBackend`` (both; the default). A backend has ``ports()``
and ``drives()`` (or, label-only, ``volumes()``: (mount point, label) pairs), and may offer
``mount(attached)``. An enumeration command (PowerShell, ``system_profiler``) is bounded by
``ENUMERATION_TIMEOUT_S`` and its answer reused for ``ENUMERATION_REFRESH_S``.

``discover(backend, port=..., volume=...)`` takes manual overrides (a port not enumerated as an
AX, a drive mounted elsewhere); an override that names nothing usable is one line naming the
option (``OverrideError``).
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable, Optional

from .. import constants as C
from . import registry
from stillpoint.engine.core.errors import StillpointError
from .errors import DeviceError

_LABEL_RE = re.compile(r"^(AX[36])[0-9A-Fa-f]{0,2}_0*(\d+)$")
_SERIAL_ID_RE = re.compile(r"(\d+)\s*$")
ENUMERATION_TIMEOUT_S = 20.0  # one PowerShell / system_profiler call (a cold CIM start takes seconds)
ENUMERATION_REFRESH_S = 2.0  # reuse an enumeration command's answer this long


@dataclass
class PortInfo:
    """What USB enumeration says about one serial port."""

    device: str  # /dev/ttyACM0, COM5, /dev/cu.usbmodem14101, /dev/pts/5 or axemu://CWA17_12345
    serial_number: Optional[str]
    manufacturer: Optional[str]
    vid: Optional[int]
    pid: Optional[int]
    location: Optional[str] = None  # USB port path (dock slot)
    emulated: bool = False
    faults: tuple = ()
    control: Optional[str] = None
    media: Optional[str] = None  # emulated: folder its drive mounts under
    read_bps: Optional[float] = None  # emulated: the drive's read speed (None: as fast as the disk)
    usb_key: Optional[str] = None  # the USB device it belongs to (None: the OS did not say)


@dataclass
class DriveInfo:
    """One filesystem of a USB drive: where it is mounted (None: present, not mounted)."""

    mount: Optional[str]
    label: Optional[str]
    usb_key: Optional[str] = None  # the USB device it belongs to (None: pair by label)
    block_device: Optional[str] = None  # /dev/sdb1, disk4s1, \\.\PHYSICALDRIVE2, emulated folder
    root: Optional[str] = None  # where its files are read (default: the mount point)
    hint: Optional[str] = None  # how to mount it by hand, when it is not mounted

    @property
    def files(self) -> Optional[str]:
        return self.root or self.mount


@dataclass
class Attached:
    """One device as the station sees it (``problem`` says why it cannot be used yet)."""

    device_id: int
    device_type: str
    serial: str
    port: str
    volume: Optional[str]
    slot: str
    emulated: bool = False
    faults: tuple = ()
    control: Optional[str] = None
    problem: Optional[str] = None
    read_bps: Optional[float] = None  # emulated drives: USB read speed to emulate
    block_device: Optional[str] = None  # its drive is present but not mounted (see ``mount``)
    paired_by: str = "usb"  # usb | label | manual

    @property
    def data_file(self) -> Optional[Path]:
        return Path(self.volume) / C.AX_DATA_FILE if self.volume else None

    def to_dict(self) -> dict:
        from dataclasses import asdict
        d = asdict(self)
        d["faults"] = list(self.faults)
        return d


def device_id_of_serial(serial: str) -> Optional[int]:
    """OmApi/axconfig rule: the trailing decimal number of the USB serial string."""
    m = _SERIAL_ID_RE.search(serial or "")
    return int(m.group(1)) if m else None


def device_type_of_serial(serial: str) -> Optional[str]:
    for prefix, kind in C.AX_SERIAL_PREFIXES.items():
        if (serial or "").upper().startswith(prefix):
            return kind
    return None


def is_ax_port(p: PortInfo) -> bool:
    """VID:PID, serial prefix and a device id in the serial (no manufacturer filter)."""
    return (p.vid == C.AX_USB_VID and p.pid == C.AX_USB_PID
            and device_type_of_serial(p.serial_number or "") is not None
            and device_id_of_serial(p.serial_number or "") is not None)


def label_device(label: Optional[str]) -> Optional[tuple[str, int]]:
    """``AX317_12345`` -> ("AX3", 12345); None if not an AX volume label."""
    m = _LABEL_RE.match(label or "")
    return (m.group(1).upper(), int(m.group(2))) if m else None


def serial_key(serial: Optional[str]) -> Optional[str]:
    """The pairing key of a USB device known only by its serial number (Windows, macOS)."""
    return f"serial:{serial.strip().upper()}" if serial and serial.strip() else None


def _unescape(s: str) -> str:
    return re.sub(r"\\([0-7]{3})", lambda m: chr(int(m.group(1), 8)), s)


def parse_mountinfo(text: str, by_label: Optional[dict] = None) -> list[tuple[str, str]]:
    """(mount point, label) for every mount in ``/proc/self/mountinfo`` text. The label comes
    from ``by_label`` (device node -> label, from ``/dev/disk/by-label``), else the mount
    folder's name."""
    out = []
    by_label = by_label or {}
    for line in text.splitlines():
        parts = line.split(" ")
        if len(parts) < 10 or "-" not in parts:
            continue
        mnt = _unescape(parts[4])
        sep = parts.index("-")
        source = parts[sep + 2] if len(parts) > sep + 2 else ""
        label = by_label.get(os.path.realpath(source)) if source.startswith("/dev/") else None
        out.append((mnt, label or os.path.basename(mnt.rstrip("/"))))
    return out


def _by_label() -> dict:
    d = Path("/dev/disk/by-label")
    out = {}
    if d.is_dir():
        for p in d.iterdir():
            try:
                out[os.path.realpath(p)] = _unescape(p.name.replace("\\x20", " "))
            except OSError:
                pass
    return out


def _pyserial_ports() -> list:
    try:
        from serial.tools import list_ports
        return list(list_ports.comports())
    except Exception:  # noqa: BLE001 - no serial support on this system: no ports
        return []


_OUTPUTS: dict = {}  # command -> (monotonic time, stdout): the last answer of each command


def _run_text(cmd: list[str]) -> str:
    """stdout of an enumeration command; an OSError or a non-zero exit raise ``OSError``. An
    answer younger than ``ENUMERATION_REFRESH_S`` is reused: the station asks for the drives
    every pass and, while it waits for a drive, ten times a second, and a PowerShell or
    system_profiler start costs about a second of CPU."""
    import time
    key = tuple(cmd)
    hit = _OUTPUTS.get(key)
    if hit is not None and time.monotonic() - hit[0] < ENUMERATION_REFRESH_S:
        return hit[1]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=ENUMERATION_TIMEOUT_S)
    if r.returncode != 0:
        raise OSError(f"{cmd[0]} exited {r.returncode}: {(r.stderr or '').strip()[:200]}")
    _OUTPUTS[key] = (time.monotonic(), r.stdout)
    return r.stdout


# ----------------------------------------------------------------------------- OS backends
class LinuxBackend:
    """Linux: ports and drives from sysfs, paired through the USB device folder (``usb_linux``).
    ``mount`` mounts a present, unmounted drive (``mount.mount_block_device``)."""

    def __init__(self, usb=None, mounter: Optional[Callable[[Optional[str]], None]] = None):
        from .usb_linux import LinuxUsb
        self.usb = usb or LinuxUsb()
        self.mounter = mounter

    def ports(self) -> list[PortInfo]:
        return [PortInfo(tty, d.serial, d.manufacturer, d.vid, d.pid, d.name,
                         usb_key=f"sysfs:{d.sys_path}")
                for d in self.usb.devices() for tty in d.ttys]

    def drives(self) -> list[DriveInfo]:
        return [DriveInfo(v.mount, v.label, f"sysfs:{d.sys_path}", v.block_device,
                          hint=f"udisksctl mount -b {v.block_device}")
                for d in self.usb.devices() for v in d.drives]

    def mount(self, att: "Attached") -> None:
        from .mount import mount_block_device
        (self.mounter or mount_block_device)(att.block_device)


class WindowsBackend:
    """Windows: ports from pyserial, drives from the CIM disk classes (``usb_windows``), paired
    by the USB serial number. ``list_ports``/``run``/``root_of`` are injectable for tests."""

    def __init__(self, list_ports: Callable[[], list] = _pyserial_ports,
                 run: Callable[[list], str] = _run_text, root_of: Callable[[str], str] = str):
        self.list_ports, self.run, self.root_of = list_ports, run, root_of
        self.drive_error: Optional[str] = None

    def ports(self) -> list[PortInfo]:
        from .usb_windows import port_serial
        out = []
        for p in self.list_ports():
            serial = port_serial(getattr(p, "serial_number", None), getattr(p, "hwid", None))
            out.append(PortInfo(p.device, serial, getattr(p, "manufacturer", None), p.vid, p.pid,
                                getattr(p, "location", None), usb_key=serial_key(serial)))
        return out

    def drives(self) -> list[DriveInfo]:
        from .usb_windows import COMMAND, parse_disks
        try:
            disks = parse_disks(self.run(COMMAND))
            self.drive_error = None
        except (OSError, ValueError, subprocess.SubprocessError) as e:
            self.drive_error = f"listing the USB disks failed ({e})"
            return []
        # a disk without a drive letter cannot be mounted from here: Windows assigns letters
        return [DriveInfo(d.mount, d.label, serial_key(d.usb_serial), None,
                          self.root_of(d.mount) if d.mount else None,
                          hint=f"give {d.disk} a drive letter in Disk Management")
                for d in disks]


class MacBackend:
    """macOS: ports from pyserial, drives from ``system_profiler SPUSBDataType -json``
    (``usb_macos``), paired by the USB serial number; without that section, the volumes under
    ``/Volumes`` by label."""

    def __init__(self, list_ports: Callable[[], list] = _pyserial_ports,
                 run: Callable[[list], str] = _run_text, volumes_dir: str = "/Volumes",
                 root_of: Callable[[str], str] = str, mounter: Optional[Callable[[Optional[str]], None]] = None):
        self.list_ports, self.run, self.volumes_dir, self.root_of = list_ports, run, volumes_dir, root_of
        self.mounter = mounter
        self.drive_error: Optional[str] = None

    def ports(self) -> list[PortInfo]:
        return [PortInfo(p.device, p.serial_number, getattr(p, "manufacturer", None), p.vid, p.pid,
                         getattr(p, "location", None), usb_key=serial_key(p.serial_number))
                for p in self.list_ports()]

    def drives(self) -> list[DriveInfo]:
        from .usb_macos import COMMAND, parse_usb_tree
        try:
            found = parse_usb_tree(self.run(COMMAND))
            self.drive_error = None
        except (OSError, ValueError, subprocess.SubprocessError) as e:
            self.drive_error = f"system_profiler failed ({e})"
            found = None
        if found is None:  # no USB topology: the mounted volumes, paired by label
            try:
                return [DriveInfo(str(p), p.name) for p in sorted(Path(self.volumes_dir).iterdir())
                        if p.is_dir()]
            except OSError:
                return []
        return [DriveInfo(d.mount, d.label, serial_key(d.usb_serial), d.bsd_name,
                          self.root_of(d.mount) if d.mount else None,
                          hint=f"diskutil mount {d.bsd_name}") for d in found]

    def mount(self, att: "Attached") -> None:
        from .mount import mount_macos
        (self.mounter or mount_macos)(att.block_device)


class LabelBackend:
    """Any other system: pyserial ports and the Linux-style mount table, paired by label only
    (no USB topology)."""

    def ports(self) -> list[PortInfo]:
        return [PortInfo(p.device, p.serial_number, p.manufacturer, p.vid, p.pid, p.location)
                for p in _pyserial_ports()]

    def volumes(self) -> list[tuple[str, str]]:
        try:
            text = Path("/proc/self/mountinfo").read_text()
        except OSError:
            return []
        return parse_mountinfo(text, _by_label())


def SystemBackend():
    """This operating system's enumeration."""
    if sys.platform.startswith("linux") and os.path.isdir("/sys/bus/usb"):
        return LinuxBackend()
    if sys.platform == "win32":
        return WindowsBackend()
    if sys.platform == "darwin":
        return MacBackend()
    return LabelBackend()


class EmulatedBackend:
    """Emulated devices registered by ``stillpoint device emulate`` or tests (any process). Every
    folder in a device's media folder is that device's mounted drive; its ``unmounted`` folder
    is its drive present but not mounted (the ``no-automount`` fault), which ``mount`` asks the
    emulator to mount."""

    MOUNT_WAIT_S = 5.0

    def ports(self) -> list[PortInfo]:
        return [PortInfo(e["port"], e["serial"], e["manufacturer"], e["vid"], e["pid"], e["slot"],
                         emulated=True, faults=tuple(e.get("faults", ())), control=e.get("control"),
                         media=e.get("media"), read_bps=e.get("read_bps"), usb_key=f"emu:{e['serial']}")
                for e in registry.entries()]

    def drives(self) -> list[DriveInfo]:
        out = []
        for e in registry.entries():
            key = f"emu:{e['serial']}"
            media = Path(e["media"])
            if media.is_dir():
                for p in sorted(media.iterdir()):
                    if p.is_dir():
                        out.append(DriveInfo(str(p), p.name, key))
            unmounted = e.get("unmounted")
            if unmounted and os.path.isdir(unmounted):
                out.append(DriveInfo(None, None, key, unmounted))
        return out

    def mount(self, att: "Attached") -> None:
        """Ask the emulated device to mount its drive (a signal file in its control folder, as
        the volume layer signals an unplug) and wait until it has."""
        import time
        if not att.control:
            raise DeviceError(att.device_id, "the emulated device has no control folder")
        Path(att.control, "mount").write_text(att.block_device or "")
        end = time.monotonic() + self.MOUNT_WAIT_S
        while time.monotonic() < end:
            if not Path(att.control, "mount").exists() and not (
                    att.block_device and os.path.exists(att.block_device)):
                return
            time.sleep(0.02)
        raise DeviceError(att.device_id, f"the emulated device did not mount its drive within "
                                         f"{self.MOUNT_WAIT_S:g} s")


def drives_of(backend) -> list[DriveInfo]:
    """A backend's drives; a label-only backend's ``volumes()`` as drives without a USB device."""
    if hasattr(backend, "drives"):
        return backend.drives()
    return [DriveInfo(mnt, label) for mnt, label in backend.volumes()]


class CombinedBackend:
    def __init__(self, backends: Optional[Iterable] = None):
        self.backends = list(backends) if backends is not None else [SystemBackend(), EmulatedBackend()]

    def ports(self) -> list[PortInfo]:
        return [p for b in self.backends for p in b.ports()]

    def drives(self) -> list[DriveInfo]:
        return [d for b in self.backends for d in drives_of(b)]

    @property
    def drive_error(self) -> Optional[str]:
        return next((e for b in self.backends if (e := getattr(b, "drive_error", None))), None)

    def mount(self, att: "Attached") -> None:
        for b in self.backends:
            if isinstance(b, EmulatedBackend) == att.emulated and hasattr(b, "mount"):
                return b.mount(att)
        raise DeviceError(att.device_id, "no way to mount a drive on this system")


# ----------------------------------------------------------------------------- pairing
def _has_data(d: DriveInfo) -> bool:
    return d.files is not None and d.files != "" and os.path.isfile(os.path.join(d.files, C.AX_DATA_FILE))


class OverrideError(StillpointError):
    """A ``--port`` / ``--volume`` override that names nothing usable."""


def _check_overrides(ports: list[PortInfo], port: Optional[str], volume: Optional[str]) -> None:
    if volume is not None:
        if not os.path.isdir(volume):
            raise OverrideError(f"--volume {volume}: no such folder")
        if not os.path.isfile(os.path.join(volume, C.AX_DATA_FILE)):
            raise OverrideError(f"--volume {volume}: the folder holds no {C.AX_DATA_FILE}")
    if port is None:
        return
    p = next((p for p in ports if p.device == port), None)
    if p is None:
        if "://" not in port and not os.path.exists(port):
            raise OverrideError(f"--port {port}: no such serial port")
        raise OverrideError(f"--port {port}: not an attached USB serial port of an AX3/AX6 (VID:PID "
                            "04D8:0057 with a serial number CWA.../AX6...)")
    if device_id_of_serial(p.serial_number or "") is None:
        raise OverrideError(f"--port {port}: its USB serial number {p.serial_number!r} names no "
                            "device id")


def _pair(p: PortInfo, dev_id: int, drives: list[DriveInfo], label_drives: dict[int, list[DriveInfo]]):
    """(the port's drives, how they were paired)."""
    mine = [d for d in drives if p.usb_key is not None and d.usb_key == p.usb_key]
    if mine:
        return mine, "usb"
    return label_drives.get(dev_id, []), "label"


def discover(backend=None, *, port: Optional[str] = None, volume: Optional[str] = None) -> list[Attached]:
    """Every attached AX3/AX6 (ports that pass the checks, paired with their drive). ``port`` /
    ``volume``: manual overrides (a port not enumerated as an AX, a drive mounted elsewhere); an
    override naming nothing usable raises ``OverrideError``."""
    backend = backend or CombinedBackend()
    drives = drives_of(backend)
    ports = backend.ports()
    _check_overrides(ports, port, volume)
    label_drives: dict[int, list[DriveInfo]] = {}
    for d in drives:  # only drives the OS gives no USB device for pair by their label
        ld = label_device(d.label or "") if d.usb_key is None else None
        if ld and _has_data(d):
            label_drives.setdefault(ld[1], []).append(d)
    candidates = [p for p in ports if (p.device == port if port else is_ax_port(p))]
    manual = manual_id = None
    if volume:
        manual = DriveInfo(volume, os.path.basename(volume.rstrip("/")))
        ld = label_device(manual.label)
        manual_id = ld[1] if ld else None
    note = getattr(backend, "drive_error", None)
    out = []
    for p in candidates:
        dev_id = device_id_of_serial(p.serial_number or "")
        kind = device_type_of_serial(p.serial_number or "") or "AX3"
        if dev_id is None:
            continue
        mine, how = _pair(p, dev_id, drives, label_drives)
        if manual is not None and (port or manual_id == dev_id
                                   or (manual_id is None and len(candidates) == 1)):
            mine, how = [manual], "manual"
        ready = [d for d in mine if d.mount and _has_data(d)]
        unmounted = [d for d in mine if not d.mount]
        volume_found, block, problem = None, None, None
        if len(ready) == 1:
            volume_found = ready[0].files
        elif len(ready) > 1:
            problem = f"more than one drive claims device {dev_id}: {', '.join(d.mount for d in ready)}"
        elif unmounted:
            block = unmounted[0].block_device  # None: not mountable from here
            hint = unmounted[0].hint
            problem = (f"its drive {block or ''} is present but not mounted".replace("  ", " ")
                       + (" (the station mounts it" if block else " (")
                       + ("; by hand: " if block and hint else "") + (hint or "") + ")")
        elif mine:
            problem = f"its drive at {mine[0].mount} holds no {C.AX_DATA_FILE}"
        else:
            problem = ("no drive found for this USB device (still enumerating, ejected by a COMMIT, "
                       "or not mounted: use --volume)" + (f"; {note}" if note else ""))
        out.append(Attached(dev_id, kind, p.serial_number or "", p.device, volume_found,
                            p.location or p.device, emulated=p.emulated, faults=tuple(p.faults),
                            control=p.control, problem=problem, read_bps=p.read_bps,
                            block_device=block, paired_by=how))
    return sorted(out, key=lambda a: (a.slot, a.device_id))
