"""One device read per worker process, so that a read blocked on a pulled drive (the kernel's SCSI
timeout can be minutes) never blocks the station: the station only polls the worker's messages
and cancels it with a bound (``stall_s`` without progress -> terminate, then kill).

``Worker(task, job, stall_s=30, what=...).start()`` runs ``task(job, progress, cancel) -> dict``
(a module-level function: it crosses into a fresh interpreter) and ``poll()`` returns the latest
(phase, done bytes, total bytes); when finished, ``result`` is set: the task's dict, or, for a
stalled, crashed or stopped worker, ``{"error": reason}`` (``"stalled": True`` for a stall).
``inline=True`` runs the task on a thread of this process instead (tests: the stall bound still
ends the wait, but a hung thread cannot be killed). Two tasks use it: the download
(``download.DownloadWorker``: its result is a ``DownloadResult``) and the re-read of a device
(``device_read.device_digest``: before a clear, ``device verify``, settling a clear left at
``sent``).

A worker never outlives its station: on Linux it asks the kernel for SIGKILL when its parent
dies (``prctl(PR_SET_PDEATHSIG)``), and everywhere it watches a pipe whose only writing end the
station holds: end of file means the station is gone, and the worker ends at once. Either way a
download's partial copy stays and resumes; a worker never gives a file its final name (the
station does, with the ledger: ``completion``). (The kernel's signal follows the thread that
started the worker; the station's flow thread waits for its worker, so it never ends first.)
"""

from __future__ import annotations

import multiprocessing as mp
import queue
import threading
import time

from typing import Callable, Optional

from ..mcap.writer import peak_rss_mb as _peak_rss_mb  # VmHWM: starts afresh at exec

_CTX = mp.get_context("spawn")  # a fresh interpreter: no inherited threads or emulator state


def _die_with_parent(parent_pid: int, lifeline) -> None:
    """End this process when the station ends (module docstring)."""
    import os
    import sys
    if sys.platform.startswith("linux"):
        try:
            import ctypes
            import signal
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(1, int(signal.SIGKILL), 0, 0, 0)  # PR_SET_PDEATHSIG = 1 (linux/prctl.h)
        except (OSError, AttributeError):
            pass
    if os.getppid() != parent_pid:  # the station died before the request took effect
        os._exit(1)

    def watch():
        try:
            lifeline.recv()  # the station never sends: this returns only at end of file
        except (EOFError, OSError):
            pass
        os._exit(1)
    threading.Thread(target=watch, daemon=True, name="lifeline").start()


def _progress_sender(q) -> Callable[[str, int, int], None]:
    """Progress messages at most every 0.2 s (and at the end of each phase)."""
    last = [0.0]

    def progress(phase, done, total):
        now = time.monotonic()
        if now - last[0] >= 0.2 or done == total:
            last[0] = now
            q.put(("progress", phase, done, total))
    return progress


def _run_task(task, job, progress, cancel) -> dict:
    try:
        d = task(job, progress, cancel)
    except BaseException as e:  # noqa: BLE001 - reported, never a traceback on the station
        d = {"error": f"worker failed: {type(e).__name__}: {e}"}
    d["peak_rss_mb"] = _peak_rss_mb()
    return d


def _main(task, job, q, parent_pid: int = 0, lifeline=None) -> None:
    import signal
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the station decides when a read stops
    if lifeline is not None:
        _die_with_parent(parent_pid, lifeline)
    q.put(("result", _run_task(task, job, _progress_sender(q), None)))


