"""The simulator's true motion rendered ahead in a child process.

``DeviceSim.chunks()`` renders chunk k+1's motion (``DeviceSim._render``: sample times, true
force, white-noise draws) while chunk k is measured and written. On a thread the two halves
contend for the interpreter lock: a week at 100 Hz took 8.2 s of wall time for 4.6 s of
rendering and ~3.9 s of measuring and writing, each alone. A child process has a lock of its own.

``rendered(sim)`` yields ``(k, sim._render(k))`` for every chunk in order, the same values bit for
bit (``_render`` is a pure function of the device and k; the chunk's generator travels pickled,
its state exact). The child (``python -c`` with the parent's import path: no ``multiprocessing``
start-up, so a caller's script is never imported again) gets the pickled device on its stdin
and writes each chunk's arrays into one of ``SLOTS`` slots of a shared file mapping
(``/dev/shm`` where there is one), announcing it with a small pickle on its stdout; the parent
copies the arrays out and frees the slot. While the child starts, the parent renders the
first chunks itself; the child takes over from the chunk the parent names.

Whatever goes wrong with the child (it cannot start, dies, is killed, sends something
unreadable) changes nothing but speed: the parent stops it and renders the rest itself.
Ctrl-C reaches the parent (the child ignores it) and the child is stopped on the way out.
"""

from __future__ import annotations

import mmap
import os
import pickle
import subprocess
import sys
import tempfile
from typing import Iterator

import numpy as np

SLOTS = 3  # chunks rendered ahead of the one being measured, at most
MAX_SLOT_BYTES = 64 << 20  # 3 slots: <= 192 MB of shared memory
_ALIGN = 64


def _slot_bytes(sim) -> int:
    """Bytes of one slot: a chunk's arrays at their largest, each aligned (``DeviceSim._render``:
    times float64, force float32, gyro float64 on an AX6 with gyro, noise float32; 8 bytes a
    sample to spare. A chunk that does not fit ends the child: the parent renders the rest)."""
    from .sensor import CHUNK_S
    n = int(np.ceil(CHUNK_S * sim.clock.rate_true_hz)) + 2
    gyro = sim.spec.kind == "ax6" and sim.spec.gyro_range_dps is not None
    per = 8 + 3 * 4 + (3 * 8 if gyro else 0) + 3 * 4 + 8
    return (n * per + 4 * _ALIGN + _ALIGN - 1) // _ALIGN * _ALIGN


def _shm_dir(need: int = 0):
    """/dev/shm when it exists, is writable and has twice ``need`` bytes free (a container's is
    often 64 MB); else None (the temporary folder)."""
    try:
        st = os.statvfs("/dev/shm")
    except (OSError, AttributeError):
        return None
    if not os.access("/dev/shm", os.W_OK) or st.f_bavail * st.f_frsize < 2 * need:
        return None
    return "/dev/shm"


def suits(sim) -> bool:
    """Whether the child pays for ``sim``: slots of at most ``MAX_SLOT_BYTES`` (an hour's motion
    up to ~400 Hz, ~250 Hz with gyro; above that the slots would hold too much memory)."""
    return _slot_bytes(sim) <= MAX_SLOT_BYTES


# ---------------------------------------------------------------------------- the parent
class _Child:
    def __init__(self, sim):
        self.proc = self.map = None
        self.ready = False
        self.slot = _slot_bytes(sim)
        fd, self.path = tempfile.mkstemp(prefix="stillpoint-render-",
                                         dir=_shm_dir(self.slot * SLOTS))
        try:
            try:
                os.ftruncate(fd, self.slot * SLOTS)
                self.map = mmap.mmap(fd, self.slot * SLOTS)
            finally:
                os.close(fd)
            self.proc = subprocess.Popen([sys.executable, "-c", _BOOT], stdin=subprocess.PIPE,
                                         stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                                         start_new_session=True)  # a terminal's Ctrl-C: the parent's
            self.send([p for p in sys.path if isinstance(p, str)])
            self.send(("device", sim, self.path, self.slot, SLOTS))
        except BaseException:
            self.stop()
            raise

    def send(self, msg) -> None:
        pickle.dump(msg, self.proc.stdin, protocol=pickle.HIGHEST_PROTOCOL)
        self.proc.stdin.flush()

    def poll_ready(self, timeout=0) -> bool:
        """True once the child said it is ready (waiting up to ``timeout`` s; None: until it
        is ready or gone)."""
        if not self.ready:
            import select
            r, _, _ = select.select([self.proc.stdout], [], [], timeout)
            if r:
                msg = pickle.load(self.proc.stdout)
                if msg != ("ready",):
                    raise RuntimeError(f"render process: {msg!r}")
                self.ready = True
                try:
                    os.unlink(self.path)  # both sides have it mapped
                except OSError:
                    pass
        return self.ready

    def receive(self, k: int):
        msg = pickle.load(self.proc.stdout)
        if msg[0] != "chunk" or msg[1] != k:
            raise RuntimeError(f"render process: expected chunk {k}, got {msg[:2]!r}")
        _, _, slot, arrays, rest = msg
        if arrays is None:
            return None
        base = slot * self.slot
        out = []
        for a in arrays:
            if a is None:
                out.append(None)
                continue
            off, dtype, shape = a
            n = int(np.prod(shape)) * np.dtype(dtype).itemsize
            out.append(np.frombuffer(self.map, dtype, int(np.prod(shape)), base + off).reshape(shape).copy()
                       if n else np.empty(shape, dtype))
        try:
            self.send(("free", slot))
        except OSError:  # the child ends after its last chunk; a dead one fails the next receive
            pass
        t, f, w, z = out
        restarts, rng = rest
        return t, f, w, restarts, rng, z

    def stop(self) -> None:
        """Stop the child (if any), unmap the slots and remove their file."""
        try:
            if self.proc is not None and self.proc.poll() is None:
                try:
                    self.send(("stop",))
                except (OSError, ValueError):
                    pass
                try:
                    self.proc.wait(2.0)
                except subprocess.TimeoutExpired:
                    self.proc.kill()
                    self.proc.wait()
        finally:
            for f in ((self.proc.stdin, self.proc.stdout) if self.proc is not None else ()):
                try:
                    f.close()
                except OSError:
                    pass
            try:
                if self.map is not None:
                    self.map.close()
            except (BufferError, ValueError):
                pass
            try:
                os.unlink(self.path)
            except OSError:
                pass


