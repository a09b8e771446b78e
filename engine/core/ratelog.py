"""The log path of every server (the dashboard, the live views): rate-limited, summarised and
never blocking the thread that logs.

``install(name)`` gives the logger ``name`` one ``BoundedLogHandler`` (once per process, however
many servers start): a line is formatted on the logging thread and put in a bounded queue that a
daemon thread writes to stderr, so a server thread never waits for a pipe nobody reads (a full
queue drops the line and counts it). At most ``burst`` lines of one kind (the logger and its
message template) are written per ``window_s``; the rest are counted and written as one summary
line when the window ends ("... 1,234 more like this in the last 60 s"); digits do not make a
kind (a message naming a client's address and port is one kind whoever sends it), and at most
``total`` lines of every kind together are written per window. Records still propagate
to the root logger's handlers (none unless an application or a test adds one), so nothing is
written twice.
"""

from __future__ import annotations

import logging
import queue
import re
import sys
import threading
import time
from typing import Callable, Optional, TextIO

BURST = 5  # lines of one kind per window
TOTAL = 50  # lines of every kind together per window
KINDS = 256  # kinds counted apart per window; the rest are counted together
WINDOW_S = 60.0
QUEUE_LINES = 256  # lines waiting for the writer; more are dropped (and counted)
_DIGITS = re.compile(r"\d+")


class BoundedLogHandler(logging.Handler):
    """See the module docstring. ``stream``: where lines go (default: ``sys.stderr`` at write
    time); ``clock``: monotonic seconds (tests)."""

    def __init__(self, stream: Optional[TextIO] = None, *, burst: int = BURST, total: int = TOTAL,
                 window_s: float = WINDOW_S, queue_lines: int = QUEUE_LINES,
                 clock: Callable[[], float] = time.monotonic):
        super().__init__()
        self.stream = stream
        self.burst, self.total, self.window_s, self.clock = burst, total, window_s, clock
        self._window = [clock(), 0]  # start of the window of ``total``, lines written in it
        self.setFormatter(logging.Formatter("%(name)s: %(message)s"))
        self._q: queue.Queue = queue.Queue(maxsize=queue_lines)
        self._kinds: dict = {}  # (logger, template) -> [window start, written, suppressed, example]
        self._lock2 = threading.Lock()
        self.dropped = 0  # lines the full queue could not take (summarised when it has room)
        self.suppressed = 0  # lines over the rate, in total
        self._writer = threading.Thread(target=self._write_loop, name="log-writer", daemon=True)
        self._writer.start()

    # ------------------------------------------------------------------ the logging thread
    def emit(self, record: logging.LogRecord) -> None:
        """Queue the record's line, or count it when its kind or the window is over the rate."""
        try:
            key = (record.name, _DIGITS.sub("#", str(record.msg))[:200])
            now = self.clock()
            with self._lock2:
                lines = self._roll(now)
                if key not in self._kinds and len(self._kinds) >= KINDS:
                    key = (record.name, "(other messages)")
                k = self._kinds.setdefault(key, [now, 0, 0, record.name])
                if k[1] < self.burst and self._window[1] < self.total:
                    k[1] += 1
                    self._window[1] += 1
                    lines.append(self.format(record))
                else:
                    k[2] += 1
                    self.suppressed += 1
            for line in lines:
                self._put(line)
        except Exception:  # noqa: BLE001 - logging never raises into a server
            self.handleError(record)

    def _roll(self, now: float) -> list:
        """Summary lines of the kinds whose window ended (their counters restart)."""
        out = []
        if now - self._window[0] >= self.window_s:
            self._window = [now if now != float("inf") else self.clock(), 0]
        for key, k in list(self._kinds.items()):
            if now - k[0] >= self.window_s:
                if k[2]:
                    out.append(f"{k[3]}: {k[2]:,} more like \"{key[1][:120]}\" in the last "
                               f"{self.window_s:g} s")
                del self._kinds[key]
        if self.dropped:
            out.append(f"stillpoint: {self.dropped:,} log line(s) dropped (stderr not read)")
            self.dropped = 0
        return out

    def _put(self, line: str) -> None:
        try:
            self._q.put_nowait(line)
        except queue.Full:
            with self._lock2:
                self.dropped += 1

    def flush_summaries(self) -> None:
        """Write the summaries of every window now (at the end of a server's life)."""
        with self._lock2:
            lines = self._roll(float("inf"))
        for line in lines:
            self._put(line)

    # ------------------------------------------------------------------ the writer thread
    def _write_loop(self) -> None:
        while True:
            try:
                line = self._q.get(timeout=self.window_s)
            except queue.Empty:
                with self._lock2:
                    lines = self._roll(self.clock())
                for ln in lines:
                    self._put(ln)
                continue
            try:
                s = self.stream or sys.stderr
                s.write(line + "\n")
                s.flush()
            except (OSError, ValueError):
                pass

    def drain(self, timeout: float = 5.0) -> None:
        """Wait (at most ``timeout``) until every queued line is written (tests, shutdown)."""
        end = time.monotonic() + timeout
        while not self._q.empty() and time.monotonic() < end:
            time.sleep(0.01)


_installed: dict = {}
_install_lock = threading.Lock()


def install(name: str, **kw) -> BoundedLogHandler:
    """The logger ``name``'s ``BoundedLogHandler`` (made and attached on the first call)."""
    with _install_lock:
        h = _installed.get(name)
        if h is None:
            h = _installed[name] = BoundedLogHandler(**kw)
            logger = logging.getLogger(name)
            logger.addHandler(h)
            if logger.level == logging.NOTSET:
                logger.setLevel(logging.WARNING)  # what stderr showed before (lastResort)
        return h
