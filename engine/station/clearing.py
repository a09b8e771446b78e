"""The only code path that erases a device.

``clear_verified(client, ledger, device_id, session_id, data_file, wait_volume, *, device_type,
erase)`` erases only when all of these hold, checked immediately before the erase:

* the ledger holds a verified download of this device id and session;
* ``ID`` names the same device id, type and session (another device may be in the slot), and
  ``SESSION`` the same session;
* the data file's header names the same device (as its firmware writes the id:
  ``drivers.ax.identity``) and session;
* **the bytes**: the raw copy on disk is hashed again and its size and SHA-256 equal the ledger's
  verified ones, and the device's data file is re-read (streamed, bypassing the page cache as
  the download's verification read does: ``volume.open_data_file(verify=True)``) and its size and
  SHA-256 equal them too. A copy damaged after verification, a device whose bytes changed, a
  ledger row that does not describe the bytes: each refuses the clear (``ClearRefused``, one line).

Then the vendor's clear: "never log" (``HIBERNATE -1``, ``STOP -1``, ``SESSION 0``, each read
back), ``FORMAT QC`` (``erase="quick"``, the default) or ``FORMAT WC`` (``"wipe"``), the drive's
return, and the read-back: the re-created data file holds only a header (at most 1024 bytes)
that names the device and says "never record" (start >= stop, the firmware's rule), and
``HIBERNATE``/``STOP`` read back ``-1`` on the wire. The clear is recorded in the ledger before
the erase (``sent``, with the erase level) and its result after (``ok`` or ``error``, with the
read-back). Nothing else in the station erases a device.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path
from typing import Optional

from stillpoint.drivers import constants as C
from stillpoint.drivers.ax.errors import DeviceError
from stillpoint.drivers.ax.identity import header_device_text, header_names_device
from stillpoint.drivers.ax.volume import open_data_file
from stillpoint.drivers.byteio import sha256_file
from stillpoint.drivers.cwa_layout import parse_header

READ_CHUNK = 1 << 20


class ClearRefused(DeviceError):
    """The clear rule does not hold: the device is not erased."""


def _header(path: Path) -> dict:
    with open(path, "rb") as f:
        return parse_header(f.read(C.CWA_HEADER_BYTES))


def device_sha256(data_file) -> tuple[int, str]:
    """(bytes, SHA-256) of the device's data file, read in chunks past the page cache."""
    f = open_data_file(data_file, verify=True)
    h = hashlib.sha256()
    n = 0
    try:
        while True:
            b = f.read(READ_CHUNK)
            if not b:
                break
            h.update(b)
            n += len(b)
    finally:
        f.close()
    return n, h.hexdigest()


def copy_sha256(path) -> tuple[int, str]:
    """(bytes, SHA-256) of a raw copy on disk."""
    return os.stat(path).st_size, sha256_file(path)


def check_bytes(device_id: int, rec, data_file) -> None:
    """The byte rule: the raw copy on disk and the device's data file both hold exactly the bytes
    the ledger verified (``rec``: a ``DownloadRecord``). Raises ``ClearRefused``."""
    if not rec.sha256 or rec.bytes is None:
        raise ClearRefused(device_id, "not cleared: the ledger's verified download has no size or "
                                      "SHA-256")
    copy = rec.cwa_path
    try:
        n, sha = copy_sha256(copy)
    except OSError as e:
        raise ClearRefused(device_id, f"not cleared: cannot read the raw copy {copy}: "
                                      f"{e.strerror or e}") from None
    if n != rec.bytes or sha != rec.sha256:
        raise ClearRefused(device_id, f"not cleared: the raw copy {copy} ({n} bytes, SHA-256 "
                                      f"{sha[:16]}) is not the verified download ({rec.bytes} bytes, "
                                      f"{rec.sha256[:16]})")
    try:
        n, sha = device_sha256(data_file)
    except OSError as e:
        raise ClearRefused(device_id, f"not cleared: cannot re-read the data file {data_file}: "
                                      f"{e.strerror or e}") from None
    if n != rec.bytes or sha != rec.sha256:
        raise ClearRefused(device_id, f"not cleared: the device's data file ({n} bytes, SHA-256 "
                                      f"{sha[:16]}) is not the verified copy {copy} ({rec.bytes} "
                                      f"bytes, {rec.sha256[:16]})")


def says_never_record(header: dict) -> bool:
    """The firmware logs only while start < stop (constants.AX_NEVER_LOG cites RunLogging)."""
    return header["logging_start_raw"] >= header["logging_end_raw"]


