"""What a path is when it is not a regular file (``not_a_file``): neither read as a recording
nor replaced by an output."""

from __future__ import annotations

import stat
from typing import Optional

_NOT_A_FILE = ((stat.S_ISDIR, "a folder"), (stat.S_ISFIFO, "a pipe"),
               (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
               (stat.S_ISSOCK, "a socket"))


def not_a_file(mode: int) -> Optional[str]:
    """What a path of this ``st_mode`` is when it is not a regular file ("a pipe", "a
    character device", ...), else None. Such a path is neither read as a recording (reads
    seek; opening a named pipe waits for a writer) nor replaced by an output."""
    if stat.S_ISREG(mode):
        return None
    return next((k for test, k in _NOT_A_FILE if test(mode)), "not a regular file")
