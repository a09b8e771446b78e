"""A source read ahead on a thread: the next blocks are decoded while the pipeline works.

``Prefetched(source)`` is itself a Source: iterating it runs the source's own iterator on a
reader thread, at most ``depth`` blocks ahead, and hands the blocks over in order. Reading and
decoding a block (file reads, numpy over the whole block) run mostly outside the interpreter
lock, so on a machine with a second core they overlap the engine's work on the block before.

What the pipeline sees is exactly what it would see without the thread, so every log is the
same byte for byte:

* the same blocks in the same order (a source's blocks own their memory: no reader reuses an
  array it has handed out);
* the source's QC report as it stood when the block being processed was produced (a copy taken
  then): stages log the reader's QC events as they appear, so what they log cannot depend on
  how far ahead the thread got. Once the source is exhausted, ``qc`` is the source's own report;
* the source's exception raised after the blocks before it, as raised.

``close()`` (or leaving the loop early: an exception in a stage, Ctrl-C) stops the thread and
then closes the source. Other attributes (``info``, ...) are the source's.
"""

from __future__ import annotations

import os
import queue
import threading
from dataclasses import replace
from typing import Iterator, Optional

from .blocks import Block

# Blocks decoded ahead (a .cwa reader block is ~1 MB of samples). `stillpoint process` on the
# week's bench file, four alternating runs each: one block ahead 11.93-12.16 s wall at 68.3-68.9
# MB peak RSS, two blocks ahead 11.82-12.19 s at 69.6-70.3 MB.
DEPTH = 1
_JOIN_S = 5.0  # how long close() waits for the thread before closing the source under it

_BLOCK, _END, _ERROR = 0, 1, 2


CORES_ENV = "STILLPOINT_CORES"  # at most this many cores (1: no extra threads; for debugging)


def cores_available() -> int:
    """CPUs this process may run on (the affinity mask where the platform has one), at most
    $STILLPOINT_CORES when that is set to a positive whole number."""
    try:
        n = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        n = os.cpu_count() or 1
    cap = os.environ.get(CORES_ENV, "").strip()
    if cap.isdigit() and int(cap) > 0:
        n = min(n, int(cap))
    return n


class Prefetched:
    """Iterate ``source`` on a reader thread, ``depth`` blocks ahead (see the module docstring)."""

    def __init__(self, source, depth: int = DEPTH):
        self.source = source
        self.depth = max(1, int(depth))
        self._qc = getattr(source, "qc", None)
        self._thread: Optional[threading.Thread] = None
        self._queue: Optional[queue.Queue] = None
        self._stop = threading.Event()

    def __getattr__(self, name):
        if name == "source":  # not set yet (copy, pickle): no recursion through __getattr__
            raise AttributeError(name)
        return getattr(self.source, name)

    @property
    def qc(self):
        """The source's QC report."""
        return self._qc

    def __iter__(self) -> Iterator[Block]:
        if self._thread is not None:
            raise RuntimeError("a source is single-pass; open it again for another pass")
        q: queue.Queue = queue.Queue(self.depth)
        self._queue = q
        self._thread = t = threading.Thread(target=self._produce, name="source-prefetch",
                                            daemon=True)
        t.start()
        try:
            while True:
                kind, item, qc = q.get()
                if kind == _BLOCK:
                    self._qc = qc
                    yield item
                elif kind == _END:
                    self._qc = getattr(self.source, "qc", None)
                    return
                else:
                    self._qc = qc
                    raise item
        finally:
            self._halt()

    # ------------------------------------------------------------------ the reader thread
    def _snapshot(self):
        qc = getattr(self.source, "qc", None)
        return replace(qc, events=list(qc.events)) if qc is not None else None

    def _put(self, item) -> bool:
        """Queue ``item`` unless stopped (True: queued and not stopped). A put blocked on a full
        queue is released by ``_halt``, which empties the queue after setting the stop flag."""
        if self._stop.is_set():
            return False
        q = self._queue
        assert q is not None  # set before the producer starts
        q.put(item)
        return not self._stop.is_set()

    def _produce(self) -> None:
        it = None
        try:
            it = iter(self.source)
            for block in it:
                if not self._put((_BLOCK, block, self._snapshot())):
                    return
            self._put((_END, None, None))
        except BaseException as e:  # noqa: BLE001 - raised again on the pipeline's thread
            self._put((_ERROR, e, self._snapshot()))
        finally:
            close = getattr(it, "close", None)
            if self._stop.is_set() and close is not None:
                try:
                    close()  # a generator's cleanup (the reader closes its file)
                except Exception:  # noqa: BLE001 - the pipeline is already leaving
                    pass

    def _halt(self) -> None:
        self._stop.set()
        q, t = self._queue, self._thread
        if q is not None:
            while True:  # release a put waiting on a full queue (at most one more follows)
                try:
                    q.get_nowait()
                except queue.Empty:
                    break
        if t is not None and t is not threading.current_thread():
            t.join(_JOIN_S)

    def close(self) -> None:
        """Stop the reader thread (if running), then close the source."""
        self._halt()
        self.source.close()
