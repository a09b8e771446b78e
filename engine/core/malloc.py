"""glibc's allocator thresholds for block-sized arrays.

Numpy arrays of a few MB are allocated and freed every block. Above glibc's mmap threshold each
is mapped and faulted in afresh; its dynamic threshold normally grows to avoid that, but a fixed
MALLOC_*_THRESHOLD_ in the environment (Dask's nanny sets one) or a pattern of frees in two
threads keeps it low. :func:`set_block_thresholds` sets mmap above 32 MiB and trim above 64 MiB,
the upper values of glibc's own dynamic thresholds (malloc.h: M_MMAP_THRESHOLD -3,
M_TRIM_THRESHOLD -1).

A thread's first allocation gives it an arena of its own, which keeps the block-sized arrays it
freed for itself: :func:`one_arena` makes threads started afterwards allocate from the existing
arena, so the arrays a reader thread frees are reused by the engine's thread (a week's batch run
with a reader thread: ~10 MB less peak RSS). ``MALLOC_ARENA_MAX`` in the environment wins.

A run does not trim the heap every few steps: with the block thresholds the freed pages are
reused by the next steps, and trimming them made those steps fault them in again.
"""

from __future__ import annotations

import sys

M_TRIM_THRESHOLD = -1  # malloc.h
M_MMAP_THRESHOLD = -3  # malloc.h
M_ARENA_MAX = -8  # malloc.h

_ONE_ARENA = False
_LIBC = None


def _libc():
    """glibc, loaded once (raises OSError where there is none)."""
    global _LIBC
    if _LIBC is None:
        import ctypes
        _LIBC = ctypes.CDLL("libc.so.6")
    return _LIBC


def set_block_thresholds() -> bool:
    """mmap above 32 MiB, trim above 64 MiB; False where it cannot be done (not glibc)."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = _libc()
        libc.mallopt(M_MMAP_THRESHOLD, 32 << 20)
        libc.mallopt(M_TRIM_THRESHOLD, 64 << 20)
        return True
    except (OSError, AttributeError):
        return False


_TUNED = False


def tune_for_blocks() -> None:
    """:func:`set_block_thresholds` once per process, unless MALLOC_MMAP_THRESHOLD_ or
    MALLOC_TRIM_THRESHOLD_ is set. Every simulator chunk allocates and frees arrays of a few MB in
    two threads; with the default thresholds they are unmapped or trimmed and faulted in afresh
    each chunk (a 1-day 100 Hz recording: 57 k page faults and 0.19 s of system CPU, against 25 k
    and 0.09 s)."""
    global _TUNED
    if _TUNED:
        return
    _TUNED = True
    import os
    if "MALLOC_MMAP_THRESHOLD_" in os.environ or "MALLOC_TRIM_THRESHOLD_" in os.environ:
        return
    set_block_thresholds()


def one_arena() -> bool:
    """Threads started from now on share the existing arena(s) (glibc ``M_ARENA_MAX`` 1, once
    per process); False where it cannot be done (not glibc) or the environment sets it."""
    global _ONE_ARENA
    if _ONE_ARENA:
        return True
    import os
    if not sys.platform.startswith("linux") or "MALLOC_ARENA_MAX" in os.environ:
        return False
    try:
        _libc().mallopt(M_ARENA_MAX, 1)
    except (OSError, AttributeError):
        return False
    _ONE_ARENA = True
    return True
