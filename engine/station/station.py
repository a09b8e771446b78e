"""The station: watch for devices, run each through its states in parallel, show a table.

``Station(options, backend=None)``: ``run(once=False, stop=None)`` polls discovery every
``poll_s``; a device that appears gets a ``DeviceFlow`` on its own thread (downloads run in their
own worker processes); a device that leaves is marked ``detached`` and, when it comes back, runs
again (an interrupted download resumes). ``once=True`` handles the devices attached at start and
returns when they are all in a final state (a device another station of the computer holds waits
in ``busy`` until it is free: ``hostlock``). The ledger lock refuses a second station on the same
folder. At start the ledger rows a killed station left between two states are resolved
(``completion.reconcile``). ``render`` draws the live table (TTY) or prints one plain line per
state change. The table's lines are cut to the terminal's width (``$COLUMNS``, else the
terminal's), so a redraw never wraps. ``add_listener(fn)`` calls ``fn(flow)`` on every state change and progress update
of any device, and once more when a device's flow has ended (``flow.finished`` set) (from the flow's thread: a listener must be quick and never raise), for a view of the
station other than the terminal's. ``rerun(serial, **option_changes)`` runs an attached device's
ended flow again (a retry; a clear or configure asked for later: the same flow, the same rules).
"""

from __future__ import annotations

import sys
import threading
import time
from typing import Optional

from stillpoint.drivers.ax.discovery import discover

from .flow import DeviceFlow, StationOptions
from .ledger import Ledger, acquire_station_lock, check_station_folder


def _bar(done: int, total: int, width: int = 20) -> str:
    if not total:
        return " " * (width + 2)
    k = int(width * min(1.0, done / total))
    return "[" + "#" * k + "." * (width - k) + "]"


def terminal_columns(out) -> int:
    """The width the table is cut to: ``$COLUMNS``, else the terminal ``out`` writes to, else
    the terminal of this process, else 80."""
    import os
    import shutil
    env = os.environ.get("COLUMNS", "")
    if env.isdigit() and int(env) > 0:
        return int(env)
    try:
        return os.get_terminal_size(out.fileno()).columns
    except (AttributeError, OSError, ValueError):
        return shutil.get_terminal_size((80, 24)).columns


def fit(line: str, columns: int) -> str:
    """``line`` cut to ``columns - 1`` characters (a line that fills the last column wraps on
    some terminals, which breaks the redraw)."""
    width = max(1, columns - 1)
    return line if len(line) <= width else line[: width - 1] + ">"


def table_lines(flows, columns: Optional[int] = None) -> list[str]:
    """The live table, one line per device (each cut to ``columns`` when given)."""
    head = f"{'slot':<10} {'device':>8} {'type':<4} {'state':<12} {'progress':<22} {'MB/s':>6}  detail"
    out = [head]
    for f in flows:
        mbps = f"{f.mbps:6.2f}" if f.mbps else "     -"
        detail = (f.reason if f.state == "error" else (f.reason or f.info)) or ""
        outputs = getattr(f, "outputs", None)
        detail += f"; outputs: {outputs}" if outputs else ""
        detail += " (detached)" if f.detached else ""
        out.append(f"{f.att.slot[:10]:<10} {f.att.device_id:>8} {f.att.device_type:<4} {f.state:<12} "
                   f"{_bar(f.done_bytes, f.total_bytes)} {mbps}  {detail or ''}")
    return [fit(line, columns) for line in out] if columns else out


