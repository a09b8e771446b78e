"""One download, up to a verified copy: the device's data file -> ``<out>/<stem>.cwa.part`` plus
the corrected ``<out>/<stem>.unverified.mcap``, written while the copy runs (names: ``names``).

``run_download(job, progress=None, cancel=None) -> DownloadResult`` (never raises for a device or
output fault: the result says what went wrong). It never gives a file its final name: the station
does that in the same step as the ledger write (``completion``), so a download is complete only
when the ledger says so. Steps:

1. The data file's size in the directory entry and its header (device id and session must be the
   job's: they were read from the USB serial, ``ID``, ``SESSION`` and the volume label).
2. The copy: large chunks to ``<stem>.cwa.part`` (opened without following a link, refused if it
   is not a plain file of its own) with a running SHA-256 and one hash per ``CHECK_BYTES`` range;
   every chunk's sectors are checked (``cwa_decode.classify``) and bad ones counted (they do not
   block). A ``.cwa.part`` left by an interrupted download is compared with the device (a
   cache-bypassing read) and only the prefix that equals the device is reused; if the partial
   copy holds bytes the device does not, it is set aside whole (``.part.<UTC>``, never deleted)
   and the new partial copy starts from its verified prefix.
3. Meanwhile the online pipeline (``engine.run.process_file``, mode "online") follows the growing
   copy on a thread and writes ``<stem>.unverified.mcap``.
4. Verification: bytes copied = size at start = size in the directory entry now; a second read of
   the device that bypasses the OS cache (``device_read.read_device``), hashed per range. A range
   whose hashes differ is read again (up to ``REREADS`` more times) until two reads agree. If they
   agree with the copy, the copy stands. If they agree on other bytes, the copy was misread only
   when every sector that differs failed its sector checks in the copy and passes them in the
   agreed bytes (a read error damages a sector; a device that writes writes whole, valid sectors):
   those ranges of the copy are patched. Any other difference means the device's data changed
   between the reads: the result is ``changed`` and the device must not be cleared. After a patch
   the corrected log is rebuilt from the patched copy. The ranges read again and patched are in
   the result (``reread_ranges``, ``patched_ranges``) and in the log's ``station`` record
   (``repairs_record``; the pipeline writes its metadata last, once the verification is done).
5. A final copy that is already there and has no ledger row (a station killed between its rename
   and its ledger write, in older versions) is adopted when it equals the device, range by range.

Any failure leaves the partial files in place and the device untouched.
"""

from __future__ import annotations

import errno
import hashlib
import os
import stat
import threading
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable, Optional

import numpy as np

from stillpoint.drivers import constants as C
from stillpoint.drivers.ax.volume import open_data_file
from stillpoint.engine.core.outputs import describe_os_error

from . import names
from .worker import Worker
from .device_read import CHECK_BYTES, CHUNK_BYTES, RangeHashes, ReadCancelled, read_device

REREADS = 2  # more reads of a range whose copy and verification reads differ
_OPEN_NOFOLLOW = os.O_NOFOLLOW | getattr(os, "O_CLOEXEC", 0)


class DownloadAborted(Exception):
    """The copy failed or was cancelled: the pipeline following the copy stops."""


class DataChanged(DownloadAborted):
    """The device's data differs between reads in a way a read error does not explain."""


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
    file_stem: Optional[str] = None  # a study's file name (study.download_stem); None: names.stem

    @property
    def stem(self) -> str:
        return self.file_stem or names.stem(self.device_type, self.device_id, self.session_id)