class Worker:
    """``task(job, progress, cancel)`` in a worker process with the stall bound (module
    docstring)."""

    def __init__(self, task, job, *, stall_s: float = 30.0, inline: bool = False,
                 what: str = "read", name: Optional[str] = None):
        self.task = task
        self.job = job
        self.stall_s = stall_s
        self.inline = inline
        self.what = what  # in messages: "the <what> worker ended unexpectedly"
        self.name = name or what  # the process or thread: stillpoint-<name>
        self.result = None
        self.peak_rss_mb: Optional[float] = None
        self.phase, self.done, self.total = "starting", 0, 0
        self._last_progress = time.monotonic()
        self._cancel = threading.Event()
        self._q = _CTX.Queue() if not inline else queue.Queue()
        self._proc = None
        self._thread = None
        self._lifeline = None  # the writing end of the pipe the worker watches
        self.started_at = time.monotonic()

    def start(self):
        self._last_progress = time.monotonic()
        if self.inline:
            def run():
                self._q.put(("result", _run_task(self.task, self.job,
                                                 lambda p, d, t: self._q.put(("progress", p, d, t)),
                                                 self._cancel)))
            self._thread = threading.Thread(target=run, daemon=True, name=f"stillpoint-{self.name}")
            self._thread.start()
        else:
            import os
            reader, self._lifeline = _CTX.Pipe(duplex=False)
            self._proc = _CTX.Process(target=_main, args=(self.task, self.job, self._q, os.getpid(),
                                                          reader),
                                      daemon=True, name=f"stillpoint-{self.name}")
            self._proc.start()
            reader.close()  # only the worker holds the reading end
        return self

    @property
    def finished(self) -> bool:
        return self.result is not None

    # what a failed worker's result is, and what its reason adds (subclasses: the download's)
    def _result(self, d: dict):
        return d

    def _failure(self, reason: str, stalled: bool = False):
        return {"error": reason + "; the read was stopped", "stalled": stalled}

    def poll(self, timeout: float = 0.0) -> tuple:
        end = time.monotonic() + timeout
        while self.result is None:
            try:
                msg = self._q.get(timeout=max(0.0, end - time.monotonic()) or 0.0) \
                    if timeout else self._q.get_nowait()
            except (queue.Empty, EOFError, OSError):
                break
            if msg[0] == "progress":
                # the stall bound is about reading the device: a byte count that moves, or the
                # heartbeat of the pipeline finishing on local data after the last read
                changed = (msg[1], msg[2]) != (self.phase, self.done) or msg[1] == "finishing"
                self.phase, self.done, self.total = msg[1], msg[2], msg[3]
                if changed:
                    self._last_progress = time.monotonic()
            elif msg[0] == "result":
                d = dict(msg[1])
                self.peak_rss_mb = d.pop("peak_rss_mb", None)
                self.result = self._result(d)
                self._reap()
        if self.result is None:
            if self._cancel.is_set():
                self.result = self._stopped()
            elif time.monotonic() - self._last_progress > self.stall_s:
                self._fail(f"reading the device stalled: no progress for {self.stall_s:g} s "
                           f"({self.phase} at {self.done} of {self.total} bytes)", stalled=True)
            elif self._proc is not None and not self._proc.is_alive() and self._q.empty():
                time.sleep(0.1)
                if self._q.empty():
                    self._fail(f"the {self.what} worker ended unexpectedly (exit code "
                               f"{self._proc.exitcode})")
        return self.phase, self.done, self.total

    def _stopped(self):
        return {"error": "stopped by the user"}

    def _fail(self, reason: str, stalled: bool = False) -> None:
        self.cancel()
        self.result = self._failure(reason, stalled)

    def cancel(self, grace_s: float = 2.0) -> None:
        """Stop the worker within ``grace_s`` (+ a kill)."""
        self._cancel.set()
        if self._proc is not None and self._proc.is_alive():
            self._proc.terminate()
            self._proc.join(grace_s)
            if self._proc.is_alive():
                self._proc.kill()
                self._proc.join(1.0)
        if self._lifeline is not None:
            self._lifeline.close()
            self._lifeline = None

    def _reap(self) -> None:
        if self._proc is not None:
            self._proc.join(5.0)
        if self._lifeline is not None:
            self._lifeline.close()
            self._lifeline = None

    def wait(self, poll_s: float = 0.1):
        while self.result is None:
            self.poll(poll_s)
        return self.result