class Station:
    def __init__(self, options: StationOptions, backend=None, *, poll_s: float = 0.5,
                 out=None, tty: Optional[bool] = None, inbox=None):
        folder = check_station_folder(options.out_dir)
        self._lock_fd = acquire_station_lock(folder)
        self.opts = options
        self.backend = backend
        self.poll_s = poll_s
        self.ledger = Ledger(folder)
        from .completion import reconcile  # what a killed station left between two states
        self.reconciled = reconcile(self.ledger)
        self.flows: dict[str, DeviceFlow] = {}
        self.detached: set[str] = set()
        self.out = out or sys.stdout
        self.tty = self.out.isatty() if tty is None else tty
        for line in self.reconciled:
            print(f"ledger: {line}", file=self.out, flush=True)
        self.inbox = inbox
        self._printed: dict[str, tuple] = {}
        self._drawn = 0
        self._lock = threading.Lock()
        self._pending = None  # a discovery pass still running (see _discover)
        self._listeners: list = []

    def add_listener(self, fn) -> None:
        """Call ``fn(flow)`` on every state change and progress update of any device, and once
        more when its flow (the tables and report included) has ended."""
        self._listeners.append(fn)

    def rerun(self, serial: str, **option_changes) -> DeviceFlow:
        """Run the ended flow of an attached device again, with ``option_changes`` to its
        ``StationOptions``; ``ValueError`` (the reason) for a device unknown, detached or busy."""
        import dataclasses
        with self._lock:
            f = self.flows.get(serial)
            if f is None or serial in self.detached:
                raise ValueError("the device is not attached to this station")
            if not f.finished.is_set():
                raise ValueError(f"the device is busy ({f.state})")
            opts = dataclasses.replace(self.opts, **option_changes) if option_changes else self.opts
            f = DeviceFlow(f.att, opts, self.ledger, self.backend, on_change=self._changed)
            self.flows[serial] = f
        f.start()
        return f

    def close(self) -> None:
        import os
        for f in self.flows.values():
            f.stop()
        for f in self.flows.values():
            f.finished.wait(5.0)
        self.ledger.close()
        if self._lock_fd is not None:
            os.close(self._lock_fd)
            self._lock_fd = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # ------------------------------------------------------------------ output
    def _changed(self, flow: DeviceFlow) -> None:
        for fn in list(self._listeners):
            try:
                fn(flow)
            except Exception as e:  # noqa: BLE001 - a view's fault never stops a device's flow
                print(f"station view failed: {type(e).__name__}: {e}", file=sys.stderr)
        if self.tty:
            return
        key = (flow.state, flow.reason, flow.detached)
        outputs = getattr(flow, "outputs", None)
        head = f"{time.strftime('%H:%M:%S')} {flow.att.device_type} {flow.att.device_id} [{flow.att.slot}]"
        with self._lock:
            if self._printed.get(flow.att.serial) != key:
                self._printed[flow.att.serial] = key
                detail = (flow.reason or flow.info) + (" (detached)" if flow.detached else "")
                print(f"{head} {flow.state}" + (f": {detail}" if detail else ""),
                      file=self.out, flush=True)
            if outputs and self._printed.get(("outputs", flow.att.serial)) != outputs:
                self._printed[("outputs", flow.att.serial)] = outputs
                print(f"{head} outputs: {outputs}", file=self.out, flush=True)

    def render(self) -> None:
        if not self.tty:
            return
        columns = terminal_columns(self.out)
        lines = table_lines(self.flows.values(), columns)
        if self.inbox is not None:
            lines += [fit(line, columns) for line in self.inbox.lines()]
        buf = ("\x1b[%dA" % self._drawn if self._drawn else "") + "".join(
            "\x1b[2K" + line + "\n" for line in lines)
        self.out.write(buf)
        self.out.flush()
        self._drawn = len(lines)

    # ------------------------------------------------------------------ loop
    def _discover(self, bound_s: float = 5.0):
        """Discovery on its own thread with a bound: a stat on a drive that was just pulled can
        block in the kernel, and the station loop must never wait on it. None: no answer yet."""
        if self._pending is None:
            box: dict = {}

            def run():
                try:
                    box["result"] = discover(self.backend)
                except Exception as e:  # noqa: BLE001 - reported below, never kills the loop
                    box["error"] = e
            t = threading.Thread(target=run, daemon=True, name="discovery")
            t.start()
            self._pending = (t, box)
        t, box = self._pending
        t.join(bound_s)
        if t.is_alive():
            return None  # still blocked: try again next pass, meanwhile the flows carry on
        self._pending = None
        if "error" in box:
            print(f"discovery failed: {box['error']}", file=sys.stderr)
            return []
        return box["result"]

    def step(self) -> list:
        """One discovery pass: start flows for new devices, mark the ones that left."""
        attached = self._discover()
        if attached is None:
            return []
        seen = set()
        for a in attached:
            seen.add(a.serial)
            f = self.flows.get(a.serial)
            if f is None or (a.serial in self.detached and f.finished.is_set()):
                self.detached.discard(a.serial)
                f = DeviceFlow(a, self.opts, self.ledger, self.backend, on_change=self._changed)
                self.flows[a.serial] = f
                f.start()
        for serial, f in self.flows.items():
            if serial not in seen and serial not in self.detached:
                if f.finished.is_set():
                    self.detached.add(serial)
                    f.detached = True
                    self._changed(f)
                # a flow still running notices the unplug itself (the port or the drive fails)
        if self.inbox is not None:
            self.inbox.step()
        return attached

    def run(self, once: bool = False, stop: Optional[threading.Event] = None) -> int:
        """Run until ``stop`` is set (or, ``once``, until the devices present are done).
        Returns 2 if any device ended in ``error``, else 0."""
        stop = stop or threading.Event()
        try:
            self.step()
            while not stop.is_set():
                self.render()
                if once and all(f.finished.is_set() for f in self.flows.values()) and \
                        (self.inbox is None or self.inbox.idle()):
                    break
                stop.wait(self.poll_s)
                if not once:
                    self.step()
                elif self.inbox is not None:
                    self.inbox.step()
            self.render()
        finally:
            for f in self.flows.values():
                if not f.finished.is_set():
                    f.stop()
        errors = [f for f in self.flows.values() if f.state == "error"]
        if self.inbox is not None and self.inbox.errors:
            return 2
        return 2 if errors else 0
