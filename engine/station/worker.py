"""One download per worker process, so that a read blocked on a pulled drive (the kernel's SCSI
timeout can be minutes) never blocks the station: the station only polls the worker's messages
and cancels it with a bound (``stall_s`` without progress -> terminate, then kill).

``DownloadWorker(job, stall_s=30).start()``, then ``poll()`` regularly: it returns the latest
(phase, done bytes, total bytes) and, when finished, ``result`` is set (a ``DownloadResult``;
a stalled or crashed worker gives ``ok=False`` with the reason). ``inline=True`` runs the
download on a thread of this process instead (tests; no hang protection).
"""

from __future__ import annotations

import multiprocessing as mp
import queue
import threading
import time

from typing import Optional

from ..mcap.writer import peak_rss_mb as _peak_rss_mb  # VmHWM: starts afresh at exec
from .download import DownloadJob, DownloadResult, run_download

_CTX = mp.get_context("spawn")  # a fresh interpreter: no inherited threads or emulator state


def _main(job: DownloadJob, q) -> None:
    import signal
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the station decides when a download stops
    last = [0.0]

    def progress(phase, done, total):
        now = time.monotonic()
        if now - last[0] >= 0.2 or done == total:
            last[0] = now
            q.put(("progress", phase, done, total))

    try:
        res = run_download(job, progress)
        d = res.to_dict()
    except BaseException as e:  # noqa: BLE001 - reported, never a traceback on the station
        d = DownloadResult(ok=False, reason=f"download worker failed: {type(e).__name__}: {e}").to_dict()
    d["peak_rss_mb"] = _peak_rss_mb()
    q.put(("result", d))


class DownloadWorker:
    def __init__(self, job: DownloadJob, *, stall_s: float = 30.0, inline: bool = False):
        self.job = job
        self.stall_s = stall_s
        self.inline = inline
        self.result: Optional[DownloadResult] = None
        self.peak_rss_mb: Optional[float] = None
        self.phase, self.done, self.total = "starting", 0, 0
        self._last_progress = time.monotonic()
        self._cancel = threading.Event()
        self._q = _CTX.Queue() if not inline else queue.Queue()
        self._proc = None
        self._thread = None
        self.started_at = time.monotonic()

    def start(self) -> "DownloadWorker":
        self._last_progress = time.monotonic()
        if self.inline:
            def run():
                r = run_download(self.job, lambda p, d, t: self._q.put(("progress", p, d, t)),
                                 self._cancel)
                self._q.put(("result", dict(r.to_dict(), peak_rss_mb=_peak_rss_mb())))
            self._thread = threading.Thread(target=run, daemon=True, name=f"download-{self.job.stem}")
            self._thread.start()
        else:
            self._proc = _CTX.Process(target=_main, args=(self.job, self._q), daemon=True,
                                      name=f"stillpoint-download-{self.job.stem}")
            self._proc.start()
        return self

    @property
    def finished(self) -> bool:
        return self.result is not None

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
                self.result = DownloadResult(**d)
                self._reap()
        if self.result is None:
            if self._cancel.is_set():
                self.result = DownloadResult(ok=False, reason="stopped by the user; the partial copy "
                                             "is kept and resumes next time", bytes=self.done)
            elif time.monotonic() - self._last_progress > self.stall_s:
                self._fail(f"reading the device stalled: no progress for {self.stall_s:g} s "
                           f"({self.phase} at {self.done} of {self.total} bytes); the download "
                           "was stopped and the partial copy is kept")
            elif self._proc is not None and not self._proc.is_alive() and self._q.empty():
                time.sleep(0.1)
                if self._q.empty():
                    self._fail(f"the download worker ended unexpectedly (exit code "
                               f"{self._proc.exitcode}); the partial copy is kept")
        return self.phase, self.done, self.total

    def _fail(self, reason: str) -> None:
        self.cancel()
        self.result = DownloadResult(ok=False, reason=reason, bytes=self.done,
                                     cwa_part=f"{self.job.out_dir}/{self.job.stem}.cwa.part")

    def cancel(self, grace_s: float = 2.0) -> None:
        """Stop the download within ``grace_s`` (+ a kill)."""
        self._cancel.set()
        if self._proc is not None and self._proc.is_alive():
            self._proc.terminate()
            self._proc.join(grace_s)
            if self._proc.is_alive():
                self._proc.kill()
                self._proc.join(1.0)

    def _reap(self) -> None:
        if self._proc is not None:
            self._proc.join(5.0)

    def wait(self, poll_s: float = 0.1) -> DownloadResult:
        while self.result is None:
            self.poll(poll_s)
        return self.result
