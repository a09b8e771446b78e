"""Does a data file header name device N of type T, as each firmware writes it?

AX3 firmware V50 writes only the low 16 bits of the device id in the header and leaves the upper
word erased (0xFFFF); the AX6 firmware writes both words (``constants.CWA_UPPER_ID_UNSET`` cites
the lines). ``header_names_device`` is the one answer used by the download's header check and by
the clear rule.
"""

from __future__ import annotations

from stillpoint.drivers import constants as C


def header_names_device(header: dict, device_id: int, device_type: str) -> bool:
    """True when the parsed header (``cwa_layout.parse_header``) is the data file of device
    ``device_id`` of type ``device_type`` ("AX3" | "AX6")."""
    if header.get("device_type") != device_type:
        return False
    low, upper = header["device_id_low"], header["upper_device_id"]
    if low != device_id & 0xFFFF:
        return False
    if upper == device_id >> 16:
        return True
    # an AX3 header with the upper word not written names the device by its low 16 bits
    return device_type == "AX3" and upper == C.CWA_UPPER_ID_UNSET


def header_device_text(header: dict) -> str:
    """How a header names its device, for messages ("AX3 57920 (low 16 bits only)")."""
    kind = header.get("device_type", "unknown")
    if header.get("upper_device_id") == C.CWA_UPPER_ID_UNSET:
        return f"{kind} {header['device_id_low']} (low 16 bits of the id only)"
    return f"{kind} {header['device_id']}"
