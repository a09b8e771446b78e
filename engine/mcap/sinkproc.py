"""The MCAP log of a batch run written by a child process, so the log's framing and
compression run on the second core while the engine corrects the next step.

``SinkProcess.start()`` starts a fresh child (``python -m stillpoint.engine.mcap.sinkproc``: a
new interpreter, never a fork of the engine, whose reader thread may be running); it imports
the sink while the engine's first pass runs. ``SinkProcess.open(path, info, settings, ...)``
then opens the log there: the child builds an ordinary ``McapSink`` (engine/mcap/sink.py) with
the arguments given and runs every call the engine makes on the returned ``RemoteSink``, one
after another in the order made. The same sink making the same calls in the same order writes
the same file, byte for byte, as a run on one core.

Transport: calls go through a pipe (pickled); the arrays of a pipeline step (Block, corrected
batches, epoch metrics, extras) go through a small ring of shared-memory slots
(engine/mcap/slots.py: ``SLOTS`` slots of ``SLOT_BYTES``), which the child copies out of at once.
At most ``SLOTS`` steps wait while one is framed: a parent that gets ahead waits for a free
slot, so memory stays flat. A lean log's sink writes neither raw nor corrected messages: the
engine sends it no Block and, of the corrected batches, only the view's samples
(``ViewDecimator.thin``, engine/mcap/view.py: a few kB a step instead of ~2.4 MB), from which it
writes the same bytes.

Faults, as on one core:

* a call that fails in the child (a full disk, a record that cannot be framed) is raised in
  the engine by its next call as the exception the sink raised there (same class, same one
  line); the calls after it are not run; the chunks written before are kept, and the sink's own
  failure handling leaves the ``.part`` file for ``stillpoint recover``;
* ``abort()`` (Ctrl-C, or a failure in the engine) drops the calls still waiting (a flag in
  the shared memory, read before each call), lets the call being run finish, aborts the sink
  (the ``.part`` file stays) and waits for the child to end; the child ignores SIGINT (the
  terminal sends it to the whole process group: the engine decides what it means);
* a child that dies (killed) is one ``OutputError`` line naming the log and the partial file;
* the engine dying closes the pipe: the child aborts the sink and ends (the ``.part`` stays).
The slots have no name in /dev/shm (an anonymous memory file): nothing is left behind.

Beside the sink, the child may run objects that write next to the log and into it (the
tables' epoch-level half, engine/run/taps.py): ``RemoteSink.attach`` builds one there, given the
child's sink, and its calls (``RemoteObject``) run in order with the sink's. Their faults are
the sink's (raised at the engine's next call, the calls after it not run), and aborting the log
(or the engine going away) aborts them too (their ``abort()``).
"""

from __future__ import annotations

import os
import pickle
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any, Optional

from ..core.jsonsafe import dumps
from ..core.outputs import OutputError
from . import slots
from .log import recover_hint
from .sink import McapSink
from .view import ViewDecimator

# A step's arrays at 100 Hz are ~3.3 MB (Block ~0.9 MB, corrected batches ~2.4 MB; a lean
# log's: its epochs and view samples, a few kB); a call whose arrays do not fit a slot is
# pickled through the pipe instead (same result, slower).
SLOT_BYTES = 8 << 20
# steps waiting for the child while it frames one: 4 rather than 2 lets the engine run on
# through the steps where the child is slower (a chunk's compression, the tables' work) and
# the child through the engine's slower ones; a week's full log, 7 days 100 Hz, three
# alternating rounds: 15.24-17.75 s wall with 2 slots against 13.73-15.19 s with 4, the same
# bytes; 32 MB of shared memory (16 MB with 2), +5-7 MB peak RSS measured
SLOTS = 4
ENV = "STILLPOINT_SINK_PROCESS"  # "0": never write the log in a child process (comparisons)
_WAIT_S = 30.0  # how long stop() waits for the child to end before killing it

# the calls the engine makes that the child runs (McapSink's methods of those names)
CALLS = frozenset({"write_slices", "write_extras", "write", "write_metadata", "flush"})
ATTACH = "attach"  # build an object beside the sink (``RemoteSink.attach``)
OBJECT = "object"  # a call of an attached object (``RemoteObject``)


def enabled() -> bool:
    """Whether the child process may be used ($STILLPOINT_SINK_PROCESS is not "0", and the
    platform has anonymous shared memory)."""
    return os.environ.get(ENV, "").strip() != "0" and slots.available()


def _error_state(e: BaseException) -> tuple:
    """An exception as plain data (many of ours cannot be unpickled from their args alone; an
    OSError's errno, strerror and file names are not in its args' place once raised)."""
    d = {}
    for k, v in getattr(e, "__dict__", {}).items():
        try:
            pickle.dumps(v)
            d[k] = v
        except Exception:
            pass
    os_fields = {k: getattr(e, k) for k in _OS_FIELDS if getattr(e, k) is not None} \
        if isinstance(e, OSError) else {}
    return (type(e).__module__, type(e).__qualname__, e.args, d, f"{type(e).__name__}: {e}",
            os_fields)


