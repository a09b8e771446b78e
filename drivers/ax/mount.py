"""Mounting a device's drive again when nothing else does (a headless station after a COMMIT).

After ``COMMIT``, ``CLEAR DATA`` or ``FORMAT`` the device drops its mass-storage medium and
presents it again (usb-protocols.md A5, conformance spec 2.6). A desktop session's automounter
mounts it again; on a headless Linux station nothing does, and every configure would wait for a
drive that never comes back. Discovery (``discovery``) reports such a drive as present but not
mounted, with its block device; the station's wait for the drive (``engine/station/flow.py``
``wait_volume``) gives an automounter ``AUTOMOUNT_GRACE_S`` and then calls ``remount``.

Why the station mounts the block device, rather than reading the data file without a mount:

* every later step reads the data file by path: the download and its cache-bypassing second
  read (``posix_fadvise(DONTNEED)`` works on a mounted file), the header read-backs of the clear
  and of the configure. A mount keeps one code path for real drives, emulated drives and
  ``--volume``; reading without a mount would need our own FAT16/FAT32 reader (directory
  entries, cluster chains, long names) beside the kernel's, for the station alone;
* reading the raw block device needs the same privilege as mounting it (the ``disk`` group),
  so it would not spare the set-up step either;
* the kernel's ``vfat`` driver is the one the desktop uses: a mounted drive behaves the same
  on a headless station and on a desktop.

How: ``udisksctl mount --block-device DEV --no-user-interaction`` when udisks2 is installed (it
mounts under ``/media/<user>/<label>`` like a desktop and cleans up the mounts of media that went
away; from a session without a seat (SSH, a service) polkit must allow it: a rule in
``/etc/polkit-1/rules.d/`` returning ``polkit.Result.YES`` for the station's user on the actions
``org.freedesktop.udisks2.filesystem-mount`` and ``...filesystem-mount-other-seat``), else, as
root, ``mount -t vfat -o nosuid,nodev,noexec`` into a folder the station owns
(``STATION_MOUNT_DIR/<device name>``). Otherwise one line says what to set up.

A mount the station made itself outlives the medium: after the next COMMIT the kernel keeps it on
the old filesystem, and nothing (no udisks) cleans it up. So the station writes the disk's
``diskseq`` (``/sys/block/<disk>/diskseq``, which the kernel increments on every media change,
Linux 5.15 and later) beside the mount, discovery treats its mount as stale once the number
differs (``usb_linux``), and the next mount first detaches the old one (``umount -l``). On older
kernels there is no ``diskseq``, and such a stale mount is not recognised. macOS
mounts a re-presented drive itself; ``mount_macos`` (``diskutil mount``) is there for a drive
that was unmounted by hand. Windows assigns drive letters itself and has no remount step.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from typing import Callable, Optional

from .errors import DeviceError

AUTOMOUNT_GRACE_S = 2.0  # a desktop automounter mounts within ~1 s of the medium appearing
STATION_MOUNT_DIR = "/run/stillpoint/mnt"  # where the station mounts drives itself (as root)
MOUNT_TIMEOUT_S = 15.0


class MountError(DeviceError):
    """A present drive could not be mounted: the reason and what to set up."""


def _run(cmd: list[str]) -> tuple[int, str]:
    try:
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=MOUNT_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        return 124, f"no answer within {MOUNT_TIMEOUT_S:g} s"
    except OSError as e:
        return 127, str(e)
    return r.returncode, ((r.stderr or "") + (r.stdout or "")).strip()


def _one_line(msg: str, limit: int = 200) -> str:
    """A tool's error output as one line (``mount`` adds a second line pointing at dmesg)."""
    return " ".join(line.strip() for line in (msg or "").splitlines()
                    if line.strip() and "dmesg(1)" not in line)[:limit]


def sequence_record(mount_dir: str, name: str) -> str:
    """The file that holds the disk sequence number of the station's mount of ``name``."""
    return os.path.join(mount_dir, f".{name}.diskseq")


def disk_sequence(device: str, sys_root: str = "/sys") -> Optional[str]:
    """The ``diskseq`` of the disk holding ``device`` (a partition's is its disk's); None on
    kernels without it."""
    real = os.path.realpath(os.path.join(sys_root, "class", "block", os.path.basename(device)))
    for d in (real, os.path.dirname(real)):
        try:
            with open(os.path.join(d, "diskseq")) as f:
                return f.read().strip() or None
        except OSError:
            continue
    return None


def mount_block_device(device: Optional[str], *, run: Callable[[list], tuple] = _run,
                       which: Callable[[str], Optional[str]] = shutil.which,
                       euid: Optional[int] = None, mount_dir: str = STATION_MOUNT_DIR,
                       sys_root: str = "/sys") -> None:
    """Mount a Linux block device (``/dev/sdb1``) that holds an AX drive; raises ``MountError``
    naming the device and what to set up."""
    if not device:
        raise MountError("drive", "no block device to mount")
    tried = []
    if which("udisksctl"):
        rc, msg = run(["udisksctl", "mount", "--block-device", device, "--no-user-interaction"])
        if rc == 0 or "AlreadyMounted" in msg:
            return
        tried.append(f"udisksctl: {_one_line(msg) or f'exit {rc}'}")
    if (os.geteuid() if euid is None else euid) == 0:
        target = os.path.join(mount_dir, os.path.basename(device))
        try:
            os.makedirs(target, mode=0o700, exist_ok=True)
        except OSError as e:
            raise MountError(device, f"cannot create the mount folder {target}: {e.strerror or e}") from None
        if os.path.ismount(target):  # the station's own mount of the medium before the COMMIT
            run(["umount", "-l", target])
        seq = disk_sequence(device, sys_root)
        rc, msg = run(["mount", "-t", "vfat", "-o", "nosuid,nodev,noexec", device, target])
        if rc == 0:
            record = sequence_record(mount_dir, os.path.basename(device))
            try:
                if seq:
                    with open(record, "w") as f:
                        f.write(seq)
                elif os.path.exists(record):
                    os.unlink(record)
            except OSError:
                pass  # only the stale-mount check needs it
            return
        tried.append(f"mount: {_one_line(msg).removeprefix('mount: ') or f'exit {rc}'}")
    if not tried:
        raise MountError(device, "the drive is present but not mounted, and this station cannot "
                                 "mount it (no udisksctl, not root): install udisks2 (and allow "
                                 "org.freedesktop.udisks2.filesystem-mount for this user) or mount "
                                 "it by hand")
    raise MountError(device, "the drive is present but could not be mounted (" + "; ".join(tried)
                     + ")")


def mount_macos(device: Optional[str], *, run: Callable[[list], tuple] = _run) -> None:
    """``diskutil mount /dev/diskNsM`` (macOS)."""
    if not device:
        raise MountError("drive", "no disk to mount")
    node = device if device.startswith("/dev/") else f"/dev/{device}"
    rc, msg = run(["diskutil", "mount", node])
    if rc != 0:
        raise MountError(device, f"diskutil could not mount it ({_one_line(msg) or rc})")


def remount(att, backend) -> None:
    """Mount ``att``'s present, unmounted drive through the backend that found it."""
    mount = getattr(backend, "mount", None)
    if mount is None:
        raise MountError(att.device_id, f"its drive {att.block_device} is present but not mounted, "
                                        "and discovery here cannot mount drives")
    try:
        mount(att)
    except DeviceError as e:
        if e.device == str(att.device_id):
            raise
        raise MountError(att.device_id, f"drive {e.device}: {e.reason}") from None
