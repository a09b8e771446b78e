"""Calls run in order on one worker thread, at most ``depth`` of them waiting.

``OrderedWorker`` is how the MCAP sink frames a pipeline step's records on a thread while the
engine works on the next step (engine/mcap/sink.py): the caller hands over calls (``submit``),
the worker runs them one after another in the order they were handed over, so what they write
is the same, byte for byte, as running them in the caller's thread. The queue is bounded
(``depth`` calls waiting, one running): a caller that gets ahead waits, so memory stays flat.

Faults: the first exception a call raises is kept, every later call is dropped unrun, and the
caller gets that exception (the same object, as raised) from its next ``submit`` or from
``drain``. ``stop`` drops what is still waiting and ends the thread once the call running
has returned (an interrupt or a failure in the caller: nothing is left running).
"""

from __future__ import annotations

import queue
import threading
from typing import Callable, Optional

_STOP = None  # queue item: end the thread


class OrderedWorker:
    """One worker thread running submitted calls in order (see the module docstring)."""

    def __init__(self, name: str, depth: int = 2):
        self._q: queue.Queue = queue.Queue(maxsize=max(1, int(depth)))
        self._error: Optional[BaseException] = None
        self._dropping = False
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    @property
    def running(self) -> bool:
        return self._thread is not None

    def on_worker(self) -> bool:
        """True when called from the worker thread itself (a call made by a running call)."""
        return self._thread is not None and threading.current_thread() is self._thread

    def _run(self) -> None:
        q = self._q
        while True:
            item = q.get()
            if item is _STOP:
                return
            if self._error is not None or self._dropping:
                continue  # after a failure or a stop: drop what was queued
            fn, args = item
            try:
                fn(*args)
            except BaseException as e:  # handed to the caller
                self._error = e

    def _raise(self) -> None:
        e = self._error
        if e is not None:
            raise e

    def submit(self, fn: Callable, *args) -> None:
        """Queue ``fn(*args)`` (waits while ``depth`` calls are waiting); raises the first
        exception an earlier call raised."""
        self._raise()
        if self._thread is None:
            raise RuntimeError("the worker has stopped")
        self._q.put((fn, args))

    def drain(self) -> None:
        """Wait until every call handed over has run and end the thread; raise the first
        exception one raised."""
        if self._thread is not None:
            self._q.put(_STOP)
            self._thread.join()
            self._thread = None
        self._raise()

    def stop(self) -> None:
        """End the thread without running what is still waiting (the call running, if any,
        returns first). Errors are not raised."""
        t = self._thread
        self._dropping = True
        if t is None or t is threading.current_thread():  # a call stopping its own worker:
            return  # the caller's stop() ends the thread
        while True:  # make room for the stop item without blocking on a full queue
            try:
                self._q.put_nowait(_STOP)
                break
            except queue.Full:
                try:
                    self._q.get_nowait()
                except queue.Empty:
                    pass
        t.join()
        self._thread = None
