"""One station per device on a computer: a host-wide lock per device, and the host-wide records
that every station honours.

Two stations may run on one computer (two studies, two output folders: each folder's ledger is
its own). They must never act on the same device at once, and what one of them found must bind
the other. So:

* **The device lock.** A station holds ``<locks>/<key>.lock`` (an exclusive ``flock``) while it
  identifies, downloads, verifies, clears or configures a device; its serial port is opened only
  under the lock. A second station that finds the lock held leaves the device (``DeviceBusy``:
  "busy: held by the station on OUT (pid N)", read from the lock file). The kernel releases a
  ``flock`` when its holder dies, so a killed station never leaves a device locked.
* **The host-wide records** (``<records>/<key>.changed.json``, ``<records>/<key>.configured.json``,
  written under the lock): a device whose data changed between two reads of a session is never
  cleared by any station of this computer while it holds that session, until a person clears
  it by hand (``stillpoint device clear``, which removes the record); a device configured by any
  station for its current session is not configured again unless asked for explicitly (a clear
  ends that configuration's record).

``<locks>`` is ``<runtime>/station-locks`` (the per-user runtime folder of
``drivers.ax.registry.runtime_dir``: ``$STILLPOINT_RUNTIME_DIR``, ``$XDG_RUNTIME_DIR/stillpoint``
or ``/tmp/stillpoint-<uid>``); ``<records>`` is ``<home>/station`` (the calibration store's root:
``$STILLPOINT_HOME`` or ``~/.local/share/stillpoint``, kept across restarts). With
``$STILLPOINT_STATION_HOST_DIR`` both are in that folder (``locks/``, ``records/``). Each is
private to the user (mode 0700).
The key is the device type and id (``AX3-10001``; an emulated device's also names its emulator
session, whose devices no other session sees, and its emulator's folder).
"""

from __future__ import annotations

import json
import os
import socket
import time
from pathlib import Path
from typing import Optional

from stillpoint.drivers.ax.errors import DeviceError
from stillpoint.drivers.ax.registry import private_folder
from stillpoint.engine.core.errors import StillpointError

from ..core.times import iso_utc

HOST_DIR_ENV = "STILLPOINT_STATION_HOST_DIR"
_NOFOLLOW = os.O_NOFOLLOW | getattr(os, "O_CLOEXEC", 0)


class HostRecordError(StillpointError):
    """The host-wide station folder cannot be used."""


class DeviceBusy(DeviceError):
    """Another station of this computer holds the device."""


def _private_dir(d: Path) -> Path:
    """``d`` made (mode 0700) or checked: this user's folder, closed to others."""
    return private_folder(d, "the stations' host folder", f"set {HOST_DIR_ENV} to a folder of yours",
                          HostRecordError, parents=True)


def lock_dir() -> Path:
    """Where the device locks are (module docstring)."""
    env = os.environ.get(HOST_DIR_ENV)
    if env:
        return _private_dir(Path(env) / "locks")
    from stillpoint.drivers.ax.registry import runtime_dir
    return _private_dir(runtime_dir() / "station-locks")


def record_dir() -> Path:
    """Where the host-wide records are (module docstring): kept across restarts."""
    env = os.environ.get(HOST_DIR_ENV)
    if env:
        return _private_dir(Path(env) / "records")
    from stillpoint.engine.calibration.store import default_root
    return _private_dir(default_root() / "station")


def device_key(device_type: str, device_id: int, emulated: bool = False,
               instance: Optional[str] = None) -> str:
    """``AX3-10001``; an emulated device's key names its emulator session and the emulator's
    folder (``instance``: a fresh emulator run gives the same ids to new devices, which must
    not inherit what was found on the last run's)."""
    key = f"{device_type}-{int(device_id)}"
    if emulated:
        import hashlib
        from stillpoint.drivers.ax.registry import session_name
        tag = hashlib.sha256(str(instance or "").encode()).hexdigest()[:10]
        key = f"emulated.{session_name()}.{tag}.{key}"
    return key


def key_of(att) -> str:
    """The key of an attached device (``discovery.Attached``; an emulated one's control folder
    is its emulator's)."""
    emulated = bool(getattr(att, "emulated", False))
    return device_key(att.device_type, att.device_id, emulated,
                      str(Path(att.control).parent) if emulated and att.control else None)


def holder_text(holder: dict) -> str:
    """"the station on OUT (pid N)" (and the host when it is not this one)."""
    where = holder.get("out")
    host = holder.get("host")
    on = "" if not host or host == socket.gethostname() else f" on host {host}"
    return (f"the {holder.get('what') or 'station'}" + (f" on {where}" if where else "")
            + f" (pid {holder.get('pid', '?')}{on})")


