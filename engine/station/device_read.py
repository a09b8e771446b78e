"""Reading a device's whole data file again, past the page cache: the one read behind every
device hash of the station (the download's verification read, the re-read just before a clear,
``device verify``, settling a clear a killed station left at ``sent``).

``read_device(data_file, ...) -> DeviceDigest`` streams the file in chunks through
``volume.open_data_file(verify=True)`` (an emulated drive's faults apply) and returns its size, its
SHA-256, its first ``CWA_HEADER_BYTES`` (the header, checked from the same read that is hashed)
and, with ``ranges=True``, one hash per ``CHECK_BYTES`` range (what the download compares with its
copy). ``progress(phase, done, total)``, ``cancel`` and ``throttle_bps`` serve the
download's worker.

``device_digest(data_file, ..., stall_s=...)`` is the same read with the download's stall bound: it
runs in a worker process (``worker.Worker``; a thread with ``inline=True``), so a read that hangs
on a pulled drive ends in ``ReadStalled`` (an ``OSError``: "no progress for N s") after
``stall_s`` without progress, never in a hung device flow.
"""

from __future__ import annotations

import errno
import hashlib
import threading
import time
from dataclasses import dataclass, field
from typing import Callable, Optional

from stillpoint.drivers import constants as C
from stillpoint.drivers.ax.volume import open_data_file

CHUNK_BYTES = 1 << 20  # 1 MiB reads (2048 sectors)
CHECK_BYTES = 64 * 1024  # the verification compares (and re-reads) the file in ranges this long


class RangeHashes:
    """One hash per ``unit`` bytes of a stream fed in pieces of any length."""

    def __init__(self, unit: int = CHECK_BYTES):
        self.unit = unit
        self.digests: list[bytes] = []
        self._h = None
        self._fill = 0

    def update(self, b) -> None:
        mv = memoryview(b)
        while len(mv):
            if self._h is None:
                self._h, self._fill = hashlib.blake2b(digest_size=16), 0
            k = min(self.unit - self._fill, len(mv))
            self._h.update(mv[:k])
            self._fill += k
            mv = mv[k:]
            if self._fill == self.unit:
                self.digests.append(self._h.digest())
                self._h = None

    def finish(self) -> list[bytes]:
        if self._h is not None:
            self.digests.append(self._h.digest())
            self._h = None
        return self.digests


class ReadCancelled(Exception):
    """``cancel`` was set during ``read_device``."""


class ReadStalled(OSError):
    """A device read made no progress within the stall bound and was stopped."""


@dataclass
class DeviceDigest:
    bytes: int
    sha256: str
    head: bytes = b""  # the first CWA_HEADER_BYTES (fewer in a shorter file)
    ranges: list = field(default_factory=list)  # one hash per CHECK_BYTES (``ranges=True``)


@dataclass
class ReadJob:
    """What a worker needs to hash a device's data file (plain data: it crosses a process)."""
    data_file: str
    faults: tuple = ()
    control: Optional[str] = None
    chunk_bytes: int = CHUNK_BYTES


def read_device(data_file, *, faults=(), control=None, chunk: int = CHUNK_BYTES,
                ranges: bool = False, phase: str = "re-read",
                progress: Optional[Callable[[str, int, int], None]] = None,
                cancel: Optional[threading.Event] = None,
                throttle_bps: Optional[float] = None) -> DeviceDigest:
    """The device's data file read once past the page cache (module docstring). Raises
    ``OSError`` for a read fault, ``ReadCancelled`` when ``cancel`` is set."""
    f = open_data_file(data_file, verify=True, faults=faults, control=control)
    sha = hashlib.sha256()
    rh = RangeHashes() if ranges else None
    total = f.size()
    got = 0
    head = b""
    t0 = time.monotonic()
    if progress is not None:
        progress(phase, 0, total)
    try:
        while True:
            if throttle_bps:  # a re-read comes from the device too
                lag = got / throttle_bps - (time.monotonic() - t0)
                if lag > 0:
                    time.sleep(lag)
            if cancel is not None and cancel.is_set():
                raise ReadCancelled("cancelled")
            b = f.read(chunk)
            if not b:
                break
            sha.update(b)
            if rh is not None:
                rh.update(b)
            if got < C.CWA_HEADER_BYTES:
                head += b[:C.CWA_HEADER_BYTES - got]
            got += len(b)
            if progress is not None:
                progress(phase, got, total)
    finally:
        f.close()
    return DeviceDigest(got, sha.hexdigest(), head, rh.finish() if rh is not None else [])


def hash_task(job: ReadJob, progress, cancel=None) -> dict:
    """``read_device`` as a worker task: a plain dict (``bytes``, ``sha256``, ``head``; or ``errno``
    and ``error`` for a read fault)."""
    try:
        d = read_device(job.data_file, faults=job.faults, control=job.control,
                        chunk=job.chunk_bytes, progress=progress, cancel=cancel)
    except OSError as e:
        return {"errno": e.errno or errno.EIO, "error": e.strerror or str(e)}
    except ReadCancelled:
        return {"errno": errno.EINTR, "error": "stopped"}
    return {"bytes": d.bytes, "sha256": d.sha256, "head": d.head}


def device_digest(data_file, *, faults=(), control=None, stall_s: Optional[float] = None,
                  inline: bool = False) -> DeviceDigest:
    """Size, SHA-256 and header of the device's data file. With ``stall_s`` the read runs in a
    worker and a read without progress that long raises ``ReadStalled`` (module docstring); read
    faults are ``OSError`` either way."""
    job = ReadJob(str(data_file), tuple(faults), str(control) if control else None)
    if stall_s is None:
        return read_device(job.data_file, faults=job.faults, control=job.control)
    from .worker import Worker
    w = Worker(hash_task, job, stall_s=stall_s, inline=inline, what="re-read").start()
    r = w.wait()
    if "sha256" in r:
        return DeviceDigest(int(r["bytes"]), r["sha256"], r["head"])
    if r.get("stalled"):
        raise ReadStalled(errno.ETIMEDOUT, r["error"])
    raise OSError(r.get("errno") or errno.EIO, r["error"])
