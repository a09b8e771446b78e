"""The MCAP file writer: compresses and writes the chunks the engine built, then the summary.

Kept apart from ``mcap.sink`` so that the writer process (spawned fresh) imports only numpy,
zstandard and the record encoders (engine/mcap/records.py), not the engine. The engine side
(engine/mcap/chunks.py) builds each chunk's uncompressed records; this side compresses them
(one reused zstd context), writes the Chunk record followed by its Message Index records,
spools its Chunk Index record (flat memory), and at ``finish`` writes Data End with the CRC32
of the whole data section, the summary (schemas, channels, statistics, chunk indexes with their
message-index offsets, metadata indexes), summary offsets and footer (with the summary CRC).
Every chunk carries the CRC32 of its uncompressed records. The layout is the MCAP
specification's, checked by tests/mcap_layout.py and by Foxglove's TypeScript reader
(tools/check_mcap_ts.sh).
"""

from __future__ import annotations

import os
import struct
import time
from typing import Optional


from . import records as rec

LIBRARY = "stillpoint"
CHUNK_SIZE = 4 << 20  # 4 MiB uncompressed chunks at most (specs/mcap-python.md §7.1)
COMPRESSIONS = ("zstd", "lz4", "none")
_IOV = 960  # parts per writev (Linux takes at most 1024, IOV_MAX)
ZSTD_LEVEL = 1  # higher levels cost much more CPU for a few percent fewer bytes (docs/performance.md#code-figures)


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


class _ChunkIndexSpool:
    """The summary's Chunk Index records, encoded as each chunk is written and kept in a spooled
    temporary file (in memory up to ``SPOOL_BYTES``, then on disk): memory stays flat however
    long the run (~120 B a chunk)."""

    SPOOL_BYTES = 1 << 20

    def __init__(self):
        import tempfile
        self._f = tempfile.SpooledTemporaryFile(max_size=self.SPOOL_BYTES)
        self.count = 0
        self.size = 0

    def append(self, record: bytes) -> None:
        self._f.write(record)
        self.count += 1
        self.size += len(record)

    def pieces(self, piece: int = 1 << 20):
        self._f.seek(0)
        while True:
            b = self._f.read(piece)
            if not b:
                return
            yield b

    def close(self) -> None:
        self._f.close()