_OS_FIELDS = ("errno", "strerror", "filename", "filename2")


def _rebuild(state: tuple) -> BaseException:
    """The exception ``_error_state`` described (same class, args and attributes), or a
    RuntimeError with its text when the class cannot be found here."""
    mod, qual, args, d, text, os_fields = state
    try:
        import importlib
        cls: Any = importlib.import_module(mod)
        for part in qual.split("."):
            cls = getattr(cls, part)
        e = cls.__new__(cls)
        e.args = args
        e.__dict__.update(d)
        for k, v in os_fields.items():
            setattr(e, k, v)
        return e
    except Exception:
        return RuntimeError(text)


class SinkProcess:
    """A child process ready to write one log (see the module docstring)."""

    def __init__(self):
        from multiprocessing.connection import Connection
        self.ring = slots.SlotRing(SLOTS, SLOT_BYTES)
        try:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "stillpoint.engine.mcap.sinkproc", str(self.ring.fd),
                 str(SLOTS), str(SLOT_BYTES)],
                stdin=subprocess.PIPE, stdout=subprocess.PIPE, close_fds=True,
                pass_fds=(self.ring.fd,))
        except BaseException:
            self.ring.close()
            raise
        self._w = Connection(os.dup(self.proc.stdin.fileno()), readable=False)
        self._r = Connection(os.dup(self.proc.stdout.fileno()), writable=False)
        self.proc.stdin.close()
        self.proc.stdout.close()

    @classmethod
    def start(cls) -> "SinkProcess":
        return cls()

    def preload(self, modules) -> None:
        """Have the child import ``modules`` (names) while it waits for its log: what objects
        attached later will need (``RemoteSink.attach``) is then imported off the run's path.
        A module that cannot be imported there is left to fail where it is used."""
        try:
            self.send(("preload", list(modules)))
        except OSError:  # the child is gone: opening the log says so
            pass

    def open(self, path, info, settings: dict, **kwargs) -> "RemoteSink":
        """Open the log ``McapSink(path, info, settings, **kwargs)`` in the child; raises what
        opening it raised there (the child then ends)."""
        return RemoteSink(self, path, info, settings, kwargs)

    def send(self, msg) -> None:
        self._w.send(msg)

    def recv(self):
        return self._r.recv()

    def poll(self) -> bool:
        return self._r.poll()

    def stop(self) -> None:
        """End the child (closing its pipe: a log not finished is aborted there) and release
        the shared memory. Idempotent; waits at most ``_WAIT_S`` before killing it."""
        if self.proc is None:
            return
        for c in (self._w, self._r):
            try:
                c.close()
            except OSError:
                pass
        try:
            self.proc.wait(timeout=_WAIT_S)
        except BaseException:  # a timeout, or an interrupt while waiting: no orphan either way
            self.proc.kill()
            self.proc.wait()
        finally:
            self.proc = None
            self.ring.close()

    @property
    def returncode(self) -> Optional[int]:
        return None if self.proc is None else self.proc.poll()