def set_never_log(client) -> None:
    """``HIBERNATE -1``, ``STOP -1``, ``SESSION 0`` (the vendor's "never log"), each read back."""
    for key, value in C.AX_NEVER_LOG:
        if key == "SESSION":
            got = str(client.session(int(value)))
        elif key == "HIBERNATE":
            got = client.hibernate(value).strip()
        else:
            got = client.stop(value).strip()
        if got != value:
            raise DeviceError(client.name, f"{key} {value} reads back {got!r}")


def session_before_clear(ledger, device_id: int, session_now: int) -> int:
    """The session a profile's "increment" counts from: a clear leaves the device at session 0,
    so the larger of the device's session and the one its last completed clear erased."""
    erased = [c[1] for c in ledger.clears() if c[0] == device_id and c[4] == "ok"]
    return max([session_now] + erased)


def clear_verified(client, ledger, device_id: int, session_id: int, data_file, wait_volume,
                   *, device_type: Optional[str] = None, erase: str = "quick") -> int:
    """Erase the device if (and only if) the rule holds; returns the clear's ledger id."""
    if erase not in C.AX_ERASE_COMMANDS:
        raise ClearRefused(device_id, f"not cleared: erase must be one of "
                                      f"{', '.join(C.AX_ERASE_COMMANDS)}, not {erase!r}")
    rec = ledger.verified_download(device_id, session_id, device_type=device_type)
    if rec is None:
        raise ClearRefused(device_id, f"not cleared: the ledger holds no verified download of "
                                      f"session {session_id}")
    ident = client.identify()
    kind = device_type or ident.device_type
    if ident.device_id != device_id or ident.device_type != kind:
        raise ClearRefused(device_id, f"not cleared: the device in this slot is now "
                                      f"{ident.device_type} {ident.device_id}")
    if ident.session_id != session_id:
        raise ClearRefused(device_id, f"not cleared: the device's session is now {ident.session_id}, "
                                      f"the verified download is of session {session_id}")
    sess = client.session()
    if sess != session_id:
        raise ClearRefused(device_id, f"not cleared: SESSION says {sess}, the verified download is of "
                                      f"session {session_id}")
    path = Path(data_file)
    try:
        h = _header(path)
    except (OSError, ValueError) as e:
        raise ClearRefused(device_id, f"not cleared: cannot re-check the data file {path}: {e}") from None
    if not header_names_device(h, device_id, kind) or h["session_id"] != session_id:
        raise ClearRefused(device_id, f"not cleared: the data file is of device "
                                      f"{header_device_text(h)} session {h['session_id']}")
    check_bytes(device_id, rec, path)
    clear_id = ledger.clear_attempt(device_id, session_id, rec.id, rec.sha256,
                                    erase=C.AX_ERASE_COMMANDS[erase])
    readback = None
    try:
        set_never_log(client)
        client.erase(erase, wait_volume)
        new_path = Path(wait_volume()) if wait_volume else path
        size2 = os.stat(new_path).st_size
        h2 = _header(new_path)
        wire = (client.hibernate().strip(), client.stop().strip())
        readback = (f"{size2} bytes; header {header_device_text(h2)} session {h2['session_id']} "
                    f"start {h2['logging_start']} stop {h2['logging_end']}; HIBERNATE={wire[0]} "
                    f"STOP={wire[1]}")
        if size2 > C.AX_EMPTY_DATA_BYTES:
            raise DeviceError(device_id, f"after {C.AX_ERASE_COMMANDS[erase]} the data file still "
                                         f"has {size2} bytes")
        if not header_names_device(h2, device_id, kind):
            raise DeviceError(device_id, f"after {C.AX_ERASE_COMMANDS[erase]} the data file names "
                                         f"device {header_device_text(h2)}")
        if not says_never_record(h2):
            raise DeviceError(device_id, f"after {C.AX_ERASE_COMMANDS[erase]} the header would record "
                                         f"(start {h2['logging_start']}, stop {h2['logging_end']})")
        if wire != ("-1", "-1"):
            raise DeviceError(device_id, f"after {C.AX_ERASE_COMMANDS[erase]} HIBERNATE/STOP read "
                                         f"back {wire[0]}/{wire[1]}, not -1/-1")
    except (DeviceError, OSError, ValueError) as e:
        why = str(getattr(e, "reason", None) or e)
        ledger.clear_result(clear_id, "error", why, readback)
        raise DeviceError(device_id, f"clear did not complete: {why}") from None
    ledger.clear_result(clear_id, "ok", None, readback)
    return clear_id
