"""One verified download: the device's data file -> ``<out>/<device>_<session>.cwa`` plus the
corrected ``<out>/<device>_<session>.mcap``, written while the copy runs.

``run_download(job, progress=None, cancel=None) -> DownloadResult`` (never raises for a device or
output fault: the result says what went wrong). Steps:

1. The data file's size in the directory entry and its header (device id and session must be the
   job's: they were read from the USB serial, ``ID``, ``SESSION`` and the volume label).
2. The copy: large chunks to ``<stem>.cwa.part`` with a running SHA-256; every chunk's sectors
   are checked (``cwa_decode.classify``: checksum, tag, length...) and bad ones counted (they do
   not block). A ``.cwa.part`` from an interrupted download of the same device and session is
   resumed: its whole sectors are compared with the device's (a cache-bypassing read) and the
   copy continues after them; a prefix that differs is set aside (never deleted) and the copy
   starts over.
3. Meanwhile the online pipeline (``engine.run.process_file``, mode "online", the same operators
   as ``process --mode online``) follows the growing ``.cwa.part`` on a thread and writes
   ``<stem>.mcap.part``.
4. Verification, all of: bytes copied = size at start = size in the directory entry now; the copy
   fsynced; a second read of the device file that bypasses the OS cache gives the same SHA-256.
   Only then are the ``.cwa`` and the ``.mcap`` finalised (atomic rename, folder fsync).

Any failure leaves the partial files in place and the device untouched.
"""

from __future__ import annotations

import errno
import hashlib
import os
import threading
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable, Optional

import numpy as np

from stillpoint.drivers import constants as C
from stillpoint.drivers.ax.volume import open_data_file
from stillpoint.drivers.outputs import describe_os_error, fsync_folder

CHUNK_BYTES = 1 << 20  # 1 MiB reads (2048 sectors)


class DownloadAborted(Exception):
    """The copy failed or was cancelled: the pipeline following the copy stops."""


@dataclass
class DownloadJob:
    device_id: int
    session_id: int
    data_file: str
    out_dir: str
    device_type: str = "AX3"
    faults: tuple = ()
    control: Optional[str] = None
    metadata: dict = field(default_factory=dict)  # MCAP metadata records {name: {key: value}}
    settings: dict = field(default_factory=dict)  # RunSettings overrides (mode is online)
    throttle_bps: Optional[float] = None  # emulate USB full speed (bytes/s); None: as fast as read
    chunk_bytes: int = CHUNK_BYTES
    pipeline: bool = True

    @property
    def stem(self) -> str:
        return f"{self.device_id}_{self.session_id}"


@dataclass
class DownloadResult:
    ok: bool
    reason: Optional[str] = None
    bytes: int = 0
    size: Optional[int] = None
    sha256: Optional[str] = None
    bad_sectors: int = 0
    resumed_from: int = 0
    cwa_path: Optional[str] = None
    mcap_path: Optional[str] = None
    cwa_part: Optional[str] = None
    copy_s: float = 0.0
    mcap_after_copy_s: Optional[float] = None  # last byte copied -> MCAP final (after verification)
    pipeline_after_copy_s: Optional[float] = None  # last byte copied -> MCAP written and closed
    verify_s: float = 0.0
    summary: Optional[dict] = None

    def to_dict(self) -> dict:
        return asdict(self)


def _bad_sectors(buf: bytes, offset: int) -> int:
    """Count data sectors in ``buf`` (starting at file ``offset``) that fail the sector checks."""
    from stillpoint.drivers.cwa_decode import EMPTY, ERASED, classify
    from stillpoint.drivers.cwa_layout import SECTOR_DTYPE
    skip = max(0, C.CWA_HEADER_BYTES - offset)
    data = buf[skip:]
    k = len(data) // C.CWA_SECTOR_BYTES
    if k <= 0:
        return 0
    sec = np.frombuffer(data, SECTOR_DTYPE, count=k)
    r = classify(sec)
    return int(np.count_nonzero((r != 0) & (r != ERASED) & (r != EMPTY)))


def _check_header(path: Path, job: DownloadJob) -> None:
    from stillpoint.drivers.ax.errors import IdentityMismatch
    from stillpoint.drivers.cwa_layout import parse_header
    with open(path, "rb") as f:
        head = f.read(C.CWA_HEADER_BYTES)
    try:
        h = parse_header(head)
    except ValueError as e:
        raise IdentityMismatch(job.device_id, f"the data file header is not readable: {e}") from None
    from stillpoint.drivers.ax.identity import header_device_text, header_names_device
    if not header_names_device(h, job.device_id, job.device_type):
        raise IdentityMismatch(job.device_id, f"the data file header names device "
                                              f"{header_device_text(h)}, not {job.device_type} "
                                              f"{job.device_id}")
    if h["session_id"] != job.session_id:
        raise IdentityMismatch(job.device_id, f"session mismatch: SESSION says {job.session_id}, the "
                                              f"data file header says {h['session_id']}")