class RemoteSink:
    """``McapSink``'s interface for the engine, its calls run by the child (module docstring).

    After ``close()``: ``messages``, ``flushes`` and ``writer_maxrss_mb`` (the child's peak
    RSS) are the child sink's."""

    def __init__(self, child: SinkProcess, path, info, settings: dict, kwargs: dict):
        self._child = child
        self.path = Path(path)
        self.messages = 0
        self.flushes = 0
        self.writer_maxrss_mb: Optional[float] = None
        from ..settings import is_lean
        self.lean = is_lean(settings)  # the sink writes no raw message: the block is not sent
        # nor a corrected one: of the corrected batches only the view's samples are sent
        # (ViewDecimator.thin; none when the view is off: then nothing is taken from them)
        view_hz = kwargs.get("view_hz") or 0.0
        self._view = ViewDecimator(view_hz) if self.lean and view_hz else None
        self._error: Optional[BaseException] = None
        self._kept: Optional[Path] = None
        self._done = False
        try:
            child.send(("open", str(path), info, settings, kwargs))
            msg = self._answer()
        except BaseException:
            child.stop()
            raise
        if msg[0] == "error":
            child.stop()
            raise _rebuild(msg[1])
        self.part, self.set_aside = msg[1], msg[2]

    # ------------------------------------------------------------------ plumbing
    def _died(self) -> OutputError:
        rc = self._child.returncode
        how = f"exit code {rc}" if rc is not None and rc >= 0 else \
            f"signal {-rc}" if rc is not None else "its pipe closed"
        kept = self.part if self.part.exists() else None
        hint = f"; {recover_hint(kept)}" if kept else ""
        return OutputError(self.path, f"writing failed: the log's writer process ended ({how}){hint}")

    def _reply(self):
        """The child's next message (a freed slot or an error noted here); a dead child is an
        error."""
        try:
            msg = self._child.recv()
        except (EOFError, OSError):
            try:
                self._child.proc.wait(timeout=_WAIT_S)
            except Exception:
                pass
            self._done = True
            raise self._died() from None
        if msg[0] == "free":
            self._child.ring.free.append(msg[1])
        elif msg[0] == "error" and self._error is None and msg[1] is not None:
            self._error = _rebuild(msg[1])
        return msg

    def _answer(self):
        """The child's next message that is not a freed slot."""
        while True:
            msg = self._reply()
            if msg[0] != "free":
                return msg

    def _check(self) -> None:
        """Take the child's replies so far; raise the first error a call raised there."""
        if self._error is None and not self._done:
            while self._child.poll():
                msg = self._reply()
                if msg[0] == "error":
                    break
        if self._error is not None:
            raise self._error
        if self._done:
            raise self._died()

    def _call(self, name: str, *args) -> None:
        """Hand one call to the child (its arrays through a slot when they fit)."""
        self._check()
        ring = self._child.ring
        head, sizes = ring.pack((name, args))
        slot = -1
        if not sizes:
            pass
        elif ring.fits(sizes):
            while not ring.free:  # wait for the child to take a step out of the ring
                if self._reply()[0] == "error":
                    raise self._error
            slot = ring.free.pop()
            ring.fill(slot, sizes)
        else:
            head, sizes = pickle.dumps((name, args), protocol=5), []
        try:
            self._child.send(("call", head, slot, sizes))
        except (BrokenPipeError, OSError):
            if slot >= 0:
                ring.free.append(slot)
            self._check()
            self._done = True
            raise self._died() from None

    # ------------------------------------------------------------------ the sink's calls
    def write_slices(self, block, corrected: list, epochs) -> None:
        if self.lean:
            block, corrected = None, self._view.thin(corrected) if self._view is not None else []
        self._call("write_slices", block, corrected, epochs)

    def write_extras(self, extras: dict) -> None:
        self._call("write_extras", extras)

    def write(self, topic: str, encoding: str, schema, log_time: int, data: bytes) -> None:
        self._call("write", topic, encoding, schema, log_time, bytes(data))

    def write_metadata(self, name: str, values: dict) -> None:
        self._call("write_metadata", name,
                   {k: (v if isinstance(v, str) else dumps(v)) for k, v in values.items()})

    def flush(self, fsync: bool = True) -> None:
        self._call("flush", fsync)

    # ------------------------------------------------------------------ objects beside the sink
    def attach(self, key: str, factory, *args, **kwargs) -> "RemoteObject":
        """Build ``factory(*args, sink=<the child's sink>, **kwargs)`` in the child (``factory``
        importable there by name); returns the handle whose calls run it (module docstring)."""
        self._piped(ATTACH, key, factory, args, kwargs)
        return RemoteObject(self, key)

    def _piped(self, name: str, *args) -> None:
        """Hand one call to the child through the pipe (small arguments: no slot is taken from
        the steps' arrays)."""
        self._check()
        try:
            self._child.send(("call", pickle.dumps((name, args), protocol=5), -1, []))
        except (BrokenPipeError, OSError):
            self._check()
            self._done = True
            raise self._died() from None

    # encoded here as the sink encodes them (JSON text, CDR bytes), then handed over by write()
    write_cdr = McapSink.write_cdr
    write_json = McapSink.write_json
    write_qc = McapSink.write_qc
    write_outcome = McapSink.write_outcome

    def close(self) -> Path:
        """Finish the log in the child (summary, index, footer, rename) and end the child."""
        self._check()
        try:
            self._child.send(("close",))
        except (BrokenPipeError, OSError):
            self._done = True
            raise self._died() from None
        msg = self._answer()
        if msg[0] == "error":
            raise self._error  # the child keeps the sink (aborted) until abort() or stop()
        _tag, path, self.messages, self.flushes, self.writer_maxrss_mb = msg
        self._done = True
        self._child.stop()
        return Path(path)

    def abort(self) -> Optional[Path]:
        """Stop without finishing: the calls still waiting are dropped, the one running ends,
        the sink is aborted in the child (the ``.part`` file stays) and the child ends. Returns
        the partial file kept (None if there is none)."""
        child = self._child
        if child.proc is None:
            return self._kept
        try:
            if not self._done:
                child.ring.stop()
                try:
                    child.send(("abort",))
                    while True:
                        msg = self._answer()
                        if msg[0] == "aborted":
                            self._kept = Path(msg[1]) if msg[1] else None
                            break
                except (OutputError, BrokenPipeError, OSError):  # the child is gone
                    self._kept = self.part if self.part.exists() else None
            elif self.part.exists():
                self._kept = self.part
        finally:
            self._done = True
            child.stop()
        return self._kept


