"""glibc's allocator thresholds for block-sized arrays.

Numpy arrays of a few MB are allocated and freed every block. Above glibc's mmap threshold each
is mapped and faulted in afresh; its dynamic threshold normally grows to avoid that, but a fixed
MALLOC_*_THRESHOLD_ in the environment (Dask's nanny sets one) or a pattern of frees in two
threads keeps it low. :func:`set_block_thresholds` sets mmap above 32 MiB and trim above 64 MiB,
the upper values of glibc's own dynamic thresholds (malloc.h: M_MMAP_THRESHOLD -3,
M_TRIM_THRESHOLD -1).
"""

from __future__ import annotations

import sys

M_TRIM_THRESHOLD = -1  # malloc.h
M_MMAP_THRESHOLD = -3  # malloc.h


def set_block_thresholds() -> bool:
    """mmap above 32 MiB, trim above 64 MiB; False where it cannot be done (not glibc)."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        import ctypes
        libc = ctypes.CDLL("libc.so.6")
        libc.mallopt(M_MMAP_THRESHOLD, 32 << 20)
        libc.mallopt(M_TRIM_THRESHOLD, 64 << 20)
        return True
    except (OSError, AttributeError):
        return False