def rendered(sim, *, parent_starts: bool = True) -> Iterator[tuple]:
    """``(k, sim._render(k))`` for k = 0 .. n_chunks - 1, the rendering done by a child process
    once it is up (see the module docstring); None where ``_render`` gives None.
    ``parent_starts=False``: wait for the child instead of rendering while it starts."""
    n = sim.n_chunks
    try:
        child = _Child(sim)
    except Exception:  # noqa: BLE001 - no child: the parent renders everything itself
        child = None
    k = 0
    try:
        while k < n and child is not None:
            try:
                if child.poll_ready(None if not parent_starts else 0):
                    child.send(("start", k))
                    break
            except Exception:  # noqa: BLE001
                child.stop()
                child = None
                break
            yield k, sim._render(k)  # while the child starts
            k += 1
        while k < n and child is not None:
            try:
                r = child.receive(k)
            except Exception:  # noqa: BLE001 - a dead or confused child: carry on without it
                child.stop()
                child = None
                break
            yield k, r
            k += 1
        while k < n:
            yield k, sim._render(k)
            k += 1
    finally:
        if child is not None:
            child.stop()


# ---------------------------------------------------------------------------- the child
def _pack(view: memoryview, base: int, arrays) -> list:
    out, off = [], 0
    for a in arrays:
        if a is None:
            out.append(None)
            continue
        a = np.ascontiguousarray(a)
        if off + a.nbytes > len(view) - base:
            raise ValueError("chunk larger than its slot")
        np.frombuffer(view, a.dtype, a.size, base + off)[:] = a.reshape(-1)
        out.append((off, a.dtype.str, a.shape))
        off += (a.nbytes + _ALIGN - 1) // _ALIGN * _ALIGN
    return out


def _serve(inp, outp) -> None:
    kind, sim, path, slot, nslots = pickle.load(inp)
    assert kind == "device"
    from stillpoint.engine.core.malloc import tune_for_blocks
    tune_for_blocks()
    with open(path, "r+b") as fh:
        m = mmap.mmap(fh.fileno(), slot * nslots)
    view = memoryview(m)
    pickle.dump(("ready",), outp, protocol=pickle.HIGHEST_PROTOCOL)
    outp.flush()
    msg = pickle.load(inp)
    if msg[0] != "start":
        return
    free = list(range(nslots))
    for k in range(int(msg[1]), sim.n_chunks):
        r = sim._render(k)
        if r is None:
            pickle.dump(("chunk", k, -1, None, None), outp, protocol=pickle.HIGHEST_PROTOCOL)
            outp.flush()
            continue
        while not free:
            msg = pickle.load(inp)
            if msg[0] == "stop":
                return
            free.append(msg[1])
        s = free.pop(0)
        t, f, w, restarts, rng, z = r
        arrays = _pack(view, s * slot, [t, f, w, z])
        pickle.dump(("chunk", k, s, arrays, (restarts, rng)), outp, protocol=pickle.HIGHEST_PROTOCOL)
        outp.flush()


def _main() -> None:
    try:
        _serve(sys.stdin.buffer, sys.stdout.buffer)
    except (EOFError, BrokenPipeError, KeyboardInterrupt):
        pass


# the child's start: Ctrl-C ignored from the first line, the parent's import path, then serve
_BOOT = ("import signal; signal.signal(signal.SIGINT, signal.SIG_IGN); import pickle, sys; "
         "sys.path[:0] = pickle.load(sys.stdin.buffer); "
         "from stillpoint.engine.sim.render_process import _main; _main()")