class RemoteObject:
    """An object built in the child by ``RemoteSink.attach``: ``call`` runs one of its methods
    there in order with the log's calls; ``ask`` also waits for what it returns."""

    def __init__(self, sink: RemoteSink, key: str):
        self._sink = sink
        self.key = key

    def call(self, method: str, *args) -> None:
        self._sink._piped(OBJECT, self.key, method, args, False)

    def ask(self, method: str, *args):
        """Run ``method(*args)`` in the child and return its result; raises what it raised
        there (or an earlier call's failure)."""
        sink = self._sink
        sink._piped(OBJECT, self.key, method, args, True)
        msg = sink._answer()
        if msg[0] == "error":
            raise sink._error
        return msg[1]


# ---------------------------------------------------------------------------- the child
def _serve(rconn, wconn, ring: slots.SlotRing) -> None:
    """Run the engine's calls on one McapSink until the log is closed or aborted; if the
    engine goes away (its pipe closed), abort the log: the ``.part`` file stays."""
    from ..core.malloc import tune_for_blocks
    tune_for_blocks()  # each step's unpickled arrays stay on the heap (engine/run/batch.py)
    box: list = []
    attached: dict = {}
    try:
        _serve_calls(rconn, wconn, ring, box, attached)
    except (EOFError, OSError):  # the engine is gone (a closed pipe either way)
        _abort_attached(attached)
        if box:
            box[0].abort()


def _abort_attached(attached: dict) -> None:
    """Abort the objects built beside the sink (a finished one ignores it)."""
    for obj in attached.values():
        try:
            obj.abort()
        except Exception:
            pass
    attached.clear()


def _serve_calls(rconn, wconn, ring: slots.SlotRing, box: list, attached: dict) -> None:
    sink: Optional[McapSink] = None
    failed = False

    def fail(e: BaseException) -> None:
        nonlocal failed
        failed = True
        wconn.send(("error", _error_state(e)))

    while True:
        msg = rconn.recv()
        op = msg[0]
        if op == "call":
            _op, head, slot, sizes = msg
            if slot >= 0:
                if failed or ring.stopping:  # dropped: give the slot back
                    wconn.send(("free", slot))
                    continue
                name, args = ring.unpack(slot, head, sizes)
                wconn.send(("free", slot))
            else:
                if failed or ring.stopping:
                    continue
                name, args = pickle.loads(head)
            try:
                if name in CALLS:
                    getattr(sink, name)(*args)
                elif name == OBJECT:
                    key, method, margs, reply = args
                    result = getattr(attached[key], method)(*margs)
                    if reply:
                        wconn.send(("result", result))
                elif name == ATTACH:
                    key, factory, fargs, kwargs = args
                    attached[key] = factory(*fargs, sink=sink, **kwargs)
                else:
                    raise ValueError(f"not a sink call: {name}")
            except BaseException as e:
                fail(e)
        elif op == "preload":
            import importlib
            for name in msg[1]:
                try:
                    importlib.import_module(name)
                except Exception:
                    pass
        elif op == "open":
            _op, path, info, settings, kwargs = msg
            try:
                sink = McapSink(path, info, settings, **kwargs)
                box.append(sink)
            except BaseException as e:
                wconn.send(("error", _error_state(e)))
                return
            wconn.send(("opened", sink.part, sink.set_aside))
        elif op == "close":
            if failed:
                wconn.send(("error", None))
                continue
            try:
                path = sink.close()
            except BaseException as e:
                fail(e)
                continue
            _abort_attached(attached)  # closed before the log, unless the engine did not
            from .writer import peak_rss_mb
            wconn.send(("closed", str(path), sink.messages, sink.flushes, peak_rss_mb()))
            return
        elif op == "abort":
            _abort_attached(attached)
            kept = sink.abort() if sink is not None else None
            wconn.send(("aborted", str(kept) if kept is not None else None))
            return


def _main() -> None:
    from multiprocessing.connection import Connection
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the engine decides what an interrupt means
    rconn = Connection(os.dup(0), writable=False)
    wconn = Connection(os.dup(1), readable=False)
    os.dup2(2, 1)  # stray output must not corrupt the reply channel
    fd, count, size = (int(a) for a in sys.argv[1:4])
    ring = slots.SlotRing(count, size, fd=fd)
    try:
        _serve(rconn, wconn, ring)
    finally:
        ring.close()


if __name__ == "__main__":
    _main()
