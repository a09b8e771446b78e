"""Headless remount: a drive that comes back present but not mounted after COMMIT/CLEAR/FORMAT is
mounted by the station (udisksctl, else mount as root), or the station says in one line what to
set up; the station completes download, clear and configure on such a device."""

from __future__ import annotations

import io

import pytest

from stillpoint.drivers.ax.discovery import EmulatedBackend, PortInfo, DriveInfo
from stillpoint.drivers.ax.errors import DeviceError
from stillpoint.drivers.ax.mount import MountError, mount_block_device, mount_macos
from stillpoint.engine.station.flow import DeviceFlow, StationOptions
from stillpoint.engine.station.profile import load_profile
from stillpoint.engine.station.station import Station

from station_fixtures import STUDY_PROFILE as PROFILE, emu, runtime  # noqa: F401


class Runner:
    def __init__(self, *answers):
        self.answers, self.cmds = list(answers), []

    def __call__(self, cmd):
        self.cmds.append(cmd)
        return self.answers.pop(0)


def test_udisksctl_first():
    run = Runner((0, "Mounted /dev/sdb1 at /media/station/AX317_12345"))
    mount_block_device("/dev/sdb1", run=run, which=lambda n: "/usr/bin/" + n, euid=1000)
    assert run.cmds == [["udisksctl", "mount", "--block-device", "/dev/sdb1", "--no-user-interaction"]]
    # mounted meanwhile by an automounter: nothing to do
    run = Runner((1, "Error mounting /dev/sdb1: GDBus.Error:org.freedesktop.UDisks2.Error.AlreadyMounted"))
    mount_block_device("/dev/sdb1", run=run, which=lambda n: "/usr/bin/" + n, euid=1000)


def test_as_root_without_udisks_mounts_into_the_station_folder(tmp_path, monkeypatch):
    sysfs = tmp_path / "sys"
    disk = sysfs / "devices/pci0000:00/usb1/1-1/1-1.2/1-1.2:1.2/host6/block/sdc"
    (disk / "sdc1").mkdir(parents=True)
    (disk / "diskseq").write_text("12\n")
    (sysfs / "class/block").mkdir(parents=True)
    (sysfs / "class/block/sdc1").symlink_to(disk / "sdc1")
    mnt = tmp_path / "mnt"
    run = Runner((0, ""))
    mount_block_device("/dev/sdc1", run=run, which=lambda n: None, euid=0, mount_dir=str(mnt),
                       sys_root=str(sysfs))
    assert run.cmds == [["mount", "-t", "vfat", "-o", "nosuid,nodev,noexec", "/dev/sdc1",
                         str(mnt / "sdc1")]]
    assert (mnt / "sdc1").is_dir()
    assert (mnt / ".sdc1.diskseq").read_text() == "12"  # the medium it was mounted on
    # the station's mount of the medium before a COMMIT is detached before mounting again
    monkeypatch.setattr("stillpoint.drivers.ax.mount.os.path.ismount", lambda p: p == str(mnt / "sdc1"))
    run = Runner((0, ""), (0, ""))
    mount_block_device("/dev/sdc1", run=run, which=lambda n: None, euid=0, mount_dir=str(mnt),
                       sys_root=str(sysfs))
    assert run.cmds[0] == ["umount", "-l", str(mnt / "sdc1")] and run.cmds[1][0] == "mount"


def test_what_cannot_be_mounted_is_one_line_naming_the_device(tmp_path):
    with pytest.raises(MountError) as e:
        mount_block_device("/dev/sdb1", run=Runner(), which=lambda n: None, euid=1000)
    msg = str(e.value)
    assert msg.startswith("device /dev/sdb1: ") and "\n" not in msg
    assert "no udisksctl, not root" in msg and "udisks2" in msg
    run = Runner((1, "Error mounting /dev/sdb1: GDBus.Error:org.freedesktop.UDisks2.Error."
                     "NotAuthorizedCanObtain: Not authorized to perform operation"),
                 (32, "mount: /x: unknown filesystem type 'vfat'.\n       dmesg(1) may have more "
                      "information after failed mount system call."))
    with pytest.raises(MountError) as e:
        mount_block_device("/dev/sdb1", run=run, which=lambda n: "/usr/bin/" + n, euid=0,
                           mount_dir=str(tmp_path))
    assert "NotAuthorized" in str(e.value) and "unknown filesystem type 'vfat'" in str(e.value)
    assert "\n" not in str(e.value) and "dmesg" not in str(e.value)
    with pytest.raises(MountError, match="diskutil could not mount it"):
        mount_macos("disk4s1", run=Runner((1, "Volume on disk4s1 failed to mount")))


