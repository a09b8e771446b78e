"""Linux: each AX3/AX6 USB device with its serial port and its drive, read from sysfs.

The kernel lays every USB device out as a folder (``/sys/bus/usb/devices/1-1.2`` -> its real path
under ``/sys/devices/...``) holding ``idVendor``, ``idProduct`` and ``serial``. The device's
interfaces are subfolders of that real path; so are the serial port (``/sys/class/tty/ttyACM0/
device`` resolves to the CDC interface) and the disk (``/sys/block/sdb`` resolves to
``.../1-1.2:1.x/host6/.../block/sdb``). A port and a drive therefore belong to the same device
exactly when both real paths lie under the same USB device folder: this is the pairing, and it
needs neither the volume label nor the serial string (two devices with the same serial still
pair correctly). The mount point comes from ``/proc/self/mountinfo``, matched on the block
device's ``major:minor`` (its ``dev`` file), so it does not matter where or by whom the drive was
mounted. OmApi's Linux finder (``omapi-devicefinder-linux.c`` 170, 235-251) pairs through the
same USB parent with libudev but assumes ``/media/<label>``; we read the files directly (no
libudev dependency).

A mount the station made itself (``mount``, as root) whose disk has changed medium since (its
``diskseq`` differs from the one recorded at mount time) is stale: the drive is reported present
but not mounted, so that it is mounted again.

Every path is relative to ``sys_root`` / ``mountinfo`` / ``dev_root`` / ``station_mounts``, so
tests build a fake tree. Only plain file reads: nothing here opens a device.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

from .. import constants as C
from .mount import STATION_MOUNT_DIR, sequence_record


@dataclass
class UsbDrive:
    """One filesystem of a USB device: its block device, where it is mounted (None: present,
    not mounted), its label if known."""

    block_device: str  # /dev/sdb1
    dev: str  # "8:17"
    mount: Optional[str]
    label: Optional[str] = None


@dataclass
class UsbDevice:
    """One USB device with VID:PID 04D8:0057 and what hangs below it."""

    sys_path: str  # real path of the USB device folder
    name: str  # bus-port name, e.g. 1-1.2 (the dock slot)
    serial: Optional[str]
    manufacturer: Optional[str]
    vid: int
    pid: int
    ttys: list  # /dev/ttyACM0 ...
    drives: list  # UsbDrive


def _read(p: Path) -> Optional[str]:
    try:
        return p.read_text(errors="replace").strip()
    except OSError:
        return None


def _hex(s: Optional[str]) -> Optional[int]:
    try:
        return int(s, 16) if s else None
    except ValueError:
        return None


def _unescape(s: str) -> str:
    import re
    return re.sub(r"\\([0-7]{3})", lambda m: chr(int(m.group(1), 8)), s)


def mounts_by_dev(text: str) -> dict[str, str]:
    """``major:minor`` -> mount point of every mount in ``/proc/self/mountinfo`` text (the first
    mount of a device wins; field 3 is the device number, field 5 the mount point)."""
    out: dict[str, str] = {}
    for line in text.splitlines():
        parts = line.split(" ")
        if len(parts) < 5:
            continue
        out.setdefault(parts[2], _unescape(parts[4]))
    return out


def _under(path: str, parent: str) -> bool:
    return path.startswith(parent.rstrip("/") + "/")


class LinuxUsb:
    """Reads the USB devices, ttys, disks and mounts of one (possibly fake) Linux system."""

    def __init__(self, sys_root: str = "/sys", mountinfo: str = "/proc/self/mountinfo",
                 dev_root: str = "/dev", station_mounts: str = STATION_MOUNT_DIR):
        self.sys = Path(sys_root)
        self.mountinfo = Path(mountinfo)
        self.dev = Path(dev_root)
        self.station_mounts = station_mounts

    def _stale(self, mount: Optional[str], name: str, disk: Path) -> bool:
        """The station's own mount of a medium the disk no longer holds."""
        if not mount or not _under(mount, self.station_mounts):
            return False
        recorded = _read(Path(sequence_record(self.station_mounts, name)))
        now = _read(disk / "diskseq")
        return bool(recorded and now and recorded != now)

    def _labels(self) -> dict[str, str]:
        d = self.dev / "disk" / "by-label"
        out = {}
        try:
            for p in d.iterdir():
                out[os.path.basename(os.path.realpath(p))] = _unescape(p.name.replace("\\x20", " "))
        except OSError:
            pass
        return out

    def _real(self, p: Path) -> Optional[str]:
        try:
            return os.path.realpath(p)
        except OSError:
            return None

    def devices(self) -> list[UsbDevice]:
        """Every USB device with the AX VID:PID, with its ttys and its drives."""
        found = []
        try:
            entries = sorted((self.sys / "bus" / "usb" / "devices").iterdir())
        except OSError:
            return []
        for e in entries:
            vid, pid = _hex(_read(e / "idVendor")), _hex(_read(e / "idProduct"))
            if vid is None or pid is None or (vid, pid) != (C.AX_USB_VID, C.AX_USB_PID):
                continue
            real = self._real(e)
            if real is None:
                continue
            found.append(UsbDevice(real, e.name, _read(e / "serial"), _read(e / "manufacturer"),
                                   vid, pid, [], []))
        if not found:
            return []
        self._attach_ttys(found)
        self._attach_drives(found)
        return found

    def _owner(self, real: Optional[str], devs: list[UsbDevice]) -> Optional[UsbDevice]:
        if not real:
            return None
        best = [d for d in devs if _under(real, d.sys_path)]
        return max(best, key=lambda d: len(d.sys_path)) if best else None  # the deepest (hubs)

    def _attach_ttys(self, devs: list[UsbDevice]) -> None:
        try:
            ttys = sorted((self.sys / "class" / "tty").iterdir())
        except OSError:
            return
        for t in ttys:
            d = self._owner(self._real(t / "device"), devs)
            if d is not None:
                d.ttys.append(str(self.dev / t.name))

    def _attach_drives(self, devs: list[UsbDevice]) -> None:
        try:
            disks = sorted((self.sys / "block").iterdir())
        except OSError:
            return
        try:
            mounts = mounts_by_dev(self.mountinfo.read_text())
        except OSError:
            mounts = {}
        labels = None
        for disk in disks:
            real = self._real(disk)
            d = self._owner(real, devs)
            if d is None or real is None:  # no owner without a real path
                continue
            if labels is None:
                labels = self._labels()
            rp = Path(real)
            try:
                parts = sorted(p for p in rp.iterdir() if (p / "partition").is_file())
            except OSError:  # the disk went away meanwhile
                continue
            for fs in parts or [rp]:  # a disk without a partition table holds the filesystem itself
                num = _read(fs / "dev")
                if not num or _read(fs / "size") == "0":  # no medium (ejected by a COMMIT)
                    continue
                mount = mounts.get(num)
                if self._stale(mount, fs.name, rp):
                    mount = None
                d.drives.append(UsbDrive(str(self.dev / fs.name), num, mount, labels.get(fs.name)))
