"""Arrays that are costly to build and never change for given inputs, kept in the user's cache.

``cached_array(name, key, build, shape)`` returns the array ``build()`` makes, from a ``.npy``
file in the cache folder when one was written for the same ``key`` (any repr-able value naming
everything the array depends on), else building it and writing the file for next time (written
to a temporary name and renamed, so a concurrent run never reads half a file). The folder is
``$STILLPOINT_CACHE_DIR``, else ``$XDG_CACHE_HOME/stillpoint``, else ``~/.cache/stillpoint``;
``STILLPOINT_CACHE_DIR=off`` turns the cache off. A folder that cannot be created, read or
written, or a damaged file, only costs the build: results never depend on the cache.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from pathlib import Path
from typing import Callable, Optional

import numpy as np


def cache_dir() -> Optional[Path]:
    """The cache folder (None: the cache is off)."""
    d = os.environ.get("STILLPOINT_CACHE_DIR")
    if d is not None:
        return None if d.strip().lower() in ("", "off", "0", "none") else Path(d)
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "stillpoint"


def cached_array(name: str, key, build: Callable[[], np.ndarray], shape: tuple) -> np.ndarray:
    """``build()`` (a float64 array of ``shape``), from the cache when it holds it for ``key``."""
    folder = cache_dir()
    path = None
    if folder is not None:
        digest = hashlib.sha256(repr(key).encode()).hexdigest()[:20]
        path = folder / f"{name}-{digest}.npy"
        try:
            a = np.load(path, allow_pickle=False)
            if a.shape == tuple(shape) and a.dtype == np.float64:
                return a
        except (OSError, ValueError, EOFError):
            pass
    a = np.ascontiguousarray(build(), np.float64)
    if path is not None and folder is not None:
        try:
            folder.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(prefix=f".{name}-", suffix=".npy", dir=folder)
            try:
                with os.fdopen(fd, "wb") as f:
                    np.save(f, a, allow_pickle=False)
                os.replace(tmp, path)
            except BaseException:
                os.unlink(tmp)
                raise
        except OSError:
            pass  # a read-only or full cache folder: the array is built each time
    return a
