"""``McapLog``: the one MCAP writer path of stillpoint (process, replay, recover, align, and any
caller that logs estimates, e.g. the station or static calibration).

It pairs the chunk builder (engine/mcap/chunks.py: records, message indexes, statistics) with
the file writer (engine/mcap/writer.py: compression, chunk and summary records) and writes
through ``engine/core/outputs.AtomicOutput``: the file is ``<name>.part`` (locked against a second
writer) until ``close()`` finishes it and renames it onto ``<name>``. An interrupted run leaves
the ``.part`` file, every complete chunk of which ``stillpoint recover`` salvages.

Topics are registered on first use with their encoding and schema: CDR types from
engine/mcap/schemas.py (``ros2msg``) and JSON schemas from engine/mcap/jsonschemas.py
(``jsonschema``); ``define_schema`` adds others. The public calls:

    with McapLog("est.mcap") as log:
        log.write_json("/static_calibration", t_ns, estimate_dict, schema=STATIC_CALIBRATION)
        log.write_metadata("device", {"id": "1234"})

Writers: ``"inline"`` (default: compress and write in the caller's thread), ``"thread"`` (one
chunk queued to a writer thread) or ``"process"`` (a fresh child process; see writer.py).
"""

from __future__ import annotations

import queue
import threading
from pathlib import Path
from typing import Optional

from stillpoint.engine.core.outputs import AtomicOutput, OutputError, describe_os_error

from ..core.jsonsafe import dumps

from .chunks import ChunkBuilder
from .jsonschemas import JsonSchema
from .schemas import ALL_TYPES, CdrType
from .writer import CHUNK_SIZE, ZSTD_LEVEL, WriterProcess, _WriterCore

WRITERS = ("inline", "thread", "process")


def recover_hint(part) -> str:
    return f"the partial log {part} is kept; `stillpoint recover {part}` salvages it"


