"""Completing a download, and resolving what a killed station left half done.

The ledger is the one place a download is completed: ``complete(ledger, download_id, ...)`` writes
the row as ``completing`` with the copy's size and SHA-256, then gives the files their final
names (``<stem>.cwa.part`` -> ``<stem>.cwa`` as a hard link then an unlink, so an existing file is
never replaced; ``<stem>.unverified.mcap`` -> ``<stem>.mcap``), fsyncs the folder, then writes
``verified``. A kill between any two of these steps leaves a state ``reconcile`` resolves:

* a ``completing`` row: the final copy whose SHA-256 is the row's, or else the partial copy whose
  SHA-256 is the row's, is (re)named into place and the row becomes ``verified``; with neither,
  the row becomes ``error`` and the device is downloaded again;
* a ``downloading`` row (no download runs while the folder's station lock is free): ``error``;
  its partial copy resumes when the device comes back.

``resolve_sent_clear(ledger, device_id, data_file, device_type=...)`` settles a clear of this
device type and id left at ``sent`` by looking at the device (re-read as before a clear): a data
file holding only a header means the clear was done (``ok``); a data file whose SHA-256 is still
the verified one means it was not (``error``, "not cleared").
"""

from __future__ import annotations

import errno
import os
import stat
from pathlib import Path
from typing import Callable, Optional

from stillpoint.drivers import constants as C
from stillpoint.drivers.byteio import sha256_file
from stillpoint.engine.core.outputs import fsync_folder

from . import names
from .ledger import kill_point


class CompletionError(Exception):
    """A file cannot be given its final name (one line: which file and why)."""


def part_of(final) -> Path:
    return Path(str(final) + names.PART)


def unverified_log_of(log_final) -> Path:
    p = Path(log_final)
    return p.with_name(p.name[: -len(names.LOG)] + names.UNVERIFIED_LOG) \
        if p.name.endswith(names.LOG) else p.with_name(p.name + ".unverified")


def _plain_file(p: Path) -> Optional[os.stat_result]:
    try:
        st = os.lstat(p)
    except FileNotFoundError:
        return None
    return st if stat.S_ISREG(st.st_mode) else None


def place_raw(part: Path, final: Path, sha256: str) -> None:
    """Give the verified partial copy its final name, never replacing another file."""
    if _plain_file(part) is not None:
        try:
            os.link(part, final, follow_symlinks=False)
        except FileExistsError:
            a, b = os.lstat(part), os.lstat(final)
            if (a.st_dev, a.st_ino) != (b.st_dev, b.st_ino) and \
                    (not stat.S_ISREG(b.st_mode) or sha256_file(final) != sha256):
                raise CompletionError(f"{final} already exists and is not this download's copy; "
                                      f"the verified copy stays as {part.name}") from None
        os.unlink(part)
        return
    if _plain_file(final) is None or sha256_file(final) != sha256:
        raise CompletionError(f"neither {part.name} nor {final.name} holds the verified copy "
                              f"(SHA-256 {sha256[:16]})")


def place_log(pending: Path, final: Path) -> bool:
    """The corrected log to its final name (derived data: an older one there is replaced)."""
    if _plain_file(pending) is not None:
        os.replace(pending, final)
        return True
    return _plain_file(final) is not None


def complete(ledger, download_id: int, *, cwa_path, mcap_path, sha256: str, bytes_: int,
             bad_sectors: int, summary: Optional[dict] = None, with_log: bool = True,
             reason: Optional[str] = None, reread_ranges: int = 0, patched_ranges: int = 0) -> None:
    """Record the verified copy and rename its files into place (module docstring)."""
    final = Path(cwa_path)
    ledger.download_completing(download_id, bytes_=bytes_, sha256=sha256, bad_sectors=bad_sectors,
                               cwa_path=str(final), mcap_path=str(mcap_path) if mcap_path else None,
                               summary=summary, reread_ranges=reread_ranges,
                               patched_ranges=patched_ranges)
    place_raw(part_of(final), final, sha256)
    kill_point("completion:raw-renamed")
    if with_log and mcap_path:
        place_log(unverified_log_of(mcap_path), Path(mcap_path))
    fsync_folder(final.parent)
    kill_point("completion:renamed")
    ledger.download_verified(download_id, bytes_=bytes_, sha256=sha256, bad_sectors=bad_sectors,
                             cwa_path=str(final), mcap_path=str(mcap_path) if mcap_path else None,
                             reason=reason)


def reconcile(ledger) -> list[str]:
    """Resolve the download rows a killed station left between states; returns one line each."""
    lines = []
    for rec in ledger.downloads_in("completing"):
        final = Path(rec.cwa_path)
        try:
            place_raw(part_of(final), final, rec.sha256)
            if rec.mcap_path:
                place_log(unverified_log_of(rec.mcap_path), Path(rec.mcap_path))
            fsync_folder(final.parent)
        except (CompletionError, OSError) as e:
            why = str(e) if isinstance(e, CompletionError) else f"{final}: {e.strerror or e}"
            ledger.download_failed(rec.id, f"interrupted while completing: {why}; the device is "
                                           "downloaded again", rec.bytes)
            lines.append(f"download {rec.id} ({final.name}): {why}")
            continue
        ledger.download_verified(rec.id, bytes_=rec.bytes, sha256=rec.sha256,
                                 bad_sectors=rec.bad_sectors or 0,
                                 cwa_path=str(final), mcap_path=rec.mcap_path,
                                 reason="completed after a restart")
        lines.append(f"download {rec.id} ({final.name}): completed after a restart")
    for rec in ledger.downloads_in("downloading"):
        ledger.download_failed(rec.id, "interrupted: the station stopped during the download; the "
                                       "partial copy resumes when the device is attached", rec.bytes)
        lines.append(f"download {rec.id}: interrupted (resumes)")
    return lines


def resolve_sent_clear(ledger, device_id: int, data_file, *, device_type: Optional[str] = None,
                       reread: Optional[Callable] = None) -> list[str]:
    """Settle this device's clears left at ``sent`` by looking at its data file (module
    docstring); returns one line per clear settled. ``reread(data_file) -> DeviceDigest``: as
    for a clear (``clearing.check_bytes``)."""
    from .clearing import default_reread
    reread = reread or default_reread
    lines = []
    for clear_id, session, _download_id, sha in ledger.sent_clears(device_id, device_type):
        try:
            size = os.stat(data_file).st_size
            if size <= C.AX_EMPTY_DATA_BYTES:
                result, why = "ok", ("settled after a restart: the device's data file holds only "
                                     "a header (the clear was done)")
            elif reread(data_file).sha256 == sha:
                result, why = "error", ("not cleared: the station stopped before the clear took "
                                        "effect; the verified data is still on the device")
            else:
                result, why = "error", ("not cleared: settled after a restart, the device holds "
                                        "data that is not the verified download")
        except OSError as e:
            if e.errno in (errno.ENOENT, errno.ENODEV):
                continue  # not readable now: settled when the device is next attached
            raise
        ledger.clear_result(clear_id, result, why)
        lines.append(f"clear {clear_id} (session {session}): {why}")
    return lines

