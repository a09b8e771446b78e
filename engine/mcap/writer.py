"""The MCAP file writer: compresses and writes the chunks the engine built, then the summary.

Kept apart from ``mcap.sink`` so that the writer process (spawned fresh) imports only numpy,
zstandard and the record encoders (engine/mcap/records.py), not the engine. The engine side
(engine/mcap/chunks.py) builds each chunk's uncompressed records; this side compresses them
(one reused zstd context), writes the Chunk record, keeps one row of 6 int64 per chunk for the
chunk index (flat memory: 56 B per 10 s of data), and at ``finish`` writes Data End, the summary
(schemas, channels, statistics, chunk indexes, metadata indexes), summary offsets and footer
(with the summary CRC). No message indexes: readers scan the small one-cell chunks
(specs/mcap-python.md §3). Every chunk carries the CRC32 of its uncompressed records.
"""

from __future__ import annotations

import os
import struct
import time
import zlib
from typing import Optional

import numpy as np

from . import records as rec

LIBRARY = "stillpoint"
CHUNK_SIZE = 4 << 20  # 4 MiB uncompressed chunks at most (specs/mcap-python.md §7.1)
COMPRESSIONS = ("zstd", "lz4", "none")
ZSTD_LEVEL = 1  # measured on 10 s chunks of a 100 Hz AX3 log: level 3 costs ~40 % more CPU for ~5 % fewer bytes


def peak_rss_mb() -> Optional[float]:
    """This process's peak RSS (VmHWM). Not getrusage: after fork+exec Linux reports the parent's
    high-water mark in ru_maxrss, which would charge the engine's memory to the writer."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    import resource
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _compressor(compression: str, zstd_level: int):
    if compression == "zstd":
        import zstandard
        return zstandard.ZstdCompressor(level=zstd_level).compress  # one reused context
    if compression == "lz4":
        import lz4.frame
        return lz4.frame.compress
    return None


class _ChunkIndexRows:
    """One int64 row per chunk (start, end, offset, length, compressed, uncompressed); the
    summary's Chunk Index records are encoded from them in one numpy pass."""

    def __init__(self):
        self._rows = np.zeros((1024, 6), np.int64)
        self._n = 0

    def append(self, *row) -> None:
        if self._n == self._rows.shape[0]:
            self._rows = np.concatenate([self._rows, np.zeros_like(self._rows)])
        self._rows[self._n] = row
        self._n += 1

    def __len__(self) -> int:
        return self._n

    def records(self, compression: str, rows: int = 8192):
        """The Chunk Index records, in pieces of ``rows`` (bounded memory at ``finish``)."""
        for a in range(0, self._n, rows):
            yield self._records(compression, a, min(self._n, a + rows))

    def record_size(self, compression: str) -> int:
        return 1 + 8 + 8 * 4 + 4 + 8 + 4 + len(compression.encode()) + 8 + 8

    def _records(self, compression: str, lo: int, hi: int) -> bytes:
        c = compression.encode()
        fields = [("op", "u1"), ("len", "<u8"), ("start", "<u8"), ("end", "<u8"),
                  ("offset", "<u8"), ("length", "<u8"), ("mio", "<u4"), ("mil", "<u8"),
                  ("clen", "<u4")]
        if c:
            fields.append(("cname", f"S{len(c)}"))
        fields += [("csize", "<u8"), ("usize", "<u8")]
        dt = np.dtype(fields)
        r = self._rows[lo:hi]
        a = np.zeros(hi - lo, dt)
        a["op"] = rec.OP_CHUNK_INDEX
        a["len"] = dt.itemsize - 9
        a["start"], a["end"], a["offset"], a["length"] = r[:, 0], r[:, 1], r[:, 2], r[:, 3]
        a["clen"] = len(c)
        if c:
            a["cname"] = c
        a["csize"], a["usize"] = r[:, 4], r[:, 5]
        return a.tobytes()


