"""Device discovery: port filters, pairing through the USB device on Linux (a fake sysfs tree),
Windows and macOS (fixture outputs of their enumeration commands), the label fallback, manual
overrides, backends."""

from __future__ import annotations

import json
import os
from pathlib import Path
from types import SimpleNamespace

import pytest

from stillpoint.drivers.ax.discovery import (EmulatedBackend, LinuxBackend, MacBackend,
                                             OverrideError, PortInfo, WindowsBackend, discover,
                                             is_ax_port, label_device, parse_mountinfo)
from stillpoint.drivers.ax.usb_linux import LinuxUsb
from stillpoint.drivers.ax.usb_windows import serial_of_pnp_id

from station_fixtures import emu, runtime  # noqa: F401

MANUF = "Newcastle University    "


def test_port_filter_is_vid_pid_serial_prefix_and_id():
    good = PortInfo("/dev/ttyACM0", "CWA17_12345", MANUF, 0x04D8, 0x0057)
    assert is_ax_port(good)
    assert is_ax_port(PortInfo("/dev/ttyACM1", "AX664_00042", MANUF, 0x04D8, 0x0057))
    assert is_ax_port(PortInfo("/dev/ttyACM1", "CWA17_1234567890", MANUF, 0x04D8, 0x0057))
    # the Microchip composite VID:PID alone is not enough
    assert not is_ax_port(PortInfo("/dev/ttyACM2", "0001234", "Microchip", 0x04D8, 0x0057))
    assert not is_ax_port(PortInfo("/dev/ttyACM2", "CWA17_", MANUF, 0x04D8, 0x0057))
    assert not is_ax_port(PortInfo("/dev/ttyUSB0", "CWA17_12345", MANUF, 0x0403, 0x6001))
    # no manufacturer filter: Windows reports the driver INF's manufacturer
    for m in ("Microchip Technology, Inc.", "Microsoft", None):
        assert is_ax_port(PortInfo("COM5", "CWA17_12345", m, 0x04D8, 0x0057))


def test_labels():
    assert label_device("AX317_12345") == ("AX3", 12345)
    assert label_device("AX664_00042") == ("AX6", 42)
    assert label_device("AX3_1234567") == ("AX3", 1234567)
    assert label_device("USBSTICK") is None


def test_mountinfo_labels_and_escapes():
    text = ("36 25 8:17 / /media/ann/AX317_12345 rw,nosuid - vfat /dev/sdb1 rw\n"
            "37 25 8:33 / /run/media/bob/My\\040Disk rw - vfat /dev/sdc1 rw\n"
            "38 25 8:49 / /mnt/dock3 rw - vfat /dev/sdd1 rw\n")
    got = parse_mountinfo(text, {"/dev/sdd1": "AX664_00042"})
    assert ("/media/ann/AX317_12345", "AX317_12345") in got
    assert ("/run/media/bob/My Disk", "My Disk") in got
    # the label comes from the by-label table, not the mount folder's name
    assert ("/mnt/dock3", "AX664_00042") in got


class FakeBackend:
    def __init__(self, ports, volumes):
        self._p, self._v = ports, volumes

    def ports(self):
        return self._p

    def volumes(self):
        return self._v


def test_pairing_and_port_without_drive(tmp_path):
    vol = tmp_path / "AX317_12345"
    vol.mkdir()
    (vol / "CWA-DATA.CWA").write_bytes(b"MD" + b"\0" * 1022)
    other = tmp_path / "AX317_99999"  # a drive without the data file is not an AX drive
    other.mkdir()
    b = FakeBackend([PortInfo("/dev/ttyACM0", "CWA17_12345", MANUF, 0x04D8, 0x0057, "1-1.2"),
                     PortInfo("/dev/ttyACM1", "CWA17_99999", MANUF, 0x04D8, 0x0057, "1-1.3"),
                     PortInfo("/dev/ttyS0", None, None, None, None)],
                    [(str(vol), "AX317_12345"), (str(other), "AX317_99999")])
    found = {a.device_id: a for a in discover(b)}
    assert set(found) == {12345, 99999}
    assert found[12345].volume == str(vol) and found[12345].slot == "1-1.2" and not found[12345].problem
    assert found[99999].volume is None and "no drive found" in found[99999].problem
    # manual override: the drive is mounted somewhere discovery did not look
    found = {a.device_id: a for a in discover(b, volume=str(vol))}
    assert found[12345].volume == str(vol)


def test_emulated_devices_are_found_through_the_registry(emu):
    emu(10001)
    b = emu(20002, "AX6")
    found = discover(EmulatedBackend())
    assert [(x.device_id, x.device_type) for x in found] == [(10001, "AX3"), (20002, "AX6")]
    assert all(x.emulated and x.volume and x.port.startswith("axemu://") for x in found)
    b.unplug()
    assert [x.device_id for x in discover(EmulatedBackend())] == [10001]


