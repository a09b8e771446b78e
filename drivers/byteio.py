"""Opening recordings as byte streams: plain files, gzip (streamed, never unpacked to disk),
and *follow* mode for a file that is still being written (a download in progress)."""

from __future__ import annotations

import gzip
import io
import os
import time
from typing import BinaryIO, Callable, Optional

GZIP_MAGIC = b"\x1f\x8b"


def is_gzip(path) -> bool:
    with open(path, "rb") as f:
        return f.read(2) == GZIP_MAGIC


def open_bytes(path) -> BinaryIO:
    """Open ``path`` for reading bytes; gzip files are decompressed transparently as a stream."""
    if is_gzip(path):
        return gzip.open(path, "rb")  # type: ignore[return-value]
    return open(path, "rb", buffering=0)


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
                return self._f.readinto(b) or 0
            time.sleep(self._poll)
            waited += self._poll

    def close(self) -> None:
        self._f.close()
        super().close()


def check_recording_path(path, *, allow_empty: bool = False) -> None:
    """Raise the typed error for a path that cannot hold a recording: missing, a directory, or
    empty (an empty file is allowed when following a file that is about to be written)."""
    from .errors import RecordingError, TruncatedRecordingError

    p = os.fspath(path)
    if not os.path.exists(p):
        raise RecordingError(p, "no such file")
    if os.path.isdir(p):
        raise RecordingError(p, "is a directory, not a recording")
    if not allow_empty and os.path.getsize(p) == 0:
        raise TruncatedRecordingError(p, "file is empty (0 bytes)")


def file_size(path) -> Optional[int]:
    try:
        return os.path.getsize(path)
    except OSError:
        return None
