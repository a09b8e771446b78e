"""The runtime registry of emulated devices, so that discovery in any process finds them.

Each running emulated device writes ``<runtime>/sessions/<session>/devices/<serial>.json`` (what
a USB host would enumerate: serial number, manufacturer, VID:PID, the serial port, the folder its
drive is mounted under, the folder that is its drive while present but not mounted, the dock
slot) and removes it when unplugged.

* Per user: ``<runtime>`` is ``$STILLPOINT_RUNTIME_DIR``, else ``$XDG_RUNTIME_DIR/stillpoint`` (the
  login manager makes ``$XDG_RUNTIME_DIR`` private to the user), else ``/tmp/stillpoint-<uid>``,
  made private (mode 0700) and refused when another user owns it or others may write to it.
* Per session: ``<session>`` is ``$STILLPOINT_EMULATOR_SESSION`` (``device emulate --session``),
  else the login session (``$XDG_SESSION_ID``: every terminal of one desktop or ssh login), else
  ``default``. Discovery reads only its own session, so two users, or two logins of one user,
  never see each other's emulated devices; a program in another session sees them when asked,
  with the same ``STILLPOINT_EMULATOR_SESSION``.

A serial that a running process has registered in the session is refused to another process
(``RegistryError``): two emulators never share a device's name.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import stat
import tempfile
from pathlib import Path

from stillpoint.engine.core.errors import StillpointError

SESSION_ENV = "STILLPOINT_EMULATOR_SESSION"
_SESSION_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,63}$")


class RegistryError(StillpointError):
    """The registry folder cannot be trusted or a device name is taken."""


def private_folder(d: Path, what: str = "the emulator registry folder",
                   hint: str = "set STILLPOINT_RUNTIME_DIR to a folder of yours",
                   error: type | None = None, parents: bool = False) -> Path:
    """``d`` made (mode 0700) or checked: it must be this user's folder, closed to others (a
    shared temp folder: another user could have made it first to read or plant entries).
    ``what`` names the folder and ``hint`` the way out in the one-line ``error`` (RegistryError)."""
    error = error or RegistryError
    try:
        d.mkdir(mode=0o700, parents=parents, exist_ok=True)
        st = os.lstat(d)
    except OSError as e:
        raise error(f"{d}: cannot make {what}: {e.strerror or e}") from None
    if not stat.S_ISDIR(st.st_mode):
        raise error(f"{d}: {what} must be a folder, not a link or a file")
    if hasattr(os, "getuid") and st.st_uid != os.getuid():
        raise error(f"{d}: {what} belongs to another user (uid {st.st_uid}); {hint}")
    if st.st_mode & 0o022:
        raise error(f"{d}: {what} may be written by other users "
                    f"(mode {stat.S_IMODE(st.st_mode):o}); chmod 700 it")
    return d


def runtime_dir() -> Path:
    """This user's runtime folder (module docstring)."""
    env = os.environ.get("STILLPOINT_RUNTIME_DIR")
    if env:
        return Path(env)
    xdg = os.environ.get("XDG_RUNTIME_DIR")
    if xdg and os.path.isdir(xdg):
        return Path(xdg) / "stillpoint"
    uid = os.getuid() if hasattr(os, "getuid") else 0
    return private_folder(Path(tempfile.gettempdir()) / f"stillpoint-{uid}")


def session_name() -> str:
    """The emulator session this process registers in and discovers from (module docstring)."""
    name = os.environ.get(SESSION_ENV) or ""
    if name:
        if not _SESSION_RE.match(name):
            raise RegistryError(f"{SESSION_ENV}={name!r}: a session name is 1-64 letters, digits, "
                                "'.', '_' or '-'")
        return name
    login = os.environ.get("XDG_SESSION_ID") or ""
    return f"login-{login}" if login and _SESSION_RE.match(login) else "default"


def session_dir() -> Path:
    """``<runtime>/sessions/<session>``: this session's devices and, by default, drives."""
    return runtime_dir() / "sessions" / session_name()


@contextlib.contextmanager
def using_runtime_dir(folder):
    """``$STILLPOINT_RUNTIME_DIR`` is ``folder`` within the block (this process and the ones it
    starts find the emulated devices registered there), then what it was."""
    old = os.environ.get("STILLPOINT_RUNTIME_DIR")
    os.environ["STILLPOINT_RUNTIME_DIR"] = str(folder)
    try:
        yield Path(folder)
    finally:
        if old is None:
            os.environ.pop("STILLPOINT_RUNTIME_DIR", None)
        else:
            os.environ["STILLPOINT_RUNTIME_DIR"] = old


def devices_dir() -> Path:
    return session_dir() / "devices"


def register(entry: dict) -> Path:
    d = devices_dir()
    d.mkdir(parents=True, exist_ok=True)
    p = d / f"{entry['serial']}.json"
    try:
        other = json.loads(p.read_text())
    except (OSError, ValueError):
        other = {}
    pid = int(other.get("owner_pid", 0) or 0)
    if pid and pid != entry.get("owner_pid") and _alive(pid):
        raise RegistryError(f"device {entry['serial']} is already emulated in session "
                            f"{session_name()!r} by process {pid}: choose other ids (--first-id) "
                            "or another session (--session)")
    tmp = p.with_name(p.name + ".tmp")
    tmp.write_text(json.dumps(entry))
    os.replace(tmp, p)
    return p


def unregister(serial: str) -> None:
    try:
        (devices_dir() / f"{serial}.json").unlink()
    except FileNotFoundError:
        pass


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def entries() -> list[dict]:
    """Registered devices whose emulator process is still running (stale entries are removed)."""
    d = devices_dir()
    out: list[dict] = []
    if not d.is_dir():
        return out
    for p in sorted(d.glob("*.json")):
        try:
            e = json.loads(p.read_text())
        except (OSError, ValueError):
            continue
        if not _alive(int(e.get("owner_pid", 0))):
            try:
                p.unlink()
            except OSError:
                pass
            continue
        out.append(e)
    return out