# ----------------------------------------------------------------------------- Linux: fake sysfs
PCI = "devices/pci0000:00/0000:00:14.0/usb1"


def _w(p: Path, text: str) -> None:
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(text + "\n")


def _link(link: Path, target: Path) -> None:
    link.parent.mkdir(parents=True, exist_ok=True)
    link.symlink_to(os.path.relpath(target, link.parent))


def _usb_device(sysfs: Path, name: str, vid: str, pid: str, serial: str, tty: str = None,
                disk: str = None, major_minor: tuple = (8, 16), partitioned: bool = True,
                medium: bool = True, diskseq: int = None) -> Path:
    """One USB device as the kernel lays it out: the device folder, a CDC interface with its tty,
    a mass-storage interface with its SCSI disk (and partition), and the class symlinks."""
    dev = sysfs / PCI / "1-1" / name
    _w(dev / "idVendor", vid)
    _w(dev / "idProduct", pid)
    _w(dev / "serial", serial)
    _w(dev / "manufacturer", "Newcastle University    ")
    _link(sysfs / "bus/usb/devices" / name, dev)
    if tty:
        intf = dev / f"{name}:1.0"
        t = intf / "tty" / tty
        _w(t / "dev", "166:0")
        _link(t / "device", intf)
        _link(sysfs / "class/tty" / tty, t)
    if disk:
        d = dev / f"{name}:1.2" / "host6/target6:0:0/6:0:0:0/block" / disk
        major, minor = major_minor
        _w(d / "dev", f"{major}:{minor}")
        _w(d / "size", "999424" if medium else "0")
        if diskseq is not None:
            _w(d / "diskseq", str(diskseq))
        if partitioned and medium:
            _w(d / f"{disk}1" / "dev", f"{major}:{minor + 1}")
            _w(d / f"{disk}1" / "size", "999360")
            _w(d / f"{disk}1" / "partition", "1")
        _link(sysfs / "block" / disk, d)
        _link(sysfs / "class/block" / disk, d)
        if partitioned and medium:
            _link(sysfs / "class/block" / f"{disk}1", d / f"{disk}1")
    return dev


def _drive(root: Path, name: str) -> Path:
    p = root / name
    p.mkdir(parents=True)
    (p / "CWA-DATA.CWA").write_bytes(b"MD" + b"\0" * 1022)
    return p


def _fake_linux(tmp_path):
    sysfs, mnt = tmp_path / "sys", tmp_path / "media"
    _w(sysfs / "bus/usb/devices/usb1/idVendor", "1d6b")  # the root hub
    _usb_device(sysfs, "1-1.2", "04d8", "0057", "CWA17_12345", "ttyACM0", "sdb", (8, 16))
    # a 10-digit id whose (7-digit) label cannot name it; no partition table
    _usb_device(sysfs, "1-1.3", "04d8", "0057", "AX664_1234567890", "ttyACM1", "sdc", (8, 32),
                partitioned=False)
    _usb_device(sysfs, "1-1.4", "04d8", "0057", "CWA17_00042", "ttyACM2", "sdd", (8, 48))
    _usb_device(sysfs, "1-1.5", "04d8", "0057", "CWA17_00099", "ttyACM3", "sde", (8, 64), medium=False)
    # a USB stick labelled like device 42's drive: never its drive
    _usb_device(sysfs, "1-1.6", "0781", "5581", "4C530001230915117383", None, "sdf", (8, 80))
    a = _drive(mnt, "RELABELLED")
    b = _drive(mnt, "AX6_1234567")
    decoy = _drive(mnt, "AX317_00042")
    mountinfo = tmp_path / "mountinfo"
    mountinfo.write_text(
        "22 1 259:2 / / rw,relatime - ext4 /dev/nvme0n1p2 rw\n"
        f"40 22 8:17 / {a} rw,nosuid - vfat /dev/sdb1 rw\n"
        f"41 22 8:32 / {b} rw,nosuid - vfat /dev/sdc rw\n"
        f"42 22 8:81 / {decoy} rw,nosuid - vfat /dev/sdf1 rw\n")
    return LinuxUsb(str(sysfs), str(mountinfo), str(tmp_path / "dev")), a, b


