"""Opening recordings as byte streams: plain files, gzip (streamed, never unpacked to disk),
and *follow* mode for a file that is still being written (a download in progress)."""

from __future__ import annotations

import errno
import hashlib
import io
import os
import stat
import time
import zlib
from typing import BinaryIO, Callable, Optional

from stillpoint.engine.core.paths import not_a_file

GZIP_MAGIC = b"\x1f\x8b"


def is_gzip(path) -> bool:
    with open(path, "rb") as f:
        return f.read(2) == GZIP_MAGIC


def open_bytes(path) -> BinaryIO:
    """Open ``path`` for reading bytes; gzip files are decompressed transparently as a stream
    (``GzipStream``: a damaged stream ends early and says why in ``.damage``)."""
    if is_gzip(path):
        return GzipStream(path)  # type: ignore[return-value]
    return open(path, "rb", buffering=0)


def consumed_fraction(f) -> Optional[float]:
    """How far a stream from ``open_bytes`` (or any opened file) has read its file: the byte
    position of the file under it (a gzip's compressed bytes) over the file's size, in [0, 1];
    None when it cannot tell (not a file); a file still growing in follow mode is read
    against its current size. A closed stream counts as read to the end (readers close
    their file when they finish)."""
    if f is None:
        return None
    if getattr(f, "closed", False):
        return 1.0
    raw = getattr(f, "_f", f)
    try:
        size = os.fstat(raw.fileno()).st_size
        return min(1.0, raw.tell() / size) if size > 0 else None
    except (AttributeError, OSError, ValueError):
        return None


def stream_damage(f) -> Optional[str]:
    """Why a stream from ``open_bytes`` ended early (a damaged or truncated gzip), else None."""
    return getattr(f, "damage", None) or getattr(f, "idle_stop", None)


class GzipStream(io.RawIOBase):
    """A gzip file decompressed as a stream that returns every byte decompressible before any
    damage, then ends (EOF) with the reason in ``.damage`` instead of raising.

    Multi-member files are read member after member; the gzip trailer (CRC-32, length) of each
    member is checked by zlib. Output per call is bounded (``_OUT_LIMIT``), so a small damaged
    stream cannot expand into a huge allocation in one step.
    """

    _IN_BYTES = 1 << 14
    _OUT_LIMIT = 1 << 20

    def __init__(self, path):
        self._f = open(path, "rb", buffering=0)
        self._d = zlib.decompressobj(16 + zlib.MAX_WBITS)
        self._pending = b""
        self._pos = 0
        self._in = 0  # compressed bytes consumed so far
        self._done = False
        self.damage: Optional[str] = None

    def readable(self) -> bool:
        return True

    def _stop(self, why: Optional[str]) -> None:
        self._done = True
        self.damage = why

    def _feed(self, data: bytes) -> None:
        saved = self._d.copy()
        try:
            out = self._d.decompress(data, self._OUT_LIMIT)
        except zlib.error as e:
            # zlib drops the whole call's output on an error: replay it in small pieces from the
            # saved state to keep every byte that decompresses before the damage
            self._pending, self._pos = self._salvage(saved, data), 0
            self._stop(f"damaged gzip data within compressed bytes {max(0, self._in - len(data))}.."
                       f"{self._in}: {e}")
            return
        self._pending = out
        self._pos = 0
        if self._d.eof:
            rest = self._d.unused_data
            if not rest:
                rest = self._f.read(self._IN_BYTES)
                self._in += len(rest)
            if not rest:
                self._done = True  # clean end
            elif rest[:2] == GZIP_MAGIC:
                self._d = zlib.decompressobj(16 + zlib.MAX_WBITS)
                self._tail = rest
            elif not rest.strip(b"\0"):
                self._done = True  # zero padding after the stream (as gzip tolerates)
            else:
                self._stop(f"{len(rest)}+ bytes that are not gzip data after compressed byte "
                           f"{self._in - len(rest)}")

    @staticmethod
    def _salvage(d, data: bytes) -> bytes:
        out = []
        for i in range(0, len(data), 64):
            try:
                out.append(d.decompress(data[i:i + 64]))
            except zlib.error:
                break
            if d.eof:
                break
        return b"".join(out)

    def _fill(self) -> None:
        tail = getattr(self, "_tail", b"") or self._d.unconsumed_tail
        self._tail = b""
        if tail:
            self._feed(tail)
            return
        raw = self._f.read(self._IN_BYTES)
        if not raw:
            self._stop(f"the gzip stream ends after {self._in} compressed bytes, before its "
                       "end marker (truncated file)")
            return
        self._in += len(raw)
        self._feed(raw)

    def readinto(self, b) -> int:
        while self._pos >= len(self._pending):
            if self._done:
                return 0
            self._fill()
        n = min(len(b), len(self._pending) - self._pos)
        b[:n] = self._pending[self._pos:self._pos + n]
        self._pos += n
        return n

    def close(self) -> None:
        self._f.close()
        super().close()


