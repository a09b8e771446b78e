"""Does a data file header name device N of type T, as each firmware writes it?

AX3 firmware V50 writes only the low 16 bits of the device id in the header and leaves the upper
word erased (0xFFFF); the AX6 firmware writes both words (``constants.CWA_UPPER_ID_UNSET`` cites
the lines). ``header_names_device`` is the one answer; ``header_mismatch`` applies it (and the
session) to a data file's first bytes for the download's header check and for the clear rule.
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


def header_mismatch(head: bytes, device_id: int, device_type: str, session_id: int):
    """None when ``head`` (a data file's first bytes) is the header of this device's session;
    else why not, as one line."""
    from stillpoint.drivers.cwa_layout import parse_header
    try:
        h = parse_header(head)
    except ValueError as e:
        return f"the data file header is not readable: {e}"
    if not header_names_device(h, device_id, device_type):
        return (f"the data file header names device {header_device_text(h)}, not {device_type} "
                f"{device_id}")
    if h["session_id"] != session_id:
        return (f"session mismatch: the data file header says session {h['session_id']}, the "
                f"device's SESSION {session_id}")
    return None


def header_device_text(header: dict) -> str:
    """How a header names its device, for messages ("AX3 57920 (low 16 bits only)")."""
    kind = header.get("device_type", "unknown")
    if header.get("upper_device_id") == C.CWA_UPPER_ID_UNSET:
        return f"{kind} {header['device_id_low']} (low 16 bits of the id only)"
    return f"{kind} {header['device_id']}"
