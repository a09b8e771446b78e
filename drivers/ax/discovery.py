"""Finding attached AX3/AX6 devices: serial port + drive, paired by device id.

A port counts only if all of these hold (VID:PID 04D8:0057 is Microchip's generic composite ID,
never enough alone): VID:PID, a serial number starting ``CWA``/``AX6`` and the manufacturer string
(usb-protocols.md A1-A2). The station additionally requires a valid ``ID`` reply naming the same
device id before it touches the device. Drives: mounted volumes whose label is
``AX3??_<id>``/``AX6??_<id>`` and whose root holds ``CWA-DATA.CWA`` (Linux: ``/proc/self/mountinfo``
with labels from ``/dev/disk/by-label``, else the mount folder's name; no ``/media/<label>``
assumption). A port without a mounted drive is reported with the reason (still enumerating,
drive ejected by a COMMIT, not mounted by the desktop).

Backends are injectable: ``SystemBackend`` (pyserial ``list_ports`` + mounts), ``EmulatedBackend``
(the emulator registry, see ``registry``), ``CombinedBackend`` (both; the default).
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Optional

from .. import constants as C
from . import registry

_LABEL_RE = re.compile(r"^(AX[36])[0-9A-Fa-f]{0,2}_0*(\d+)$")
_SERIAL_ID_RE = re.compile(r"(\d+)\s*$")


@dataclass
class PortInfo:
    """What USB enumeration says about one serial port."""

    device: str  # /dev/ttyACM0, /dev/pts/5 or axemu://CWA17_12345
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
    return (p.vid == C.AX_USB_VID and p.pid == C.AX_USB_PID
            and device_type_of_serial(p.serial_number or "") is not None
            and device_id_of_serial(p.serial_number or "") is not None
            and (p.manufacturer or "").strip() == C.AX_MANUFACTURER)


def label_device(label: str) -> Optional[tuple[str, int]]:
    """``AX317_12345`` -> ("AX3", 12345); None if not an AX volume label."""
    m = _LABEL_RE.match(label or "")
    return (m.group(1).upper(), int(m.group(2))) if m else None


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


class SystemBackend:
    """Real USB devices: pyserial ``list_ports`` and the mount table."""

    def ports(self) -> list[PortInfo]:
        try:
            from serial.tools import list_ports
            found = list_ports.comports()
        except Exception:  # pragma: no cover - no serial support on this system
            return []
        return [PortInfo(p.device, p.serial_number, p.manufacturer, p.vid, p.pid, p.location)
                for p in found]

    def volumes(self) -> list[tuple[str, str]]:
        try:
            text = Path("/proc/self/mountinfo").read_text()
        except OSError:
            return []
        return parse_mountinfo(text, _by_label())


class EmulatedBackend:
    """Emulated devices registered by ``stillpoint device emulate`` or tests (any process)."""

    def ports(self) -> list[PortInfo]:
        return [PortInfo(e["port"], e["serial"], e["manufacturer"], e["vid"], e["pid"], e["slot"],
                         emulated=True, faults=tuple(e.get("faults", ())), control=e.get("control"),
                         media=e.get("media"), read_bps=e.get("read_bps"))
                for e in registry.entries()]

    def volumes(self) -> list[tuple[str, str]]:
        out = []
        for e in registry.entries():
            media = Path(e["media"])
            if media.is_dir():
                for p in media.iterdir():
                    if p.is_dir():
                        out.append((str(p), p.name))
        return out


class CombinedBackend:
    def __init__(self, backends: Iterable = (SystemBackend(), EmulatedBackend())):
        self.backends = list(backends)

    def ports(self) -> list[PortInfo]:
        return [p for b in self.backends for p in b.ports()]

    def volumes(self) -> list[tuple[str, str]]:
        return [v for b in self.backends for v in b.volumes()]


def discover(backend=None, *, port: Optional[str] = None, volume: Optional[str] = None) -> list[Attached]:
    """Every attached AX3/AX6 (ports that pass the checks, paired with their drive). ``port`` /
    ``volume``: manual overrides (a port not enumerated as an AX, a drive mounted elsewhere)."""
    backend = backend or CombinedBackend()
    vols: dict[int, list[str]] = {}
    for mnt, label in backend.volumes():
        ld = label_device(label)
        if ld and os.path.isfile(os.path.join(mnt, C.AX_DATA_FILE)):
            vols.setdefault(ld[1], []).append(mnt)
    if volume:
        ld = label_device(os.path.basename(volume.rstrip("/")))
        if ld:
            vols[ld[1]] = [volume]
    out = []
    for p in backend.ports():
        if port and p.device != port:
            continue
        if not is_ax_port(p) and not (port and p.device == port):
            continue
        dev_id = device_id_of_serial(p.serial_number or "")
        kind = device_type_of_serial(p.serial_number or "") or "AX3"
        if dev_id is None:
            continue
        mounts = vols.get(dev_id, [])
        if volume and port:
            mounts = [volume]
        problem = None
        if not mounts:
            problem = ("no mounted drive with label AX3??_/AX6??_<id> holding CWA-DATA.CWA (still "
                       "enumerating, ejected by a COMMIT, or not mounted: use --volume)")
        elif len(mounts) > 1:
            problem = f"more than one drive claims device {dev_id}: {', '.join(mounts)}"
        out.append(Attached(dev_id, kind, p.serial_number or "", p.device,
                            mounts[0] if len(mounts) == 1 else None, p.location or p.device,
                            emulated=p.emulated, faults=tuple(p.faults), control=p.control,
                            problem=problem, read_bps=p.read_bps))
    return sorted(out, key=lambda a: (a.slot, a.device_id))
