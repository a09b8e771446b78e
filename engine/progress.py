"""Progress of a long command: percentage done and time left, from the size of its input.

One ``Progress`` per command run, written to stderr:

* on a terminal, one line redrawn in place (at most every 0.2 s):
  ``process: [#########.....................]  31.0 %  elapsed 0m09s  ETA 0m20s  pass 1/2``;
* otherwise (a log file, a pipe), a plain line each time another tenth of the work is done or
  30 s have passed since the last line, and a closing line with the total time;
* nothing at all when ``quiet``.

The work is measured in any unit whose total is known at the start (bytes of input for files
and cohorts, samples for the simulator); a command with several passes over its input gives
each pass a share of the whole (``phase``). The time left is the elapsed time scaled by the
share still to do. The clock is injectable so tests need no waiting.
"""

from __future__ import annotations

import sys
import time
from typing import Callable, Optional


# A batch run's two passes over its input as shares of the whole: the first (features only) is
# a fifth of the time of the second (correct and write); a week's AX3 file: ~1 s and ~8 s.
BATCH_PASS_SPANS = {"pass 1/2": (0.0, 0.2), "pass 2/2": (0.2, 1.0)}


def run_fraction(label: str, fraction: float) -> float:
    """The share of a whole ``process_file`` run done, from its progress label ("pass 1/2",
    "pass 2/2", "online") and the fraction of that pass's input read."""
    lo, hi = BATCH_PASS_SPANS.get(label, (0.0, 1.0))
    return lo + (hi - lo) * min(max(float(fraction), 0.0), 1.0)


def hms(s: float) -> str:
    """Seconds as ``1h02m`` (an hour or more) or ``2m05s``."""
    s = int(max(0, round(s)))
    return f"{s // 3600}h{s // 60 % 60:02d}m" if s >= 3600 else f"{s // 60}m{s % 60:02d}s"


