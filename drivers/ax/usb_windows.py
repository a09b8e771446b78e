"""Windows: which drive letter belongs to which USB serial number, from the OS's own CIM classes.

One PowerShell call (``DISKS_SCRIPT``) lists every USB disk (``Win32_DiskDrive`` with
``InterfaceType='USB'``) with its ``PNPDeviceID``, its ``SerialNumber`` and the drive letters and
volume names reached through ``Win32_DiskDriveToDiskPartition`` and
``Win32_LogicalDiskToPartition`` (``Get-CimAssociatedInstance`` follows those associations), as
one JSON array. The mass-storage disk of a device with a USB serial number has the instance id
``USBSTOR\\DISK&VEN_...&PROD_...&REV_...\\<serial>&<LUN>``: the serial is the last path part
without its ``&<LUN>`` (Microsoft, "Device Instance ID" / "USB serial number" in the USB driver
documentation). A device Windows found no usable serial for gets a generated instance
(``7&2a3b4c5d&0&0``); such a disk has no known USB device, so only its label can pair it.
OmApi's Windows finder pairs through the same PnP tree (composite parent -> CDC port and USBSTOR
disk -> volume).

Serial ports come from pyserial (``serial_number``, else ``SER=`` in ``hwid``); on Windows its
``manufacturer`` is the driver INF's, so it is never used to filter.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from typing import Optional

DISKS_SCRIPT = (
    "$ErrorActionPreference='Stop';"
    "$rows=@(Get-CimInstance -ClassName Win32_DiskDrive -Filter \"InterfaceType='USB'\" | ForEach-Object {"
    "$d=$_;"
    "$v=@($d | Get-CimAssociatedInstance -ResultClassName Win32_DiskPartition | "
    "Get-CimAssociatedInstance -ResultClassName Win32_LogicalDisk | "
    "ForEach-Object { [pscustomobject]@{DeviceID=$_.DeviceID; VolumeName=$_.VolumeName} });"
    "[pscustomobject]@{PNPDeviceID=$d.PNPDeviceID; SerialNumber=$d.SerialNumber; Disk=$d.DeviceID; Volumes=$v}"
    "});"
    "ConvertTo-Json -InputObject $rows -Depth 4 -Compress"
)
COMMAND = ["powershell.exe", "-NoProfile", "-NonInteractive", "-Command", DISKS_SCRIPT]

_GENERATED = re.compile(r"^\d+&[0-9A-Fa-f]+&\d+$")  # a PnP-generated instance, not a serial


@dataclass
class WinDrive:
    usb_serial: Optional[str]  # None: Windows knows no serial for this disk
    disk: str  # \\.\PHYSICALDRIVE2
    mount: Optional[str]  # E:\ ; None: the disk has no drive letter
    label: Optional[str]


def serial_of_pnp_id(pnp: str) -> Optional[str]:
    """``USBSTOR\\DISK&VEN_X&PROD_Y&REV_1\\CWA17_12345&0`` -> ``CWA17_12345``; None when the
    instance is generated (no serial) or the id is not a USBSTOR disk."""
    parts = (pnp or "").split("\\")
    if len(parts) < 3 or parts[0].upper() != "USBSTOR":
        return None
    inst = parts[-1]
    m = re.match(r"^(.*)&\d+$", inst)
    serial = m.group(1) if m else inst
    if not serial or _GENERATED.match(serial):
        return None
    return serial


def parse_disks(text: str) -> list[WinDrive]:
    """The JSON of ``DISKS_SCRIPT`` (an array; a single object or empty output are accepted,
    as ``ConvertTo-Json`` prints them)."""
    text = (text or "").strip()
    if not text:
        return []
    rows = json.loads(text)
    if isinstance(rows, dict):
        rows = [rows]
    out = []
    for r in rows:
        if not isinstance(r, dict):
            continue
        serial = serial_of_pnp_id(r.get("PNPDeviceID") or "")
        vols = r.get("Volumes") or []
        if isinstance(vols, dict):
            vols = [vols]
        disk = str(r.get("Disk") or "")
        if not vols:
            out.append(WinDrive(serial, disk, None, None))
        for v in vols:
            letter = str(v.get("DeviceID") or "").rstrip("\\")
            out.append(WinDrive(serial, disk, letter + "\\" if letter else None, v.get("VolumeName")))
    return out


_SER_RE = re.compile(r"SER=(\S+)")


def port_serial(serial_number: Optional[str], hwid: Optional[str]) -> Optional[str]:
    """pyserial's ``serial_number``, else the ``SER=`` field of its ``hwid``."""
    if serial_number:
        return serial_number
    m = _SER_RE.search(hwid or "")
    return m.group(1) if m else None
