"""The runtime registry of emulated devices, so that discovery in any process finds them.

Each running emulated device writes ``<runtime>/devices/<serial>.json`` (what a USB host would
enumerate: serial number, manufacturer, VID:PID, the serial port, the folder its drive is
mounted under, the folder that is its drive while present but not mounted, the dock slot) and
removes it when unplugged. ``<runtime>`` is
``$STILLPOINT_RUNTIME_DIR``, else ``$XDG_RUNTIME_DIR/stillpoint``, else ``/tmp/stillpoint-<uid>``.
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from pathlib import Path


def runtime_dir() -> Path:
    env = os.environ.get("STILLPOINT_RUNTIME_DIR")
    if env:
        return Path(env)
    xdg = os.environ.get("XDG_RUNTIME_DIR")
    if xdg and os.path.isdir(xdg):
        return Path(xdg) / "stillpoint"
    return Path(tempfile.gettempdir()) / f"stillpoint-{os.getuid()}"


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
    return runtime_dir() / "devices"


def register(entry: dict) -> Path:
    d = devices_dir()
    d.mkdir(parents=True, exist_ok=True)
    p = d / f"{entry['serial']}.json"
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
    out = []
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