class McapLog:
    """One MCAP being written (see the module docstring). Use as a context manager or call
    ``close()`` (finish and rename) / ``abort()`` (stop; the ``.part`` file stays)."""

    def __init__(self, path, *, compression: str = "zstd", chunk_size: int = CHUNK_SIZE,
                 fsync_every_wall_s: float = 1.0, writer: str = "inline",
                 zstd_level: int = ZSTD_LEVEL, what: str = "MCAP output"):
        if writer not in WRITERS:
            raise ValueError(f"writer must be one of {', '.join(WRITERS)}")
        self.path = Path(path)
        self._out = AtomicOutput(self.path, what=what)
        self.part = self._out.part
        self.set_aside = self._out.set_aside
        self._error: Optional[str] = None
        self._q: Optional[queue.Queue] = None
        self._thread = None
        self._conn = None
        self._metadata = 0
        self.writer_maxrss_mb: Optional[float] = None  # the writer process's peak RSS
        self._chunk = ChunkBuilder({t.name: ("ros2msg", t.schema_text().encode()) for t in ALL_TYPES},
                                   chunk_size)
        try:
            if writer == "process":
                # a fresh, small writer process (~30 MB; a fork would inherit the engine's heap)
                self._conn = WriterProcess((["fd-path", str(self.part)], compression,
                                            fsync_every_wall_s, int(zstd_level)))
                self._core = None
            else:
                self._core = _WriterCore(self._out.fd, compression, fsync_every_wall_s,
                                         int(zstd_level))
                if writer == "thread":
                    # at most one chunk waits while one is compressed
                    self._q = queue.Queue(maxsize=1)
                    self._thread = threading.Thread(target=self._worker, name="mcap-writer",
                                                    daemon=True)
                    self._thread.start()
        except BaseException:
            self._out.abandon()
            raise

    # ------------------------------------------------------------------ plumbing
    @property
    def messages(self) -> int:
        return self._chunk.message_count

    def _worker(self):
        while True:
            item = self._q.get()
            if item is None:
                return
            if self._error is None:
                try:
                    self._core.execute(*item)
                except OSError as e:
                    self._error = describe_os_error(e)
                except BaseException as e:  # reported on the caller's next call
                    self._error = f"{type(e).__name__}: {e}"

    def _fail(self, reason: str):
        kept = self.abort()
        hint = f"; {recover_hint(kept)}" if kept else ""
        raise OutputError(self.path, f"writing failed: {reason}{hint}") from None

    def _check(self):
        if self._conn is not None and self._error is None and self._conn.poll():
            msg = self._conn.recv()
            if msg[0] == "error":
                self._error = msg[1]
        if self._error is not None:
            self._fail(self._error)

    def _send(self, item) -> None:
        """Hand one file operation to the writer (process, thread or inline)."""
        self._check()
        if self._conn is not None:
            try:
                self._conn.send(item)
            except (BrokenPipeError, OSError):
                self._check()
                self._fail("the writer process ended")
        elif self._q is None:
            try:
                self._core.execute(*item)
            except OSError as e:
                self._fail(describe_os_error(e))
        else:
            self._q.put(item)

    def _end_chunk(self, fsync: bool) -> None:
        c = self._chunk.take()
        if c is not None:
            self._send(("chunk", *c, fsync))
        elif fsync:
            self._send(("flush", True))

    # ------------------------------------------------------------------ schemas and channels
    def define_schema(self, name: str, encoding: str, data: bytes) -> None:
        """Make a schema known (used when a channel first names it)."""
        self._chunk.define(name, encoding, data)

    def channel(self, topic: str, encoding: str, schema=None) -> int:
        """The channel id of ``topic`` (registered on first use). ``schema``: a ``CdrType``,
        a ``JsonSchema``, a schema name already defined, or None (schemaless)."""
        name = None
        if isinstance(schema, (CdrType, JsonSchema)):
            name = schema.name
            if name not in self._chunk.schema_defs:
                enc = "ros2msg" if isinstance(schema, CdrType) else "jsonschema"
                text = schema.schema_text() if isinstance(schema, CdrType) else schema.text
                self._chunk.define(name, enc, text.encode())
        elif schema:
            name = str(schema)
        return self._chunk.channel(topic, encoding, name)

    # ------------------------------------------------------------------ messages
    def add(self, cid: int, log_time: int, data: bytes, *, sequence: Optional[int] = None,
            publish_time: Optional[int] = None) -> None:
        """One message on channel ``cid`` (payload already encoded)."""
        if self._chunk.add(cid, log_time, data, sequence=sequence, publish_time=publish_time):
            self._end_chunk(False)

    def write(self, topic: str, encoding: str, schema, log_time: int, data: bytes) -> None:
        self.add(self.channel(topic, encoding, schema), log_time, data)

    def write_cdr(self, topic: str, cdr_type: CdrType, log_time: int, values: dict) -> None:
        """One CDR message of ``cdr_type`` (``values``: field -> value)."""
        self.add(self.channel(topic, "cdr", cdr_type), log_time, cdr_type.encode(values))

    def write_json(self, topic: str, log_time: int, obj, schema: Optional[JsonSchema] = None) -> None:
        """One JSON message (keys sorted, NaN/inf as null) with its JSON schema, if given."""
        self.add(self.channel(topic, "json", schema), log_time, dumps(obj).encode())

    def write_metadata(self, name: str, values: dict) -> None:
        """A Metadata record (string values; others are stored as JSON text)."""
        self._send(("metadata", name, {k: (v if isinstance(v, str) else dumps(v))
                                       for k, v in values.items()}))
        self._metadata += 1

    def flush(self, fsync: bool = True) -> None:
        """Close the chunk in progress and hand it to the OS (``fsync``: to the disk)."""
        self._end_chunk(fsync)

    # ------------------------------------------------------------------ end
    def close(self) -> Path:
        """Finish the file (summary, indexes, footer), rename it onto its name; return it."""
        self._end_chunk(False)
        self._send(("finish", self._chunk.summary(self._metadata)))
        self._stop()
        if self._error is not None:
            self._fail(self._error)
        try:
            return self._out.commit()
        except OutputError:
            raise
        except OSError as e:
            self._fail(describe_os_error(e))

    def abort(self) -> Optional[Path]:
        """Stop writing without finishing; return the partial file kept (None if empty)."""
        self._stop()
        if self._core is not None:
            self._core.abandon()
        return self._out.abandon()

    def _stop(self):
        if self._thread is not None:
            self._q.put(None)
            self._thread.join()
            self._thread = None
        if self._conn is not None:
            try:
                self._conn.send(None)
            except (OSError, BrokenPipeError):
                pass
            done = False
            try:
                while True:
                    msg = self._conn.recv()
                    if msg[0] == "error":
                        self._error = msg[1]
                    elif msg[0] == "done":
                        done = True
                        self.writer_maxrss_mb = msg[1]
            except (EOFError, OSError):
                pass
            if not done and self._error is None:
                self._error = "the writer process ended unexpectedly"
            self._conn.close()
            self._conn = None

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            self.close()
        else:
            kept = self.abort()
            if kept is not None and exc is not None:
                try:
                    exc.partial_output = str(kept)
                except AttributeError:
                    pass

