"""A small ring of shared-memory slots that carries a call's arrays to another process.

``SlotRing`` is how the engine hands a pipeline step's arrays (the raw Block, the corrected
batches, the epoch metrics: ~3 MB at 100 Hz) to the log's process (engine/mcap/sinkproc.py)
without pushing them through a pipe. A call is pickled with protocol 5: the small header (the
objects' structure, a few hundred bytes) goes through the pipe, and every contiguous array's
bytes go out of band into one slot, one after another (``pack``). The receiving process copies
the slot's bytes into memory of its own at once and gives the slot back (``unpack``), so a slot
is busy only while its bytes are copied, and what the receiver keeps from a step never points
into the ring. A call whose arrays do not fit a slot is pickled whole through the pipe (the same
objects; rare: a step much longer than the default).

The ring is one anonymous memory file (``os.memfd_create``), inherited by the child as a file
descriptor: it has no name under /dev/shm, so nothing can be left behind however either
process ends (killed, interrupted, crashed). Memory stays flat: ``count`` slots of ``size``
bytes, allocated once.
"""

from __future__ import annotations

import mmap
import os
import pickle
from typing import Any, Optional

ALIGN = 64  # each buffer starts on a cache line (and on any dtype's alignment)


def available() -> bool:
    """Whether this platform has anonymous memory files (Linux)."""
    return hasattr(os, "memfd_create")


class SlotRing:
    """``count`` slots of ``size`` bytes in one shared memory file (see the module docstring).

    The creator makes it with ``SlotRing(count, size)`` and passes ``fd`` to the child, which
    opens the same memory with ``SlotRing(count, size, fd=fd)``."""

    def __init__(self, count: int, size: int, fd: Optional[int] = None):
        self.count, self.size = int(count), int(size)
        total = self.count * self.size + ALIGN  # the slots, then the control word
        if fd is None:
            fd = os.memfd_create("stillpoint-slots", os.MFD_CLOEXEC)
            try:
                os.ftruncate(fd, total)
            except BaseException:
                os.close(fd)
                raise
        self.fd = fd
        self._mm = mmap.mmap(fd, total)
        self._view = memoryview(self._mm)
        self._flag = self.count * self.size
        self.free = list(range(self.count))  # the creator's side: slots it may fill

    @property
    def stopping(self) -> bool:
        """The control word: set by the creator when the calls still waiting are to be dropped
        (read by the child before each call; no pipe message can overtake the ones queued)."""
        return self._view[self._flag] != 0

    def stop(self) -> None:
        self._view[self._flag] = 1

    def pack(self, obj: Any) -> tuple[bytes, list[int]]:
        """``obj`` pickled (protocol 5): the header and the sizes of its out-of-band buffers,
        whose bytes ``fill`` copies into a slot. Sizes [] : nothing out of band."""
        bufs: list = []
        head = pickle.dumps(obj, protocol=5, buffer_callback=bufs.append)
        self._bufs = [b.raw() for b in bufs]
        return head, [b.nbytes for b in self._bufs]

    def fits(self, sizes: list[int]) -> bool:
        return _span(sizes) <= self.size

    def fill(self, slot: int, sizes: list[int]) -> None:
        """Copy the buffers of the last ``pack`` into ``slot``."""
        at = slot * self.size
        v = self._view
        for b, n in zip(self._bufs, sizes):
            v[at:at + n] = b
            at += -(-n // ALIGN) * ALIGN
        self._bufs = []

    def unpack(self, slot: int, head: bytes, sizes: list[int]) -> Any:
        """The object ``pack`` made, its buffers copied out of ``slot`` into memory of this
        process's own (the slot may be reused as soon as this returns)."""
        at = slot * self.size
        data = bytearray(self._view[at:at + _span(sizes)])
        mv = memoryview(data)
        parts, off = [], 0
        for n in sizes:
            parts.append(mv[off:off + n])
            off += -(-n // ALIGN) * ALIGN
        return pickle.loads(head, buffers=parts)

    def close(self) -> None:
        """Unmap and close the memory file (it goes away with the last process holding it)."""
        try:
            self._view.release()
            self._mm.close()
        except (BufferError, ValueError):
            pass
        try:
            os.close(self.fd)
        except OSError:
            pass
        self.fd = -1


def _span(sizes: list[int]) -> int:
    return sum(-(-n // ALIGN) * ALIGN for n in sizes)
