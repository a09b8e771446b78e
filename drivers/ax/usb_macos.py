"""macOS: which mounted volume belongs to which USB serial number, from ``system_profiler``.

``system_profiler SPUSBDataType -json`` prints the USB tree as JSON: each device an object with
``_name``, ``vendor_id`` (``"0x04d8"``, sometimes followed by the vendor's name in brackets),
``product_id``, ``serial_num``, ``location_id`` and, for a mass-storage device, ``Media``: a list
of disks (``bsd_name`` ``disk4``) each with ``volumes`` (``_name`` = the label, ``bsd_name``
``disk4s1``, ``mount_point`` when mounted); hubs hold their devices in ``_items``. The drive and
the serial port (pyserial: ``/dev/cu.usbmodem...`` with the same ``serial_number``) pair through
that serial. A system whose ``system_profiler`` has no ``SPUSBDataType`` section gives no
topology; discovery then falls back to the volume labels under ``/Volumes``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Optional

from .. import constants as C

COMMAND = ["system_profiler", "SPUSBDataType", "-json"]


@dataclass
class MacDrive:
    usb_serial: Optional[str]
    bsd_name: str  # disk4s1
    mount: Optional[str]  # /Volumes/AX317_12345; None: present, not mounted
    label: Optional[str]


def _hex(v) -> Optional[int]:
    try:
        return int(str(v).split()[0], 16)
    except (ValueError, IndexError):
        return None


def _walk(items):
    for it in items or []:
        if isinstance(it, dict):
            yield it
            yield from _walk(it.get("_items"))


def parse_usb_tree(text: str) -> Optional[list[MacDrive]]:
    """Drives of every 04D8:0057 device in ``system_profiler SPUSBDataType -json`` output;
    None when the output has no ``SPUSBDataType`` section (no topology on this system)."""
    doc = json.loads(text or "{}")
    if not isinstance(doc, dict) or "SPUSBDataType" not in doc:
        return None
    out = []
    for dev in _walk(doc["SPUSBDataType"]):
        if (_hex(dev.get("vendor_id")), _hex(dev.get("product_id"))) != (C.AX_USB_VID, C.AX_USB_PID):
            continue
        serial = dev.get("serial_num") or None
        for media in dev.get("Media") or []:
            vols = media.get("volumes") or []
            if not vols:  # a disk without a partition map is its own volume
                vols = [media]
            for v in vols:
                out.append(MacDrive(serial, str(v.get("bsd_name") or ""), v.get("mount_point") or None,
                                    v.get("_name")))
    return out
