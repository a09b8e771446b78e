"""Reading a device's ``CWA-DATA.CWA``: plain reads for the copy, cache-bypassing reads for the
verification (``posix_fadvise(DONTNEED)`` before and while reading, so the second read comes
from the device, not the page cache), and, for emulated devices, the fault layer.

The fault layer (``FaultyFile``) makes an emulated drive misbehave as a real one can:
``unplug-mid-copy`` (signals the emulator to pull the cable, then fails with ENODEV; fires once),
``short-read`` (end of file early), ``io-error`` (EIO at half the file), ``hang`` (a read that
never returns), ``hang-before-clear`` (every cache-bypassing read after the first, the download's
verification read, never returns: the re-read just before a clear), ``bit-flip`` (one bit differs
in the copy read), ``change-between-reads`` (the file changes before the verification read),
``swap-before-clear`` (after the verification read another device takes the slot). Faults fire at
fractions of the file so they land mid-copy for any recording length.
"""

from __future__ import annotations

import errno
import os
import time
from pathlib import Path
from typing import Optional

from .. import constants as C

_FAULT_AT = {"unplug-mid-copy": 0.4, "short-read": 0.6, "io-error": 0.5, "hang": 0.5}


def drop_cache(fd: int, offset: int = 0, length: int = 0) -> None:
    """Ask the kernel to drop cached pages of ``fd`` (so the next read goes to the device)."""
    if hasattr(os, "posix_fadvise"):
        try:
            os.posix_fadvise(fd, offset, length, os.POSIX_FADV_DONTNEED)
        except OSError:
            pass


class DataFile:
    """A raw, unbuffered read handle on the data file; ``verify=True`` bypasses the cache."""

    def __init__(self, path, verify: bool = False):
        self.path = Path(path)
        self.verify = verify
        self.f = open(self.path, "rb", buffering=0)
        self.pos = 0
        if verify:
            drop_cache(self.f.fileno())

    def size(self) -> int:
        return os.fstat(self.f.fileno()).st_size

    def read(self, n: int) -> bytes:
        b = self.f.read(n)
        if self.verify and b:
            drop_cache(self.f.fileno(), self.pos, len(b))
        self.pos += len(b)
        return b

    def seek(self, pos: int) -> None:
        self.f.seek(pos)
        self.pos = pos

    def close(self) -> None:
        self.f.close()


class FaultyFile(DataFile):
    """``DataFile`` with the emulated drive's faults (see module docstring)."""

    def __init__(self, path, faults, control, verify: bool = False):
        self.faults = set(faults)
        self.control = Path(control) if control else None
        self.total = os.path.getsize(path)
        if verify and "change-between-reads" in self.faults and self._once("change"):
            with open(path, "r+b") as f:  # the device wrote to the file after the copy
                f.seek(C.CWA_HEADER_BYTES + 7 * C.CWA_SECTOR_BYTES + 40)
                b = f.read(1)
                f.seek(-1, os.SEEK_CUR)
                f.write(bytes([b[0] ^ 0xFF]) if b else b"\x00")
        # the first cache-bypassing read is the download's verification; a later one (the re-read
        # before a clear) hangs
        self.hang_now = verify and "hang-before-clear" in self.faults and not self._once("verified")
        super().__init__(path, verify)

    def _once(self, name: str) -> bool:
        """True the first time ``name`` fires for this drive (a marker in the control folder)."""
        if self.control is None:
            return True
        m = self.control / f"fired-{name}"
        try:
            fd = os.open(m, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
        except FileExistsError:
            return False
        os.close(fd)
        return True

    def _signal(self, name: str, wait_gone: Optional[Path] = None) -> None:
        if self.control is not None:
            (self.control / name).write_text("1")
            end = time.monotonic() + 3.0
            while time.monotonic() < end and (self.control / name).exists():
                time.sleep(0.02)
            while wait_gone is not None and time.monotonic() < end and wait_gone.exists():
                time.sleep(0.02)

    def read(self, n: int) -> bytes:
        while self.hang_now:  # a read stuck in the kernel: only the worker's cancel ends it
            time.sleep(3600)
        if not self.verify:
            for fault, frac in _FAULT_AT.items():
                at = int(frac * self.total) // C.CWA_SECTOR_BYTES * C.CWA_SECTOR_BYTES
                if fault in self.faults and self.pos < at < self.pos + n:
                    n = at - self.pos  # read up to the fault's offset first
                elif fault in self.faults and self.pos + n > at:
                    if fault == "unplug-mid-copy" and self._once("unplug"):
                        self._signal("unplug", wait_gone=self.path)
                        raise OSError(errno.ENODEV, f"No such device (reading {self.path})")
                    if fault == "short-read":
                        return b""
                    if fault == "io-error":
                        raise OSError(errno.EIO, f"Input/output error (reading {self.path})")
                    if fault == "hang":
                        while True:  # a read stuck in the kernel: only the worker's cancel ends it
                            time.sleep(3600)
        b = super().read(n)
        if not self.verify and "bit-flip" in self.faults:
            at = C.CWA_HEADER_BYTES + 3 * C.CWA_SECTOR_BYTES + 100
            start = self.pos - len(b)
            if start <= at < self.pos:
                mb = bytearray(b)
                mb[at - start] ^= 0x04
                b = bytes(mb)
        if self.verify and not b and "swap-before-clear" in self.faults and self._once("swap"):
            self._signal("swap")
            time.sleep(0.3)
        return b


def open_data_file(path, *, verify: bool = False, faults=(), control=None) -> DataFile:
    """The data file for reading (emulated drives with faults get the fault layer)."""
    if faults:
        return FaultyFile(path, faults, control, verify)
    return DataFile(path, verify)
