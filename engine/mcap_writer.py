"""The MCAP writer core: the mcap ``Writer`` and its file, executing write operations.

Kept apart from ``mcap_sink`` so that the writer process (spawned fresh) imports only numpy and
mcap (~30 MB) and not the engine. Operations: ``("msg", topic, encoding, schema, log_time,
data)``, ``("msgs", topic, encoding, schema, [(log_time, data), ...])``, ``("metadata", name,
values)``, ``("flush", fsync)``, ``("finish",)``.
"""

from __future__ import annotations

import os
import time
from typing import Optional

import numpy as np
from mcap.records import ChunkIndex
from mcap.writer import CompressionType, IndexType, Writer

from .mcap_schemas import ALL_TYPES

LIBRARY = "stillpoint"
CHUNK_SIZE = 4 << 20  # 4 MiB uncompressed chunks (specs/mcap-python.md §7.1)

_COMPRESSION = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}


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


class _CompactChunkIndexes:
    """Drop-in for the mcap Writer's list of chunk indexes, stored as int64 rows.

    The writer keeps one ChunkIndex object per chunk until ``finish()`` writes the summary
    (~0.6 KB each); with a chunk per 10 s of data that is ~70 MB for 14 days. Rows of 7 int64
    (56 B) keep the writer's memory flat; iteration rebuilds the records for the summary.
    """

    _FIELDS = ("chunk_length", "chunk_start_offset", "compressed_size", "message_end_time",
               "message_index_length", "message_start_time", "uncompressed_size")

    def __init__(self):
        self._rows = np.zeros((1024, len(self._FIELDS)), np.int64)
        self._n = 0
        self._compression: dict[int, str] = {}  # row -> compression, where not the first's
        self._first_compression: Optional[str] = None
        self._offsets: dict[int, dict] = {}  # row -> message index offsets (none without them)

    def append(self, ci: ChunkIndex) -> None:
        if self._n == self._rows.shape[0]:
            self._rows = np.concatenate([self._rows, np.zeros_like(self._rows)])
        self._rows[self._n] = [getattr(ci, f) for f in self._FIELDS]
        if self._first_compression is None:
            self._first_compression = ci.compression
        elif ci.compression != self._first_compression:
            self._compression[self._n] = ci.compression
        if ci.message_index_offsets:
            self._offsets[self._n] = dict(ci.message_index_offsets)
        self._n += 1

    def __len__(self) -> int:
        return self._n

    def __iter__(self):
        for i in range(self._n):
            vals = dict(zip(self._FIELDS, (int(v) for v in self._rows[i])))
            yield ChunkIndex(compression=self._compression.get(i, self._first_compression),
                             message_index_offsets=self._offsets.get(i, {}), **vals)


class _ReusedZstd:
    """Stand-in for the ``zstandard`` module inside ``mcap.writer`` (writer process only): one
    reused compressor context instead of a new one per chunk (``zstandard.compress`` builds a
    context each call, a fixed cost that matters with a chunk every 10 s of data)."""

    def __init__(self, level: int = 3):
        import zstandard
        self._c = zstandard.ZstdCompressor(level=level)

    def compress(self, data: bytes) -> bytes:
        return self._c.compress(data)


def use_reused_zstd(level: int = 3) -> None:
    import mcap.writer as mw
    if getattr(mw, "zstandard", None) is not None and not isinstance(mw.zstandard, _ReusedZstd):
        mw.zstandard = _ReusedZstd(level)


class _WriterCore:
    """The mcap Writer and the file: executes write operations (in-process, in a thread, or in
    a writer process)."""

    def __init__(self, path: str, chunk_size: int, compression: str, fsync_every_wall_s: float):
        self.fsync_every_wall_s = fsync_every_wall_s
        self._f = open(path, "wb")
        # no per-message index: 16 B + a Python record per message per chunk, and the per-chunk
        # index dicts the writer keeps for the summary would grow with the number of flushes;
        # readers scan our small (one-cell) chunks instead (specs/mcap-python.md §3)
        self._w = Writer(self._f, chunk_size=chunk_size, compression=_COMPRESSION[compression],
                         index_types=IndexType.CHUNK | IndexType.METADATA | IndexType.ATTACHMENT)
        if isinstance(getattr(self._w, "_Writer__chunk_indices", None), list):
            self._w._Writer__chunk_indices = _CompactChunkIndexes()
        self._w.start(profile="", library=LIBRARY)
        self._schemas = {t.name: self._w.register_schema(t.name, "ros2msg", t.schema_text().encode())
                         for t in ALL_TYPES}
        self._channels: dict[str, int] = {}
        self._seq: dict[str, int] = {}
        self._last_fsync = time.monotonic()

    def _channel(self, topic: str, encoding: str, schema: Optional[str]) -> int:
        cid = self._channels.get(topic)
        if cid is None:
            sid = self._schemas[schema] if schema else 0
            cid = self._w.register_channel(topic, encoding, sid)
            self._channels[topic] = cid
            self._seq[topic] = 0
        return cid

    def execute(self, op, *args):
        if op == "msg":
            topic, encoding, schema, log_time, data = args
            cid = self._channel(topic, encoding, schema)
            seq = self._seq[topic]
            self._seq[topic] = seq + 1
            t = max(0, int(log_time))
            self._w.add_message(cid, t, data, t, seq)
        elif op == "msgs":
            topic, encoding, schema, items = args
            cid = self._channel(topic, encoding, schema)
            seq = self._seq[topic]
            for t, data in items:
                t = max(0, int(t))
                self._w.add_message(cid, t, data, t, seq)
                seq += 1
            self._seq[topic] = seq
        elif op == "metadata":
            self._w.add_metadata(args[0], args[1])
        elif op == "flush":
            self._w.flush()
            now = time.monotonic()
            if args[0] or now - self._last_fsync >= self.fsync_every_wall_s:
                os.fsync(self._f.fileno())
                self._last_fsync = now
        elif op == "finish":
            self._w.finish()
            self._f.flush()
            os.fsync(self._f.fileno())
            self._f.close()

    def abandon(self) -> None:
        """Stop without finishing: what was flushed stays on disk, recoverable."""
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
    """A writer in a child process started with ``python -m stillpoint.engine.mcap_writer``:
    no multiprocessing (so no re-import of the caller's ``__main__`` and no "daemonic processes
    cannot have children" inside process pools), operations pickled over its stdin, replies on
    its stdout."""

    def __init__(self, core_args):
        import json
        import subprocess
        import sys
        from multiprocessing.connection import Connection
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "stillpoint.engine.mcap_writer", json.dumps(list(core_args))],
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
    use_reused_zstd(int(os.environ.get("STILLPOINT_ZSTD_LEVEL", "3")))
    _writer_loop(rconn, wconn, json.loads(sys.argv[1]))


if __name__ == "__main__":
    _main()