@dataclass
class DownloadResult:
    ok: bool
    reason: Optional[str] = None
    bytes: int = 0
    size: Optional[int] = None
    sha256: Optional[str] = None
    bad_sectors: int = 0
    resumed_from: int = 0
    cwa_path: Optional[str] = None  # the final name the station gives the raw copy
    mcap_path: Optional[str] = None  # the final name of the corrected log
    cwa_part: Optional[str] = None  # where the raw copy is now (None: already at cwa_path)
    mcap_part: Optional[str] = None  # where the corrected log is now (None: no pipeline)
    set_aside: Optional[str] = None  # an earlier partial copy that differed from the device
    reread_ranges: int = 0  # ranges read again because the copy and the verification differed
    patched_ranges: int = 0  # ranges of the copy replaced by bytes two later reads agreed on
    changed: bool = False  # the device's data changed between reads: never clear it
    adopted: bool = False  # the final copy was already there and equals the device
    copy_s: float = 0.0
    mcap_after_copy_s: Optional[float] = None  # last byte copied -> MCAP ready (after verification)
    pipeline_after_copy_s: Optional[float] = None  # last byte copied -> MCAP written and closed
    verify_s: float = 0.0
    summary: Optional[dict] = None

    def to_dict(self) -> dict:
        return asdict(self)


def repairs_text(reread_ranges: int, patched_ranges: int) -> str:
    """What the verification repaired, in words ("" when it read nothing again): "1 range
    re-read, copy patched"; "1 range re-read, copy confirmed" (the verification read was the
    misread one); "3 ranges re-read, 2 patched"."""
    if not reread_ranges:
        return ""
    head = f"{reread_ranges} range{'s' if reread_ranges != 1 else ''} re-read"
    if patched_ranges == 0:
        return f"{head}, copy confirmed"
    if patched_ranges == reread_ranges:
        return f"{head}, copy patched"
    return f"{head}, {patched_ranges} patched"


def repairs_record(reread_ranges: int, patched_ranges: int) -> dict:
    """The repair keys of the log's ``station`` record (MCAP metadata values are strings)."""
    return {"reread_ranges": str(int(reread_ranges)), "patched_ranges": str(int(patched_ranges)),
            "repairs": repairs_text(reread_ranges, patched_ranges) or "none"}


def _with_repairs(metadata: dict, reread_ranges: int, patched_ranges: int) -> dict:
    out = {k: dict(v) for k, v in (metadata or {}).items()}
    out.setdefault("station", {}).update(repairs_record(reread_ranges, patched_ranges))
    return out


def _range_hash(b: bytes) -> bytes:
    return hashlib.blake2b(b, digest_size=16).digest()


def _sector_reasons(buf: bytes, offset: int) -> tuple[int, np.ndarray]:
    """(first data sector's file offset, reason code per whole data sector) of ``buf`` read at
    file ``offset`` (the header is not a data sector)."""
    from stillpoint.drivers.cwa_decode import classify
    from stillpoint.drivers.cwa_layout import SECTOR_DTYPE
    skip = max(0, C.CWA_HEADER_BYTES - offset)
    data = buf[skip:]
    k = len(data) // C.CWA_SECTOR_BYTES
    if k <= 0:
        return offset + skip, np.zeros(0, np.uint8)
    return offset + skip, classify(np.frombuffer(data, SECTOR_DTYPE, count=k))


def _bad(reasons: np.ndarray) -> np.ndarray:
    from stillpoint.drivers.cwa_decode import EMPTY, ERASED
    return (reasons != 0) & (reasons != ERASED) & (reasons != EMPTY)


def _bad_sectors(buf: bytes, offset: int) -> int:
    """Count data sectors in ``buf`` (starting at file ``offset``) that fail the sector checks."""
    return int(np.count_nonzero(_bad(_sector_reasons(buf, offset)[1])))


def _check_header(path: Path, job: DownloadJob) -> None:
    from stillpoint.drivers.ax.errors import IdentityMismatch
    from stillpoint.drivers.ax.identity import header_mismatch
    with open(path, "rb") as f:
        why = header_mismatch(f.read(C.CWA_HEADER_BYTES), job.device_id, job.device_type,
                              job.session_id)
    if why:
        raise IdentityMismatch(job.device_id, why)


def _set_aside(p: Path) -> Path:
    aside = names.set_aside_name(p)
    os.rename(p, aside)
    return aside