class DeviceLock:
    """The host-wide lock of one device (module docstring). ``acquire()`` raises ``DeviceBusy``
    when another process (or another station of this process) holds it; ``release()`` (or the
    holder's death) frees it."""

    def __init__(self, key: str, out_dir, *, what: str = "station"):
        self.key = key
        self.holder = {"out": str(Path(out_dir).resolve()) if out_dir else None, "pid": os.getpid(),
                       "host": socket.gethostname(), "what": what}
        self.path = lock_dir() / f"{key}.lock"
        self._fd: Optional[int] = None

    @property
    def held(self) -> bool:
        return self._fd is not None

    def acquire(self, device_id=None) -> "DeviceLock":
        import fcntl
        try:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT | _NOFOLLOW, 0o600)
        except OSError as e:
            raise HostRecordError(f"{self.path}: cannot open the device lock: "
                                  f"{e.strerror or e}") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            try:
                other = json.loads(os.pread(fd, 4096, 0).decode(errors="replace") or "{}")
            except (OSError, ValueError):
                other = {}
            os.close(fd)
            raise DeviceBusy(device_id if device_id is not None else self.key,
                             f"held by {holder_text(other)}") from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, json.dumps(dict(self.holder, since=time.time())).encode(), 0)
        self._fd = fd
        return self

    def release(self) -> None:
        if self._fd is not None:
            fd, self._fd = self._fd, None
            try:
                os.ftruncate(fd, 0)
            except OSError:
                pass
            os.close(fd)  # closing the last descriptor releases the flock

    def __enter__(self):
        return self if self.held else self.acquire()

    def __exit__(self, *exc):
        self.release()


# ---------------------------------------------------------------------- host-wide records
def _record_path(key: str, kind: str) -> Path:
    return record_dir() / f"{key}.{kind}.json"


def _write_record(key: str, kind: str, record: dict) -> None:
    p = _record_path(key, kind)
    tmp = p.with_name(f".{p.name}.{os.getpid()}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | _NOFOLLOW, 0o600)
    try:
        os.write(fd, json.dumps(record, sort_keys=True, default=str).encode())
        os.fsync(fd)
    finally:
        os.close(fd)
    os.replace(tmp, p)


def _read_record(key: str, kind: str) -> Optional[dict]:
    p = _record_path(key, kind)
    try:
        fd = os.open(p, os.O_RDONLY | _NOFOLLOW)
    except FileNotFoundError:
        return None
    except OSError as e:
        raise HostRecordError(f"{p}: cannot read the host-wide record: {e.strerror or e}") from None
    try:
        text = os.read(fd, 1 << 16)
    finally:
        os.close(fd)
    try:
        rec = json.loads(text.decode())
    except (ValueError, UnicodeDecodeError):
        raise HostRecordError(f"{p}: the host-wide record is damaged; a person must look at "
                              "the device (and remove the file)") from None
    return rec if isinstance(rec, dict) else None


def _drop_record(key: str, kind: str) -> None:
    try:
        os.unlink(_record_path(key, kind))
    except FileNotFoundError:
        pass


def _stamp(out_dir) -> dict:
    return {"out": str(Path(out_dir).resolve()) if out_dir else None, "pid": os.getpid(),
            "host": socket.gethostname(), "time": time.time(),
            "time_utc": iso_utc(time.time_ns())}


def record_changed(key: str, session: int, out_dir, *, download_id=None,
                   reason: Optional[str] = None) -> None:
    """The device's data changed between two reads of ``session``: no station of this computer
    clears it until a person does (``device clear``)."""
    _write_record(key, "changed", dict(_stamp(out_dir), session=int(session),
                                       download_id=download_id, reason=reason))


def changed_record(key: str) -> Optional[dict]:
    """The host-wide ``changed`` verdict of this device (None: none)."""
    return _read_record(key, "changed")


def forget_changed(key: str) -> None:
    """A person cleared the device by hand: the verdict is settled."""
    _drop_record(key, "changed")


def record_configured(key: str, session: int, out_dir, *, start=None, stop=None) -> None:
    """A station configured the device for ``session``."""
    _write_record(key, "configured", dict(_stamp(out_dir), session=int(session), start=start,
                                          stop=stop))


def configured_record(key: str) -> Optional[dict]:
    """The latest host-wide configuration of this device (None: none)."""
    return _read_record(key, "configured")


def forget_configured(key: str) -> None:
    _drop_record(key, "configured")