class Unmountable:
    """A backend whose device's drive is back but not mounted, and cannot be mounted."""

    def __init__(self, tmp_path):
        self.tmp = tmp_path

    def ports(self):
        return [PortInfo("/dev/ttyACM0", "CWA17_12345", "x", 0x04D8, 0x0057, "1-1.2", usb_key="k")]

    def drives(self):
        return [DriveInfo(None, None, "k", "/dev/sdb1")]

    def mount(self, att):
        raise MountError(att.block_device, "the drive is present but could not be mounted (udisksctl: "
                                           "Not authorized)")


def test_wait_volume_names_a_drive_it_cannot_mount(tmp_path):
    b = Unmountable(tmp_path)
    from stillpoint.drivers.ax.discovery import discover
    att = discover(b)[0]
    flow = DeviceFlow(att, StationOptions(str(tmp_path)), ledger=None, backend=b)
    with pytest.raises(DeviceError) as e:
        flow.wait_volume(2.0)
    assert str(e.value) == ("device 12345: drive /dev/sdb1: the drive is present but could not be "
                            "mounted (udisksctl: Not authorized)")


def test_station_completes_on_a_device_whose_drive_is_not_mounted_again(emu, tmp_path):
    d = emu(10001, faults=("no-automount",))
    prof = tmp_path / "study.toml"
    prof.write_text(PROFILE)
    out = tmp_path / "out"
    out.mkdir()
    opts = StationOptions(str(out), profile=load_profile(prof), clear_after_verify=True,
                          configure_after=True, inline=True, remount_s=10.0)
    with Station(opts, EmulatedBackend(), tty=False, out=io.StringIO(), poll_s=0.1) as st:
        rc = st.run(once=True)
        f = next(iter(st.flows.values()))
    assert (f.state, rc) == ("configured", 0), f.reason
    # the clear and the configure's COMMIT each left the drive unmounted; the station mounted it
    assert d.events.count("mounted by the host") == 2
    assert len(d.clears) == 1 and len(list(out.glob("*10001_1.cwa"))) == 1
    from stillpoint.drivers.cwa_layout import parse_header
    h = parse_header(d.data_file.read_bytes()[:1024])
    assert (h["session_id"], h["sample_rate_hz"]) == (2, 50.0)


class NoLetter(Unmountable):
    """Windows: the device's disk is there but has no drive letter (nothing the station can mount)."""

    def drives(self):
        return [DriveInfo(None, None, "k", None, hint="give \\\\.\\PHYSICALDRIVE4 a drive letter in "
                                                      "Disk Management")]


def test_wait_volume_says_why_a_present_drive_never_appeared(tmp_path):
    b = NoLetter(tmp_path)
    from stillpoint.drivers.ax.discovery import discover
    flow = DeviceFlow(discover(b)[0], StationOptions(str(tmp_path)), ledger=None, backend=b)
    with pytest.raises(DeviceError, match=r"did not come back within 0.3 s .*present but not mounted "
                                          r"\(give \\\\\.\\PHYSICALDRIVE4 a drive letter"):
        flow.wait_volume(0.3)


def test_device_commands_complete_on_a_device_whose_drive_is_not_mounted_again(emu, tmp_path, capsys):
    from stillpoint.tools.cli import main
    d = emu(10001, faults=("no-automount",))
    out = tmp_path / "out"
    out.mkdir()
    prof = tmp_path / "study.toml"
    prof.write_text(PROFILE)
    assert main(["device", "download", "10001", "-o", str(out)]) == 0
    assert main(["device", "clear", "10001", "-o", str(out)]) == 0, capsys.readouterr().err
    assert main(["device", "configure", "10001", "--profile", str(prof)]) == 0, capsys.readouterr().err
    assert d.events.count("mounted by the host") == 2 and len(d.clears) == 1