def read_exact(f: BinaryIO, n: int) -> bytes:
    """Read up to n bytes, looping over short reads (gzip and raw files may return less)."""
    chunks = []
    got = 0
    while got < n:
        b = f.read(n - got)
        if not b:
            break
        chunks.append(b)
        got += len(b)
    return b"".join(chunks)


class FollowingReader(io.RawIOBase):
    """A file reader that, at end of file, waits for more bytes instead of stopping.

    It stops when ``is_done()`` returns True (e.g. the download finished) and no more bytes
    arrive, or after ``idle_timeout`` seconds without growth.
    """

    def __init__(self, path, is_done: Optional[Callable[[], bool]] = None,
                 poll_interval: float = 0.2, idle_timeout: float = 5.0):
        self._f = open(path, "rb", buffering=0)
        self._is_done = is_done or (lambda: False)
        self._poll = poll_interval
        self._idle = idle_timeout
        self.idle_stop: Optional[str] = None  # why reading stopped, when it was the idle timeout

    def readable(self) -> bool:
        return True

    def readinto(self, b) -> int:
        waited = 0.0
        while True:
            n = self._f.readinto(b)
            if n:
                return n
            if self._is_done() or waited >= self._idle:
                # one last read after done, to catch bytes written just before
                n = self._f.readinto(b) or 0
                if not n and not self._is_done():
                    self.idle_stop = (f"no new bytes for {self._idle:g} s: follow mode stopped "
                                      "reading (the file may still be growing)")
                return n
            time.sleep(self._poll)
            waited += self._poll

    def close(self) -> None:
        self._f.close()
        super().close()


def check_recording_path(path, *, allow_empty: bool = False) -> None:
    """Raise the typed error for a path that cannot hold a recording: missing, a directory, a
    pipe, device or socket (recordings are read with seeks; opening a pipe would wait for a
    writer), or empty (an empty file is allowed when following a file that is about to be
    written)."""
    from stillpoint.engine.core.errors import RecordingError, TruncatedRecordingError

    p = os.fspath(path)
    try:
        st = os.stat(p)
    except OSError as e:
        raise RecordingError(p, "no such file" if e.errno == errno.ENOENT else
                             f"cannot read: {e.strerror or e}") from None
    if stat.S_ISDIR(st.st_mode):
        raise RecordingError(p, "is a directory, not a recording")
    kind = not_a_file(st.st_mode)
    if kind:
        raise RecordingError(p, f"is {kind}, not a recording file (save the recording to a "
                                "file first)")
    if not allow_empty and st.st_size == 0:
        raise TruncatedRecordingError(p, "file is empty (0 bytes)")


def sha256_file(path, chunk: int = 1 << 20) -> str:
    """The SHA-256 of a file's bytes (hex), read ``chunk`` bytes at a time."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for b in iter(lambda: f.read(chunk), b""):
            h.update(b)
    return h.hexdigest()


def file_size(path) -> Optional[int]:
    try:
        return os.path.getsize(path)
    except OSError:
        return None