class Progress:
    """Percentage and ETA of one command on ``stream`` (default stderr); see the module doc."""

    BAR = 30

    def __init__(self, label: str, total: Optional[float] = None, *, stream=None,
                 tty: Optional[bool] = None, quiet: bool = False,
                 clock: Callable[[], float] = time.monotonic, redraw_s: float = 0.2,
                 every_fraction: float = 0.1, every_s: float = 30.0):
        self.label = label
        self.total = total
        self.stream = sys.stderr if stream is None else stream
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)()) if tty is None else tty
        self.quiet = quiet
        self.clock = clock
        self.redraw_s, self.every_fraction, self.every_s = redraw_s, every_fraction, every_s
        self.t0 = clock()
        self.fraction = 0.0
        self.detail = ""
        self._span = (0.0, 1.0)  # the share of the whole that the current pass covers
        self._last_draw = -1e18
        self._last_line_t = self.t0
        self._last_step = 0  # tenths (every_fraction steps) already reported
        self._drawn = False
        self._closed = False

    # ------------------------------------------------------------------ feeding it
    def phase(self, index: int, count: int) -> None:
        """The work that follows is pass ``index`` (0-based) of ``count`` equal passes."""
        n = max(1, int(count))
        self.span(index / n, (index + 1) / n)

    def span(self, lo: float, hi: float) -> None:
        """The work that follows covers the share ``lo``..``hi`` of the whole (passes of
        unequal cost: a batch run's feature pass is a fraction of its writing pass)."""
        self._span = (float(lo), float(hi))

    def update(self, done: Optional[float] = None, *, fraction: Optional[float] = None,
               total: Optional[float] = None, detail: Optional[str] = None) -> None:
        """``done`` units of ``total`` (or ``fraction`` of the current pass) are done."""
        if total is not None:
            self.total = total
        if fraction is None and done is not None and self.total:
            fraction = done / self.total
        if detail is not None:
            self.detail = detail
        if fraction is not None:
            lo, hi = self._span
            f = lo + (hi - lo) * min(max(float(fraction), 0.0), 1.0)
            self.fraction = max(self.fraction, min(f, 1.0))
        self._show()

    # ------------------------------------------------------------------ output
    def eta_s(self) -> Optional[float]:
        """Seconds left, or None before any work is measured."""
        el = self.clock() - self.t0
        if self.fraction <= 0.0 or el <= 0:
            return None
        return el * (1.0 - self.fraction) / self.fraction

    def line(self) -> str:
        el = self.clock() - self.t0
        eta = self.eta_s()
        text = (f"{self.label}: {100 * self.fraction:5.1f} %  elapsed {hms(el)}  "
                f"ETA {'?' if eta is None else hms(eta)}")
        return text + (f"  {self.detail}" if self.detail else "")

    def _show(self) -> None:
        if self.quiet or self._closed:
            return
        now = self.clock()
        if self.tty:
            if now - self._last_draw < self.redraw_s:
                return
            self._last_draw = now
            k = int(self.BAR * self.fraction)
            text = self.line()
            head, _, tail = text.partition(": ")
            self.stream.write(f"\r\033[K{head}: [{'#' * k}{'.' * (self.BAR - k)}] {tail}")
            self.stream.flush()
            self._drawn = True
            return
        k = int(self.fraction / self.every_fraction + 1e-9)  # tenths reached
        if k > self._last_step or now - self._last_line_t >= self.every_s:
            self._last_line_t = now
            self._last_step = max(k, self._last_step)
            self.stream.write(self.line() + "\n")
            self.stream.flush()

    def message(self, text: str) -> None:
        """A line of its own (a warning, a failed file) that the bar does not overwrite."""
        if self.quiet:
            return
        self.stream.write(("\r\033[K" if self.tty and self._drawn else "") + text + "\n")
        self.stream.flush()
        self._drawn = False

    def close(self, *, completed: bool = True) -> None:
        """Clear the bar (terminal) or write the closing line (``completed``: 100 %)."""
        if self.quiet or self._closed:
            return
        self._closed = True
        if self.tty:
            if self._drawn:
                self.stream.write("\r\033[K")
                self.stream.flush()
            return
        if completed:
            self.fraction = 1.0
            self.stream.write(f"{self.label}: done in {hms(self.clock() - self.t0)}\n")
        self.stream.flush()

    def __enter__(self) -> "Progress":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close(completed=exc_type is None)


def file_size(path) -> Optional[int]:
    """Bytes of a file, or None (missing, not a file): the total for ``Progress``."""
    import os
    try:
        return os.path.getsize(path)
    except OSError:
        return None


class Reporting:
    """A Source whose iteration calls ``update(fraction=...)`` with the wrapped source's share
    read (``source.progress()``) after each block; everything else is the source's."""

    def __init__(self, source, update):
        self.source = source
        self.update = update

    def __getattr__(self, name):
        if name == "source":
            raise AttributeError(name)
        return getattr(self.source, name)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.source.close()

    def __iter__(self):
        probe = getattr(self.source, "progress", None)
        for block in self.source:
            yield block
            f = probe() if callable(probe) else None
            if f is not None:
                self.update(fraction=f)


class ByteSpans:
    """Files of known sizes worked through one after another on one ``Progress``: ``start(i)``
    points the bar at file i's share of the total bytes (``Progress.span``)."""

    def __init__(self, bar: Progress, paths):
        self.bar = bar
        sizes = [max(file_size(p) or 0, 1) for p in paths]
        total = float(sum(sizes))
        self.edges = [sum(sizes[:i]) / total for i in range(len(sizes) + 1)]

    def start(self, i: int) -> None:
        self.bar.span(self.edges[i], self.edges[i + 1])
        self.bar.update(fraction=0.0)

    def finish(self, i: int) -> None:
        self.bar.span(self.edges[i], self.edges[i + 1])
        self.bar.update(fraction=1.0)