def test_linux_pairs_port_and_drive_through_the_usb_device(tmp_path):
    usb, a, b = _fake_linux(tmp_path)
    found = {x.device_id: x for x in discover(LinuxBackend(usb))}
    assert set(found) == {12345, 1234567890, 42, 99}
    assert (found[12345].port, found[12345].volume, found[12345].slot, found[12345].paired_by) == (
        str(tmp_path / "dev/ttyACM0"), str(a), "1-1.2", "usb")
    assert not found[12345].problem
    # a relabelled drive and a 10-digit id pair; a drive without a partition table too
    assert (found[1234567890].device_type, found[1234567890].volume) == ("AX6", str(b))
    # present but not mounted: the block device is reported (the station mounts it), and the
    # mounted USB stick with device 42's label is not taken for its drive
    assert found[42].volume is None and found[42].block_device == str(tmp_path / "dev/sdd1")
    assert "present but not mounted" in found[42].problem
    # a disk without a medium (ejected by a COMMIT) is no drive at all
    assert found[99].volume is None and found[99].block_device is None
    assert "no drive found" in found[99].problem


def test_linux_mount_goes_to_the_block_device(tmp_path):
    usb, _, _ = _fake_linux(tmp_path)
    asked = []
    b = LinuxBackend(usb, mounter=asked.append)
    att = next(x for x in discover(b) if x.device_id == 42)
    b.mount(att)
    assert asked == [str(tmp_path / "dev/sdd1")]


# ----------------------------------------------------------------------------- Windows / macOS
DATA = Path(__file__).parents[2] / "data" / "discovery"


def _ports(name):
    return [SimpleNamespace(**r) for r in json.loads((DATA / name).read_text())]


def test_usbstor_instance_ids():
    assert serial_of_pnp_id("USBSTOR\\DISK&VEN_A&PROD_B&REV_1\\CWA17_12345&0") == "CWA17_12345"
    assert serial_of_pnp_id("USBSTOR\\DISK&VEN_A&PROD_B&REV_1\\7&2A3B4C5D&0&0") is None
    assert serial_of_pnp_id("USB\\VID_04D8&PID_0057\\CWA17_12345") is None


def test_windows_pairs_drive_letters_by_usb_serial(tmp_path):
    for _letter, name in (("E", "E"), ("F", "F"), ("G", "G"), ("H", "H")):
        _drive(tmp_path, name)
    ran = []

    def run(cmd):
        ran.append(cmd)
        return (DATA / "windows_disks.json").read_text()

    b = WindowsBackend(list_ports=lambda: _ports("windows_ports.json"), run=run,
                       root_of=lambda m: str(tmp_path / m[0]))
    found = {x.device_id: x for x in discover(b)}
    assert ran and ran[0][0] == "powershell.exe" and "Win32_DiskDrive" in ran[0][-1]
    # the INF manufacturers ("Microchip Technology, Inc.", "Microsoft") do not hide a device
    assert set(found) == {12345, 1234567890, 42, 777}
    assert (found[12345].port, found[12345].volume, found[12345].paired_by) == (
        "COM5", str(tmp_path / "E"), "usb")
    # serial from hwid's SER=; a relabelled drive of a 10-digit id
    assert (found[1234567890].port, found[1234567890].volume) == ("COM7", str(tmp_path / "F"))
    # a disk without a drive letter; the stick labelled AX317_00042 (G:) is not its drive
    assert found[42].volume is None and found[42].block_device is None
    assert "present but not mounted (give \\\\.\\PHYSICALDRIVE4 a drive letter" in found[42].problem
    # a disk Windows knows no serial for pairs by its label only
    assert (found[777].volume, found[777].paired_by) == (str(tmp_path / "H"), "label")


def test_windows_listing_failure_is_named(tmp_path):
    def run(cmd):
        raise OSError("powershell.exe not found")
    b = WindowsBackend(list_ports=lambda: _ports("windows_ports.json"), run=run)
    found = {x.device_id: x for x in discover(b)}
    assert found[12345].volume is None and "powershell.exe not found" in found[12345].problem


def test_macos_pairs_volumes_by_usb_serial(tmp_path):
    for name in ("AX317_12345", "WRIST-LEFT", "AX317_00042"):
        _drive(tmp_path, name)
    b = MacBackend(list_ports=lambda: _ports("macos_ports.json"),
                   run=lambda cmd: (DATA / "macos_spusb.json").read_text(),
                   root_of=lambda m: str(tmp_path / Path(m).name))
    found = {x.device_id: x for x in discover(b)}
    assert set(found) == {12345, 1234567890, 42}
    assert (found[12345].port, found[12345].volume, found[12345].paired_by) == (
        "/dev/cu.usbmodem141101", str(tmp_path / "AX317_12345"), "usb")
    assert found[1234567890].volume == str(tmp_path / "WRIST-LEFT")
    # device 42's own volume is not mounted; the USB stick mounted as /Volumes/AX317_00042 is
    # not taken for it
    assert found[42].volume is None and found[42].block_device == "disk6s1"
    asked = []
    MacBackend(mounter=asked.append).mount(found[42])
    assert asked == ["disk6s1"]