def _open_part(part: Path) -> int:
    """The partial copy, created if missing, never through a link; refused unless it is a plain
    file with no other name (a planted hard link would receive the download)."""
    fd = os.open(part, os.O_RDWR | os.O_CREAT | _OPEN_NOFOLLOW, 0o644)
    st = os.fstat(fd)
    if not stat.S_ISREG(st.st_mode) or st.st_nlink != 1:
        os.close(fd)
        raise OSError(errno.EPERM, "not a plain file of its own (it has another name)")
    return fd


def _lock(fd: int) -> bool:
    import fcntl
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        return False
    return True


def _pread_all(fd: int, n: int, off: int) -> bytes:
    parts = []
    while n > 0:
        b = os.pread(fd, n, off)
        if not b:
            break
        parts.append(b)
        n -= len(b)
        off += len(b)
    return b"".join(parts)


def _write_all(fd: int, b) -> None:
    mv = memoryview(b)
    while mv:
        n = os.write(fd, mv)
        mv = mv[n:]


def _common_prefix(fd: int, data: Path, n: int, chunk: int) -> int:
    """How many leading bytes of the partial copy (``fd``) equal the device's (read bypassing the
    cache), looking at the first ``n``."""
    dev = open_data_file(data, verify=True)
    try:
        off = 0
        while off < n:
            want = min(chunk, n - off)
            a = _pread_all(fd, want, off)
            b = dev.read(want)
            if a != b:
                k = min(len(a), len(b))
                same = np.frombuffer(a[:k], np.uint8) == np.frombuffer(b[:k], np.uint8)
                return off + (int(np.argmin(same)) if not same.all() else k)
            off += want
        return n
    finally:
        dev.close()


class _Pipeline:
    """The online pipeline following the growing copy on a thread."""

    def __init__(self, part: Path, log: Path, job: DownloadJob):
        self.part, self.log, self.job = part, log, job
        self.done = threading.Event()
        self.failed: Optional[str] = None
        self.summary: Optional[dict] = None
        self.error: Optional[str] = None
        self.finished_at: Optional[float] = None
        self.verified = threading.Event()  # the verification is done: ``repairs`` is known
        self.repairs = (0, 0)  # (ranges re-read, ranges patched)
        self.thread = threading.Thread(target=self._run, name=f"pipeline-{job.stem}", daemon=True)

    def copy_done(self) -> bool:
        if self.failed:
            raise DownloadAborted(self.failed)
        return self.done.is_set()

    def _metadata(self) -> dict:
        """The log's metadata records, written last: its ``station`` record says what the
        verification re-read and patched, so the pipeline waits for the verification here."""
        while not self.verified.wait(0.2):
            if self.failed:
                raise DownloadAborted(self.failed)
        return _with_repairs(self.job.metadata, *self.repairs)

    def _run(self) -> None:
        try:
            self.summary = run_pipeline(self.part, self.log, self.job, follow=self.copy_done,
                                        metadata=self._metadata)
        except DownloadAborted:
            self.error = "aborted"
        except BaseException as e:  # noqa: BLE001 - reported in the result, never a traceback
            self.error = f"{type(e).__name__}: {e}"
        self.finished_at = time.monotonic()


def run_pipeline(raw: Path, log: Path, job: DownloadJob, follow=None, progress=None,
                 metadata=None) -> dict:
    """The online pipeline on ``raw`` (following it while ``follow()`` is false) into ``log``;
    ``metadata``: the log's metadata records (default the job's; a function: called when they
    are written, at the end)."""
    from stillpoint.engine.run import RunSettings, process_file
    s = RunSettings.from_dict(dict(job.settings, mode="online"))
    opts = {"follow": True, "follow_done": follow, "follow_idle_s": 1e9} if follow else None
    return process_file(raw, log, s, metadata=job.metadata if metadata is None else metadata,
                        source_options=opts, progress=progress)


def _clear_stale_log(log: Path) -> None:
    """The corrected log of an earlier attempt is derived data, rebuilt from the raw copy: an
    unfinished one is removed (the caller holds the partial copy's lock)."""
    for p in (log, Path(str(log) + names.PART)):
        try:
            os.unlink(p)
        except FileNotFoundError:
            pass


