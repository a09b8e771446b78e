"""The only code path that erases a device.

``clear_verified(client, ledger, device_id, session_id, data_file, wait_volume, *, device_type,
erase, reread)`` erases only when all of these hold, checked immediately before the erase:

* the ledger holds a verified download of this device type, id and session;
* ``ID`` names the same device id, type and session (another device may be in the slot), and
  ``SESSION`` the same session;
* **the bytes**: the raw copy on disk is hashed again and its size and SHA-256 equal the ledger's
  verified ones; then the device's data file is read once more (``device_read.device_digest``:
  streamed past the page cache as the download's verification read is, in a worker with the
  download's stall bound), and in that one read its header names the same device (as its
  firmware writes the id: ``drivers.ax.identity``) and session, and its size and SHA-256 equal
  the verified ones. A copy damaged after verification, a device whose bytes changed, a re-read
  that stalls (a pulled drive), a ledger row that does not describe the bytes: each refuses the
  clear (``ClearRefused``, one line).

Then the vendor's clear: "never log" (``HIBERNATE -1``, ``STOP -1``, ``SESSION 0``, each read
back), ``FORMAT QC`` (``erase="quick"``, the default) or ``FORMAT WC`` (``"wipe"``), the drive's
return, and the read-back: the re-created data file holds only a header (at most 1024 bytes)
that names the device and says "never record" (start >= stop, the firmware's rule), and
``HIBERNATE``/``STOP`` read back ``-1`` on the wire. The clear is recorded in the ledger before
the erase (``sent``, with the erase level) and its result after (``ok`` or ``error``, with the
read-back). Nothing else in the station erases a device.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Callable, Optional

from stillpoint.drivers import constants as C
from stillpoint.drivers.ax.errors import DeviceError
from stillpoint.drivers.ax.identity import header_device_text, header_mismatch, header_names_device
from stillpoint.drivers.byteio import sha256_file
from stillpoint.drivers.cwa_layout import parse_header

from .device_read import DeviceDigest, device_digest

DEFAULT_STALL_S = 30.0  # a re-read without progress this long is stopped (the download's default)


class ClearRefused(DeviceError):
    """The clear rule does not hold: the device is not erased."""


def copy_sha256(path) -> tuple[int, str]:
    """(bytes, SHA-256) of a raw copy on disk."""
    return os.stat(path).st_size, sha256_file(path)


def _must_hold(device_id: int, rec, what: str, read_what: str, read, verified: str) -> None:
    """``read()`` gives (bytes, SHA-256) of ``what``; both must be the ledger row's. A read
    fault refuses the clear naming ``read_what``."""
    try:
        n, sha = read()
    except OSError as e:
        raise ClearRefused(device_id, f"not cleared: cannot {read_what}: {e.strerror or e}") from None
    if n != rec.bytes or sha != rec.sha256:
        raise ClearRefused(device_id, f"not cleared: {what} ({n} bytes, SHA-256 {sha[:16]}) is not "
                                      f"{verified} ({rec.bytes} bytes, SHA-256 {rec.sha256[:16]})")


def check_bytes(device_id: int, rec, data_file, reread: Optional[Callable] = None,
                check_header: Optional[Callable[[bytes], None]] = None) -> None:
    """The byte rule: the raw copy on disk and the device's data file both hold exactly the bytes
    the ledger verified (``rec``: a ``DownloadRecord``). ``reread(data_file) -> DeviceDigest``
    re-reads the device once (default: ``device_read.device_digest`` with the stall bound, on a
    thread); ``check_header(head)`` checks the header of that same read. Raises
    ``ClearRefused``."""
    if not rec.sha256 or rec.bytes is None:
        raise ClearRefused(device_id, "not cleared: the ledger's verified download has no size or "
                                      "SHA-256")
    reread = reread or default_reread
    copy = rec.cwa_path
    _must_hold(device_id, rec, f"the raw copy {copy}", f"read the raw copy {copy}",
               lambda: copy_sha256(copy), "the verified download")

    def device() -> tuple[int, str]:
        d = reread(data_file)
        if check_header is not None:
            check_header(d.head)
        return d.bytes, d.sha256
    _must_hold(device_id, rec, "the device's data file", f"re-read the data file {data_file}",
               device, f"the verified copy {copy}")


def default_reread(data_file) -> DeviceDigest:
    """The device re-read with the stall bound, on a thread (a station passes its own ``reread``:
    a worker process, the emulated drive's faults)."""
    return device_digest(data_file, stall_s=DEFAULT_STALL_S, inline=True)


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


def session_before_clear(ledger, device_id: int, session_now: int,
                         device_type: Optional[str] = None) -> int:
    """The session a profile's "increment" counts from: a clear leaves the device at session 0,
    so the larger of the device's session and the one its last completed clear erased."""
    erased = [c[1] for c in ledger.clears(device_id, device_type) if c[4] == "ok"]
    return max([session_now] + erased)


def clear_verified(client, ledger, device_id: int, session_id: int, data_file, wait_volume,
                   *, device_type: Optional[str] = None, erase: str = "quick",
                   reread: Optional[Callable] = None) -> int:
    """Erase the device if (and only if) the rule holds; returns the clear's ledger id.
    ``reread``: how the device is re-read (``check_bytes``)."""
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

    def this_device_and_session(head: bytes) -> None:
        why = header_mismatch(head, device_id, kind, session_id)
        if why:
            raise ClearRefused(device_id, f"not cleared: {why}")
    check_bytes(device_id, rec, path, reread, this_device_and_session)
    clear_id = ledger.clear_attempt(device_id, session_id, rec.id, rec.sha256,
                                    erase=C.AX_ERASE_COMMANDS[erase], device_type=kind)
    readback = None
    try:
        set_never_log(client)
        client.erase(erase, wait_volume)
        new_path = Path(wait_volume()) if wait_volume else path
        after = default_reread(new_path)  # bounded: a drive pulled now cannot hang the flow
        size2, h2 = after.bytes, parse_header(after.head)
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