def test_macos_without_usb_topology_falls_back_to_labels(tmp_path):
    vols = tmp_path / "Volumes"
    _drive(vols, "AX317_12345")
    _drive(vols, "WRIST-LEFT")
    b = MacBackend(list_ports=lambda: _ports("macos_ports.json"),
                   run=lambda cmd: '{"SPUSBHostDataType": []}', volumes_dir=str(vols))
    found = {x.device_id: x for x in discover(b)}
    assert (found[12345].volume, found[12345].paired_by) == (str(vols / "AX317_12345"), "label")
    assert found[1234567890].volume is None  # a relabelled drive cannot pair without topology


# ----------------------------------------------------------------------------- manual overrides
def test_overrides_that_name_nothing_are_errors(tmp_path, runtime, capsys):
    b = FakeBackend([PortInfo("/dev/ttyACM0", "CWA17_12345", MANUF, 0x04D8, 0x0057, "1-1.2")], [])
    with pytest.raises(OverrideError, match="^--port /dev/nonexistent: no such serial port$"):
        discover(b, port="/dev/nonexistent")
    with pytest.raises(OverrideError, match="not an attached USB serial port"):
        discover(b, port=str(tmp_path))  # exists, but is no enumerated port
    with pytest.raises(OverrideError, match="--volume .*nope: no such folder"):
        discover(b, volume=str(tmp_path / "nope"))
    with pytest.raises(OverrideError, match="holds no CWA-DATA.CWA"):
        discover(b, volume=str(tmp_path))
    # the command line: one line, exit code 2
    from stillpoint.tools.cli import main
    assert main(["devices", "--port", "/dev/nonexistent"]) == 2
    err = capsys.readouterr().err
    assert "--port /dev/nonexistent: no such serial port" in err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err


def test_a_manual_volume_overrides_the_usb_pairing(tmp_path):
    usb, a, _ = _fake_linux(tmp_path)
    elsewhere = _drive(tmp_path / "mnt", "dock3")
    found = {x.device_id: x for x in discover(LinuxBackend(usb), port=str(tmp_path / "dev/ttyACM2"),
                                              volume=str(elsewhere))}
    assert list(found) == [42] and found[42].volume == str(elsewhere)
    assert found[42].paired_by == "manual"


def test_the_stations_own_mount_of_an_old_medium_is_stale(tmp_path):
    """After a COMMIT the kernel keeps the station's mount on the old filesystem: once the disk's
    diskseq differs from the one recorded at mount time, the drive is present but not mounted."""
    sysfs, station = tmp_path / "sys", tmp_path / "station-mnt"
    _usb_device(sysfs, "1-1.2", "04d8", "0057", "CWA17_12345", "ttyACM0", "sdb", (8, 16), diskseq=9)
    mnt = _drive(station, "sdb1")
    (tmp_path / "mountinfo").write_text(f"40 22 8:17 / {mnt} rw - vfat /dev/sdb1 rw\n")
    usb = LinuxUsb(str(sysfs), str(tmp_path / "mountinfo"), str(tmp_path / "dev"), str(station))
    (station / ".sdb1.diskseq").write_text("9")  # mounted on this medium
    assert discover(LinuxBackend(usb))[0].volume == str(mnt)
    (station / ".sdb1.diskseq").write_text("7")  # mounted on the medium before the COMMIT
    a = discover(LinuxBackend(usb))[0]
    assert a.volume is None and a.block_device == str(tmp_path / "dev/sdb1")


def test_an_enumeration_command_runs_at_most_once_per_refresh(tmp_path, monkeypatch):
    """PowerShell / system_profiler are not started on every poll of a drive."""
    from stillpoint.drivers.ax import discovery as D
    counter = tmp_path / "runs"
    cmd = ["sh", "-c", f"echo run >> {counter}; wc -l < {counter}"]
    monkeypatch.setattr(D, "ENUMERATION_REFRESH_S", 3600.0)
    assert D._run_text(cmd).strip() == "1"
    assert D._run_text(cmd).strip() == "1"  # the answer reused
    monkeypatch.setattr(D, "ENUMERATION_REFRESH_S", 0.0)
    assert D._run_text(cmd).strip() == "2"
    with pytest.raises(OSError, match="exited 3"):
        D._run_text(["sh", "-c", "exit 3"])


@pytest.mark.parametrize("platform,kind", [("win32", WindowsBackend), ("darwin", MacBackend)])
def test_each_system_gets_its_own_enumeration(monkeypatch, platform, kind):
    from stillpoint.drivers.ax import discovery as D
    monkeypatch.setattr(D.sys, "platform", platform)
    assert isinstance(D.SystemBackend(), kind)
    monkeypatch.setattr(D.sys, "platform", "freebsd14")
    assert isinstance(D.SystemBackend(), D.LabelBackend)  # no USB topology known: labels