def _set_aside(p: Path) -> Path:
    stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
    aside = p.with_name(f"{p.name}.{stamp}")
    n = 1
    while aside.exists():
        aside = p.with_name(f"{p.name}.{stamp}-{n}")
        n += 1
    os.replace(p, aside)
    return aside


def _hash_prefix(fobj, n: int, chunk: int) -> "hashlib._Hash":
    h = hashlib.sha256()
    left = n
    while left > 0:
        b = fobj.read(min(chunk, left))
        if not b:
            break
        h.update(b)
        left -= len(b)
    if left:
        raise EOFError(f"ended {left} bytes early")
    return h


class _Pipeline:
    """The online pipeline following the growing copy on a thread."""

    def __init__(self, part: Path, mcap_part: Path, job: DownloadJob):
        self.part, self.mcap_part, self.job = part, mcap_part, job
        self.done = threading.Event()
        self.failed: Optional[str] = None
        self.summary: Optional[dict] = None
        self.error: Optional[str] = None
        self.finished_at: Optional[float] = None
        self.thread = threading.Thread(target=self._run, name=f"pipeline-{job.stem}", daemon=True)

    def copy_done(self) -> bool:
        if self.failed:
            raise DownloadAborted(self.failed)
        return self.done.is_set()

    def _run(self) -> None:
        from stillpoint.engine.run import RunSettings, process_file
        try:
            s = RunSettings.from_dict(dict(self.job.settings, mode="online"))
            self.summary = process_file(self.part, self.mcap_part, s, metadata=self.job.metadata,
                                        source_options={"follow": True, "follow_done": self.copy_done,
                                                        "follow_idle_s": 1e9})
        except DownloadAborted:
            self.error = "aborted"
        except BaseException as e:  # noqa: BLE001 - reported in the result, never a traceback
            self.error = f"{type(e).__name__}: {e}"
        self.finished_at = time.monotonic()