class _WriterCore:
    """The file: writes chunks (compressed here), metadata and, at ``finish``, the summary.

    Operations: ``("chunk", data, start, end, fsync)``, ``("metadata", name, values)``,
    ``("flush", fsync)``, ``("finish", summary)`` (``summary`` from ``ChunkBuilder.summary``).
    Every chunk is handed to the OS as soon as it is written (a killed process loses nothing
    written before); fsync at most once per ``fsync_every_wall_s`` unless asked.
    """

    def __init__(self, path: str, compression: str, fsync_every_wall_s: float,
                 zstd_level: int = ZSTD_LEVEL):
        if compression not in COMPRESSIONS:
            raise ValueError(f"compression must be one of {', '.join(COMPRESSIONS)}")
        self.fsync_every_wall_s = fsync_every_wall_s
        self.compression = "" if compression == "none" else compression
        self._compress = _compressor(compression, zstd_level)
        self._f = open(path, "wb", buffering=0)  # unbuffered: one writev per chunk, no copies
        self._fd = self._f.fileno()
        self._pos = 0
        self._write(rec.MAGIC, rec.header("", LIBRARY))
        self._chunks = _ChunkIndexRows()
        self._meta: list[tuple[int, int, str]] = []
        self._last_fsync = time.monotonic()

    def _write(self, *parts) -> None:
        """Hand ``parts`` to the OS (a killed process loses nothing written before)."""
        want = sum(len(p) for p in parts)
        done = os.writev(self._fd, parts)
        if done != want:  # a short write (signal, full pipe/disk): finish it piece by piece
            view = memoryview(b"".join(parts))[done:]
            while view:
                k = os.write(self._fd, view)
                view = view[k:]
        self._pos += want

    def _sync(self, force: bool) -> None:
        now = time.monotonic()
        if force or now - self._last_fsync >= self.fsync_every_wall_s:
            os.fsync(self._fd)
            self._last_fsync = now

    def execute(self, op, *args):
        if op == "chunk":
            data, start, end, fsync = args
            comp = self._compress(data) if self._compress else data
            parts = rec.chunk(start, end, len(data), zlib.crc32(data), self.compression, comp)
            offset = self._pos
            self._write(*parts)
            self._chunks.append(start, end, offset, self._pos - offset, len(comp), len(data))
            self._sync(fsync)
        elif op == "metadata":
            name, values = args
            r = rec.metadata(name, values)
            self._meta.append((self._pos, len(r), name))
            self._write(r)
        elif op == "flush":
            self._sync(args[0])
        elif op == "finish":
            self._finish(args[0])

    def _finish(self, summary: dict) -> None:
        self._write(rec.data_end(0))
        start = self._pos
        groups = []  # (opcode, bytes)
        if summary["schemas"]:
            groups.append((rec.OP_SCHEMA, b"".join(summary["schemas"])))
        if summary["channels"]:
            groups.append((rec.OP_CHANNEL, b"".join(summary["channels"])))
        groups.append((rec.OP_STATISTICS, summary["statistics"]))
        if len(self._chunks):  # written in pieces: ~70 B a chunk, 8.5 MB for 14 days
            groups.append((rec.OP_CHUNK_INDEX, (self._chunks.records(self.compression),
                                                len(self._chunks) * self._chunks.record_size(self.compression))))
        if self._meta:
            groups.append((rec.OP_METADATA_INDEX,
                           b"".join(rec.metadata_index(o, n, name) for o, n, name in self._meta)))
        crc = 0
        offsets = []
        for op, body in groups:
            pieces, length = body if isinstance(body, tuple) else ([body], len(body))
            offsets.append(rec.summary_offset(op, self._pos, length))
            start_group = self._pos
            for piece in pieces:
                crc = zlib.crc32(piece, crc)
                self._write(piece)
            if self._pos - start_group != length:
                raise AssertionError("summary group length mismatch")
        offset_start = self._pos
        so = b"".join(offsets)
        crc = zlib.crc32(so, crc)
        self._write(so)
        foot = rec.footer_body_prefix(start, offset_start)
        crc = zlib.crc32(foot, crc)
        self._write(foot, struct.pack("<I", crc), rec.MAGIC)
        os.fsync(self._fd)
        self._f.close()

    def abandon(self) -> None:
        """Stop without finishing: what was written stays on disk, recoverable."""
        try:
            self._f.close()
        except Exception:
            pass


def _writer_loop(rconn, wconn, core_args) -> None:
    """Serve write operations from ``rconn`` until ``None`` (then report) or EOF (engine died:
    leave the file unfinished and recoverable)."""
    try:
        core = _WriterCore(*core_args)
    except BaseException as e:
        wconn.send(("error", f"{type(e).__name__}: {e}"))
        return
    while True:
        try:
            item = rconn.recv()
        except (EOFError, OSError):
            core.abandon()
            return
        if item is None:
            core.abandon()
            wconn.send(("done", peak_rss_mb()))
            return
        try:
            for it in (item if isinstance(item, list) else [item]):
                core.execute(*it)
        except BaseException as e:
            core.abandon()
            wconn.send(("error", f"{type(e).__name__}: {e}"))
            return


class WriterProcess:
    """A writer in a child process started with ``python -m stillpoint.engine.mcap.writer``:
    no multiprocessing (so no re-import of the caller's ``__main__`` and no "daemonic processes
    cannot have children" inside process pools), operations pickled over its stdin, replies on
    its stdout."""

    def __init__(self, core_args):
        import json
        import subprocess
        import sys
        from multiprocessing.connection import Connection
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "stillpoint.engine.mcap.writer", json.dumps(list(core_args))],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, close_fds=True)
        self._w = Connection(os.dup(self.proc.stdin.fileno()), readable=False)
        self._r = Connection(os.dup(self.proc.stdout.fileno()), writable=False)
        self.proc.stdin.close()
        self.proc.stdout.close()

    def send(self, obj) -> None:
        self._w.send(obj)

    def poll(self) -> bool:
        return self._r.poll()

    def recv(self):
        return self._r.recv()

    def close(self) -> None:
        for c in (self._w, self._r):
            try:
                c.close()
            except OSError:
                pass
        self.proc.wait()


def _main() -> None:  # the writer process
    import json
    import signal
    import sys
    from multiprocessing.connection import Connection
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the engine decides what an interrupt means
    rconn = Connection(os.dup(0), writable=False)
    wconn = Connection(os.dup(1), readable=False)
    os.dup2(2, 1)  # stray output must not corrupt the reply channel
    _writer_loop(rconn, wconn, json.loads(sys.argv[1]))


if __name__ == "__main__":
    _main()