def _resolve_ranges(fd: int, job: DownloadJob, size: int, copy_d: list, ver_d: list,
                    res: DownloadResult) -> None:
    """Read again the ranges whose copy and verification hashes differ (see module docstring,
    step 4); patch the copy where two reads agree on bytes that show the copy was misread.
    Raises ``DataChanged`` or ``DownloadAborted``."""
    diff = [i for i, (a, b) in enumerate(zip(copy_d, ver_d)) if a != b]
    if not diff:
        return
    res.reread_ranges = len(diff)
    dev = open_data_file(job.data_file, verify=True, faults=job.faults, control=job.control)
    try:
        for i in diff:
            off = i * CHECK_BYTES
            n = min(CHECK_BYTES, size - off)
            copy_b = _pread_all(fd, n, off)
            seen = [copy_d[i], ver_d[i]]
            agreed = None
            for _ in range(REREADS):
                dev.seek(off)
                b = dev.read(n)
                h = _range_hash(b)
                if h in seen:
                    agreed = b
                    break
                seen.append(h)
            if agreed is None:
                raise DataChanged(f"the device gives different bytes on every read of bytes "
                                  f"{off}-{off + n} ({2 + REREADS} reads)")
            if agreed == copy_b:
                continue  # the verification read was the misread one
            why = _why_not_a_misread(copy_b, agreed, off)
            if why:
                raise DataChanged(f"the device's data changed between the copy and the "
                                  f"verification read ({why})")
            os.pwrite(fd, agreed, off)
            res.bad_sectors += _bad_sectors(agreed, off) - _bad_sectors(copy_b, off)
            res.patched_ranges += 1
    finally:
        dev.close()


def _why_not_a_misread(copy_b: bytes, agreed: bytes, off: int) -> Optional[str]:
    """None when every byte that differs lies in a data sector that failed its checks in the copy
    and passes them in the agreed bytes; else what shows the data changed."""
    a = np.frombuffer(copy_b, np.uint8)
    b = np.frombuffer(agreed, np.uint8)
    where = np.flatnonzero(a != b) + off
    if len(where) and where[0] < C.CWA_HEADER_BYTES:
        return "the header differs"
    first, ra = _sector_reasons(copy_b, off)
    _, rb = _sector_reasons(agreed, off)
    for s in np.unique((where - first) // C.CWA_SECTOR_BYTES):
        if s >= len(ra):
            return "bytes after the last whole sector differ"
        sector = (first - C.CWA_HEADER_BYTES) // C.CWA_SECTOR_BYTES + int(s)
        if not _bad(ra[s:s + 1])[0]:
            return f"data sector {sector} is a complete sector in both reads"
        if _bad(rb[s:s + 1])[0]:
            return f"data sector {sector} fails its checks in both versions"
    return None


def _hash_file(fd: int, size: int, chunk: int) -> str:
    h = hashlib.sha256()
    off = 0
    while off < size:
        b = _pread_all(fd, min(chunk, size - off), off)
        if not b:
            break
        h.update(b)
        off += len(b)
    return h.hexdigest()


def _adopt(final: Path, size0: int, job: DownloadJob, res: DownloadResult, progress) -> DownloadResult:
    """A final copy with no verified ledger row: adopted when it equals the device, else refused."""
    try:
        fd = os.open(final, os.O_RDONLY | _OPEN_NOFOLLOW)
    except OSError as e:
        res.reason = f"{final} already exists and cannot be read ({describe_os_error(e)}); nothing " \
                     "is overwritten"
        return res
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode) or st.st_size != size0 or \
                _common_prefix(fd, Path(job.data_file), size0, job.chunk_bytes) != size0:
            res.reason = (f"{final} already exists and is not a copy of the device's data "
                          f"({st.st_size} bytes, the device {size0}); nothing is overwritten")
            return res
        res.sha256 = _hash_file(fd, size0, job.chunk_bytes)
        res.bytes = size0
        res.bad_sectors = sum(_bad_sectors(_pread_all(fd, min(job.chunk_bytes, size0 - o), o), o)
                              for o in range(0, size0, job.chunk_bytes))
    finally:
        os.close(fd)
    res.adopted, res.cwa_part = True, None
    log = names.log_unverified(job.out_dir, job.stem)
    if job.pipeline and not os.path.lexists(res.mcap_path):
        _clear_stale_log(log)
        res.summary = run_pipeline(final, log, job,
                                   progress=lambda *a: progress("finishing", size0, size0),
                                   metadata=_with_repairs(job.metadata, 0, 0))
        res.mcap_part = str(log)
    elif os.path.lexists(res.mcap_path):
        res.mcap_part = None
    res.ok = True
    return res