def run_download(job: DownloadJob, progress: Optional[Callable[[str, int, int], None]] = None,
                 cancel: Optional[threading.Event] = None) -> DownloadResult:
    """See the module docstring. ``progress(phase, done_bytes, total_bytes)``."""
    out = Path(job.out_dir)
    data = Path(job.data_file)
    part = out / f"{job.stem}.cwa.part"
    final = out / f"{job.stem}.cwa"
    mcap_part = out / f"{job.stem}.mcap.part"
    mcap_final = out / f"{job.stem}.mcap"
    res = DownloadResult(ok=False, cwa_part=str(part))
    progress = progress or (lambda *a: None)
    cancel = cancel or threading.Event()
    if final.exists():
        return DownloadResult(ok=False, reason=f"{final} already exists (a verified copy of this "
                                               "session); nothing is overwritten", cwa_path=str(final))
    # ---------------------------------------------------------------- 1. size and header
    try:
        size0 = os.stat(data).st_size
        _check_header(data, job)
    except OSError as e:
        res.reason = f"cannot read {data}: {describe_os_error(e)}"
        return res
    except Exception as e:  # IdentityMismatch
        res.reason = str(getattr(e, "reason", e))
        return res
    res.size = size0
    # ---------------------------------------------------------------- 2. open the copy (resume?)
    import fcntl
    try:
        fd = os.open(part, os.O_RDWR | os.O_CREAT | getattr(os, "O_CLOEXEC", 0), 0o644)
    except OSError as e:
        res.reason = f"cannot create {part}: {describe_os_error(e)}"
        return res
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        os.close(fd)
        res.reason = f"{part} is being written by another download"
        return res
    pipe: Optional[_Pipeline] = None
    src = None
    try:
        have = os.fstat(fd).st_size
        start = min(have, size0) // C.CWA_SECTOR_BYTES * C.CWA_SECTOR_BYTES
        sha = hashlib.sha256()
        if start >= C.CWA_HEADER_BYTES:
            with open(part, "rb") as mine:
                h_mine = _hash_prefix(mine, start, job.chunk_bytes)
            dev = open_data_file(data, verify=True)
            try:
                h_dev = _hash_prefix(dev, start, job.chunk_bytes)
            finally:
                dev.close()
            if h_mine.digest() == h_dev.digest():
                sha = h_mine
                res.resumed_from = start
            else:
                start = 0
        else:
            start = 0
        if start == 0 and have > 0:
            os.close(fd)
            _set_aside(part)
            fd = os.open(part, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o644)
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        os.ftruncate(fd, start)
        os.lseek(fd, start, os.SEEK_SET)
        if start:  # bad sectors of the kept prefix count too
            with open(part, "rb") as mine:
                off = 0
                while off < start:
                    b = mine.read(min(job.chunk_bytes, start - off))
                    res.bad_sectors += _bad_sectors(b, off)
                    off += len(b)
        # ---------------------------------------------------------------- 3. copy + pipeline
        if job.pipeline:
            if mcap_part.exists() and mcap_part.stat().st_size > 0:
                _set_aside(mcap_part)
            pipe = _Pipeline(part, mcap_part, job)
        src = open_data_file(data, faults=job.faults, control=job.control)
        src.seek(start)
        pos = start
        t0 = time.monotonic()
        last_report = 0.0
        while pos < size0:
            if cancel.is_set():
                raise DownloadAborted("cancelled")
            b = src.read(min(job.chunk_bytes, size0 - pos))
            if not b:
                break
            mv = memoryview(b)
            while mv:
                n = os.write(fd, mv)
                mv = mv[n:]
            sha.update(b)
            res.bad_sectors += _bad_sectors(b, pos)
            pos += len(b)
            res.bytes = pos
            if pipe is not None and not pipe.thread.is_alive() and pos >= C.CWA_HEADER_BYTES \
                    and pipe.finished_at is None:
                pipe.thread.start()
            if job.throttle_bps:
                lag = (pos - start) / job.throttle_bps - (time.monotonic() - t0)
                if lag > 0:
                    time.sleep(lag)
            now = time.monotonic()
            if now - last_report >= 0.2:
                progress("copy", pos, size0)
                last_report = now
        res.bytes = pos
        res.copy_s = time.monotonic() - t0
        t_last = time.monotonic()
        progress("copy", pos, size0)
        src.close()
        src = None
        if pos != size0:
            raise DownloadAborted(f"short read: {pos} of {size0} bytes copied (the file ended "
                                  "early); the partial copy is kept")
        size_now = os.stat(data).st_size
        if size_now != size0:
            raise DownloadAborted(f"the data file changed size during the copy ({size0} -> "
                                  f"{size_now} bytes)")
        os.fsync(fd)
        res.sha256 = sha.hexdigest()
        if pipe is not None:
            if pipe.finished_at is None and not pipe.thread.is_alive():
                pipe.thread.start()
            pipe.done.set()
        # ---------------------------------------------------------------- 4. verification read
        progress("verify", 0, size0)
        ver = open_data_file(data, verify=True, faults=job.faults, control=job.control)
        t_ver = time.monotonic()
        try:
            h2 = hashlib.sha256()
            got = 0
            while True:
                if job.throttle_bps:  # the second read comes from the device too
                    lag = got / job.throttle_bps - (time.monotonic() - t_ver)
                    if lag > 0:
                        time.sleep(lag)
                if cancel.is_set():
                    raise DownloadAborted("cancelled")
                b = ver.read(job.chunk_bytes)
                if not b:
                    break
                h2.update(b)
                got += len(b)
                progress("verify", got, size0)
        finally:
            ver.close()
        res.verify_s = time.monotonic() - t_ver
        if got != size0 or h2.hexdigest() != res.sha256:
            raise DownloadAborted(f"verification failed: the second read of {data} differs from "
                                  f"the copy ({got} bytes, SHA-256 {h2.hexdigest()[:12]} vs "
                                  f"{res.sha256[:12]}); the copy is kept as {part.name}")
        # ---------------------------------------------------------------- pipeline result
        if pipe is not None:
            while pipe.thread.is_alive():
                if cancel.is_set():
                    raise DownloadAborted("cancelled")
                progress("finishing", pos, size0)
                pipe.thread.join(0.5)
            if pipe.error:
                raise DownloadAborted(f"the correction pipeline failed: {pipe.error}")
            res.summary = pipe.summary
            res.pipeline_after_copy_s = max(0.0, pipe.finished_at - t_last)
        # ---------------------------------------------------------------- finalise
        os.fsync(fd)
        os.replace(part, final)
        fsync_folder(out)
        res.cwa_path = str(final)
        if pipe is not None:
            os.replace(mcap_part, mcap_final)
            fsync_folder(out)
            res.mcap_path = str(mcap_final)
            res.mcap_after_copy_s = time.monotonic() - t_last
        res.ok = True
        return res
    except DownloadAborted as e:
        res.reason = str(e)
    except OSError as e:
        if e.errno in (errno.ENOSPC, errno.EDQUOT, errno.EROFS):
            res.reason = f"cannot write {part}: {describe_os_error(e)}; the partial copy is kept"
        elif e.errno in (errno.ENODEV, errno.ENOENT, errno.ENXIO):
            res.reason = f"device unplugged during the copy ({describe_os_error(e)}); the partial copy is kept"
        else:
            res.reason = f"reading {data} failed: {describe_os_error(e)}; the partial copy is kept"
    finally:
        if src is not None:
            try:
                src.close()
            except OSError:
                pass
        if pipe is not None and not res.ok:
            pipe.failed = res.reason or "aborted"
            if pipe.thread.is_alive():
                pipe.thread.join(10)
        try:
            os.close(fd)
        except OSError:
            pass
    return res
