"""The only code path that clears a device (``CLEAR DATA``).

``clear_verified(client, ledger, device_id, session_id, data_file, wait_volume)`` sends the clear
only when all of these hold, checked immediately before the command:

* the ledger holds a verified download of this device id and session whose raw copy exists;
* ``ID`` names the same device id and session (another device may be in the slot), and
  ``SESSION`` the same session;
* the data file's header names the same device and session, and its size equals the verified
  download's byte count.

The clear is recorded in the ledger before the command is sent (``sent``) and its result after
the drive comes back (``ok`` when the re-created file holds only a header with the same device
id and the device's current rate and session, or ``error`` with the reason). Any refusal raises ``ClearRefused``; nothing else in the
station sends ``CLEAR DATA``.
"""

from __future__ import annotations

import os
from pathlib import Path

from stillpoint.drivers import constants as C
from stillpoint.drivers.ax.errors import DeviceError
from stillpoint.drivers.cwa_layout import parse_header


class ClearRefused(DeviceError):
    """The clear rule does not hold: the device is not cleared."""


def _header(path: Path) -> dict:
    with open(path, "rb") as f:
        return parse_header(f.read(C.CWA_HEADER_BYTES))


def clear_verified(client, ledger, device_id: int, session_id: int, data_file, wait_volume) -> int:
    """Clear the device if (and only if) the rule holds; returns the clear's ledger id."""
    rec = ledger.verified_download(device_id, session_id)
    if rec is None:
        raise ClearRefused(device_id, f"not cleared: the ledger holds no verified download of "
                                      f"session {session_id}")
    ident = client.identify()
    if ident.device_id != device_id:
        raise ClearRefused(device_id, f"not cleared: the device in this slot is now {ident.device_id}")
    if ident.session_id != session_id:
        raise ClearRefused(device_id, f"not cleared: the device's session is now {ident.session_id}, "
                                      f"the verified download is of session {session_id}")
    sess = client.session()
    if sess != session_id:
        raise ClearRefused(device_id, f"not cleared: SESSION says {sess}, the verified download is of "
                                      f"session {session_id}")
    path = Path(data_file)
    try:
        size = os.stat(path).st_size
        h = _header(path)
    except (OSError, ValueError) as e:
        raise ClearRefused(device_id, f"not cleared: cannot re-check the data file {path}: {e}") from None
    if h["device_id"] != device_id or h["session_id"] != session_id:
        raise ClearRefused(device_id, f"not cleared: the data file is of device {h['device_id']} "
                                      f"session {h['session_id']}")
    if size != rec.bytes:
        raise ClearRefused(device_id, f"not cleared: the data file has {size} bytes, the verified "
                                      f"download {rec.bytes}")
    clear_id = ledger.clear_attempt(device_id, session_id, rec.id, rec.sha256)
    try:
        client.clear_data(wait_volume)
        new_path = Path(wait_volume()) if wait_volume else path
        size2 = os.stat(new_path).st_size
        h2 = _header(new_path)
        if size2 > C.AX_EMPTY_DATA_BYTES:
            raise DeviceError(device_id, f"after CLEAR the data file still has {size2} bytes")
        if h2["device_id"] != device_id:
            raise DeviceError(device_id, f"after CLEAR the data file names device {h2['device_id']}")
        code = client.rate()[0]
        if h2["rate_code"] != code or h2["session_id"] != client.session():
            raise DeviceError(device_id, f"after CLEAR the header's settings (rate code "
                                         f"{h2['rate_code']}, session {h2['session_id']}) differ from "
                                         "the device's")
    except (DeviceError, OSError, ValueError) as e:
        ledger.clear_result(clear_id, "error", str(getattr(e, "reason", e)))
        raise DeviceError(device_id, f"clear did not complete: {getattr(e, 'reason', e)}") from None
    ledger.clear_result(clear_id, "ok")
    return clear_id