def run_download(job: DownloadJob, progress: Optional[Callable[[str, int, int], None]] = None,
                 cancel: Optional[threading.Event] = None) -> DownloadResult:
    """See the module docstring. ``progress(phase, done_bytes, total_bytes)``."""
    out = Path(job.out_dir)
    data = Path(job.data_file)
    part = names.raw_part(out, job.stem)
    final = names.raw_copy(out, job.stem)
    log = names.log_unverified(out, job.stem)
    res = DownloadResult(ok=False, cwa_part=str(part), cwa_path=str(final),
                         mcap_path=str(names.log_final(out, job.stem)))
    progress = progress or (lambda *a: None)
    cancel = cancel or threading.Event()
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
    if os.path.lexists(final):
        try:
            return _adopt(final, size0, job, res, progress)
        except Exception as e:  # noqa: BLE001 - one line in the result
            res.ok = False
            res.reason = f"{final} already exists and could not be compared with the device: " \
                         f"{describe_os_error(e) if isinstance(e, OSError) else e}"
            return res
    # ---------------------------------------------------------------- 2. open the copy (resume?)
    try:
        fd = _open_part(part)
    except OSError as e:
        what = "is a link" if e.errno == errno.ELOOP else describe_os_error(e)
        res.reason = f"cannot create {part}: {what}; nothing is written to it"
        return res
    if not _lock(fd):
        os.close(fd)
        res.reason = f"{part} is being written by another download"
        return res
    pipe: Optional[_Pipeline] = None
    src = None
    try:
        have = os.fstat(fd).st_size
        same = _common_prefix(fd, data, min(have, size0), job.chunk_bytes) if have else 0
        start = same // C.CWA_SECTOR_BYTES * C.CWA_SECTOR_BYTES
        if start < C.CWA_HEADER_BYTES:
            start = 0
        if same < have:  # the partial copy holds bytes the device does not: keep it whole
            aside = _set_aside(part)
            res.set_aside = str(aside)
            new = _open_part(part)
            if not _lock(new):
                os.close(new)
                raise DownloadAborted(f"{part} is being written by another download")
            with open(aside, "rb") as old:
                left = start
                while left > 0:
                    b = old.read(min(job.chunk_bytes, left))
                    if not b:
                        break
                    _write_all(new, b)
                    left -= len(b)
            os.close(fd)
            fd = new
        os.ftruncate(fd, start)
        os.lseek(fd, start, os.SEEK_SET)
        res.resumed_from = start
        sha = hashlib.sha256()
        ranges = RangeHashes()
        off = 0
        while off < start:  # the kept prefix: its hashes and bad sectors count too
            b = _pread_all(fd, min(job.chunk_bytes, start - off), off)
            sha.update(b)
            ranges.update(b)
            res.bad_sectors += _bad_sectors(b, off)
            off += len(b)
        # ---------------------------------------------------------------- 3. copy + pipeline
        if job.pipeline:
            _clear_stale_log(log)
            pipe = _Pipeline(part, log, job)
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
            _write_all(fd, b)
            sha.update(b)
            ranges.update(b)
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
        copy_d = ranges.finish()
        if pipe is not None:
            if pipe.finished_at is None and not pipe.thread.is_alive():
                pipe.thread.start()
            pipe.done.set()
        # ---------------------------------------------------------------- 4. verification read
        t_ver = time.monotonic()
        try:
            ver = read_device(data, faults=job.faults, control=job.control, chunk=job.chunk_bytes,
                              ranges=True, phase="verify", progress=progress, cancel=cancel,
                              throttle_bps=job.throttle_bps)
        except ReadCancelled:
            raise DownloadAborted("cancelled") from None
        got, ver_d = ver.bytes, ver.ranges
        if got != size0:
            raise DownloadAborted(f"verification failed: the second read of {data} gave {got} "
                                  f"bytes, the copy has {size0}; the copy is kept as {part.name}")
        try:
            _resolve_ranges(fd, job, size0, copy_d, ver_d, res)
        except DataChanged as e:
            res.changed = True
            raise DataChanged(f"verification failed: {e}; the copy is kept as {part.name} and "
                              "the device is not cleared") from None
        except DownloadAborted as e:
            raise DownloadAborted(f"verification failed: {e}; the copy is kept as "
                                  f"{part.name}") from None
        if res.patched_ranges:
            os.fsync(fd)
            res.sha256 = _hash_file(fd, size0, job.chunk_bytes)
        res.verify_s = time.monotonic() - t_ver
        if pipe is not None:  # the log's station record can say what was repaired now
            pipe.repairs = (res.reread_ranges, res.patched_ranges)
            pipe.verified.set()
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
            if res.patched_ranges:  # the log followed the misread copy: rebuilt from the patched one
                res.summary = run_pipeline(part, log, job,
                                           progress=lambda *a: progress("finishing", pos, size0),
                                           metadata=_with_repairs(job.metadata, res.reread_ranges,
                                                                  res.patched_ranges))
            res.pipeline_after_copy_s = max(0.0, time.monotonic() - t_last)
            res.mcap_part = str(log)
            res.mcap_after_copy_s = time.monotonic() - t_last
        os.fsync(fd)
        res.ok = True
        return res
    except DownloadAborted as e:
        res.reason = str(e)
    except OSError as e:
        if e.errno in (errno.ENOSPC, errno.EDQUOT, errno.EROFS):
            res.reason = f"cannot write {part}: {describe_os_error(e)}; the partial copy is kept"
        elif e.errno in (errno.ENODEV, errno.ENOENT, errno.ENXIO):
            res.reason = f"device unplugged during the copy ({describe_os_error(e)}); the partial copy is kept"
        elif e.errno == errno.ELOOP or (e.errno == errno.EPERM and "its own" in str(e)):
            res.reason = f"cannot create {part}: it is a link; nothing is written to it"
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