class _WriterCore:
    """The file: writes chunks (compressed here) each followed by its Message Index records,
    metadata and, at ``finish``, Data End (with the CRC of the whole data section) and the
    summary.

    ``target``: a path (created or truncated) or an open file descriptor positioned at 0 (e.g.
    an ``AtomicOutput``'s; not closed here). Operations: ``("chunk", data, start, end,
    indexes, fsync)`` (from ``ChunkBuilder.take``), ``("chunks", data, bounds, starts, ends,
    index_blob, index_bounds, index_maps, fsync)`` (many at once, from
    ``ChunkBuilder.whole_chunks``), ``("metadata", name, values)``,
    ``("flush", fsync)``, ``("finish", summary)`` (``summary`` from ``ChunkBuilder.summary``).
    Every chunk is handed to the OS as soon as it is written (a killed process loses nothing
    written before); fsync at most once per ``fsync_every_wall_s`` unless asked.
    """

    def __init__(self, target, compression: str, fsync_every_wall_s: float,
                 zstd_level: int = ZSTD_LEVEL):
        if compression not in COMPRESSIONS:
            raise ValueError(f"compression must be one of {', '.join(COMPRESSIONS)}")
        self.fsync_every_wall_s = fsync_every_wall_s
        self.compression = "" if compression == "none" else compression
        self._compress = _compressor(compression, zstd_level)
        if isinstance(target, int):
            self._f = None
            self._fd = target
        elif isinstance(target, (list, tuple)):  # ("fd-path", path): open an existing file
            self._f = open(os.open(target[1], os.O_WRONLY | getattr(os, "O_CLOEXEC", 0)
                                   | getattr(os, "O_NOFOLLOW", 0)), "wb",
                           buffering=0)
            self._fd = self._f.fileno()
        else:
            self._f = open(target, "wb", buffering=0)  # unbuffered: one writev per chunk
            self._fd = self._f.fileno()
        self._pos = 0
        self._crc = 0  # CRC32 of the data section (from the magic to Data End)
        self._write(rec.MAGIC, rec.header("", LIBRARY))
        self._chunks = _ChunkIndexSpool()
        self._meta: list[tuple[int, int, str]] = []
        self._last_fsync = time.monotonic()
        self.closed = False

    def _write(self, *parts) -> None:
        """Hand ``parts`` to the OS (a killed process loses nothing written before)."""
        want = 0
        crc = self._crc
        for p in parts:
            want += len(p)
            crc = rec.crc32(p, crc)
        self._crc = crc
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
        if op == "chunks":
            self._chunks_out(*args)
        elif op == "chunk":
            data, start, end, indexes, fsync = args
            blob = b"".join(r for _cid, r in indexes)
            imap, at = [], 0
            for cid, r in indexes:
                imap.append((cid, at))
                at += len(r)
            self._chunks_out(data, [0, len(data)], [start], [end], blob, [0, len(blob)], [imap],
                             fsync)
        elif op == "metadata":
            name, values = args
            r = rec.metadata(name, values)
            self._meta.append((self._pos, len(r), name))
            self._write(r)
        elif op == "flush":
            self._sync(args[0])
        elif op == "finish":
            self._finish(args[0])

    def _chunks_out(self, data, bounds, starts, ends, blob, ibounds, maps, fsync) -> None:
        """Chunks i = 0.. of ``data[bounds[i]:bounds[i + 1]]`` (uncompressed records, time
        range ``starts[i]..ends[i]``), each followed by its Message Index records
        ``blob[ibounds[i]:ibounds[i + 1]]`` (``maps[i]``: channel id, offset of its record
        there), written with one writev (at most ``_IOV`` parts a call)."""
        mv, iv = memoryview(data), memoryview(blob)
        name, compress = self.compression, self._compress
        pos = self._pos
        parts = []
        for i, (start, end) in enumerate(zip(starts, ends)):
            d = mv[bounds[i]:bounds[i + 1]]
            comp = compress(d) if compress else d
            head = rec.chunk_head(start, end, len(d), rec.crc32(d), name, len(comp))
            ix = iv[ibounds[i]:ibounds[i + 1]]
            length = len(head) + len(comp)
            ipos = pos + length
            self._chunks.append(rec.chunk_index(start, end, pos, length,
                                                {cid: ipos + o for cid, o in maps[i]}, len(ix),
                                                name, len(comp), len(d)))
            parts += (head, comp, ix)
            pos = ipos + len(ix)
        for j in range(0, len(parts), _IOV):
            self._write(*parts[j:j + _IOV])
        self._sync(fsync)

    def _finish(self, summary: dict) -> None:
        self._write(rec.data_end(self._crc))
        start = self._pos
        groups = []  # (opcode, bytes)
        if summary["schemas"]:
            groups.append((rec.OP_SCHEMA, b"".join(summary["schemas"])))
        if summary["channels"]:
            groups.append((rec.OP_CHANNEL, b"".join(summary["channels"])))
        groups.append((rec.OP_STATISTICS, summary["statistics"]))
        if self._chunks.count:  # copied from the spool in pieces
            groups.append((rec.OP_CHUNK_INDEX, (self._chunks.pieces(), self._chunks.size)))
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
                crc = rec.crc32(piece, crc)
                self._write(piece)
            if self._pos - start_group != length:
                raise AssertionError("summary group length mismatch")
        self._chunks.close()
        offset_start = self._pos
        so = b"".join(offsets)
        crc = rec.crc32(so, crc)
        self._write(so)
        foot = rec.footer_body_prefix(start, offset_start)
        crc = rec.crc32(foot, crc)
        self._write(foot, struct.pack("<I", crc), rec.MAGIC)
        os.fsync(self._fd)
        self.closed = True
        if self._f is not None:
            self._f.close()

    def abandon(self) -> None:
        """Stop without finishing: what was written stays on disk, recoverable."""
        self.closed = True
        try:
            self._chunks.close()
            if self._f is not None:
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