def download_task(job: DownloadJob, progress, cancel=None) -> dict:
    """``run_download`` as a worker task (its ``DownloadResult`` as a dict)."""
    try:
        return run_download(job, progress, cancel).to_dict()
    except BaseException as e:  # noqa: BLE001 - reported, never a traceback on the station
        return DownloadResult(ok=False, reason=f"download worker failed: {type(e).__name__}: "
                                               f"{e}").to_dict()


class DownloadWorker(Worker):
    """One download (``run_download``) in a worker; ``result`` is its ``DownloadResult``."""

    def __init__(self, job: DownloadJob, *, stall_s: float = 30.0, inline: bool = False):
        super().__init__(download_task, job, stall_s=stall_s, inline=inline, what="download",
                         name=f"download-{job.stem}")

    def _result(self, d: dict) -> DownloadResult:
        return DownloadResult(**d)

    def _stopped(self) -> DownloadResult:
        return DownloadResult(ok=False, reason="stopped by the user; the partial copy is kept and "
                              "resumes next time", bytes=self.done)

    def _failure(self, reason: str, stalled: bool = False) -> DownloadResult:
        from . import names
        if stalled:
            reason += "; the download was stopped"
        return DownloadResult(ok=False, reason=reason + "; the partial copy is kept",
                              bytes=self.done,
                              cwa_part=str(names.raw_part(self.job.out_dir, self.job.stem)))
