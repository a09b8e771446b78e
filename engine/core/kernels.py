"""Compiled kernels of scipy, loaded from their extension modules alone.

Importing ``scipy.signal`` or ``scipy.ndimage`` costs 0.35-0.5 s of CPU and ~20 MB of memory at
start-up (scipy's array-API layer and every submodule they pull in), more than the kernels
themselves spend on a day of data. ``scipy_extension("signal", "_sosfilt")`` loads one compiled
module of a scipy subpackage by its file, without running the subpackage's ``__init__``; it
returns None when the module is not there (another scipy layout) or cannot be loaded, and the
callers then use scipy's public function (the same kernel, the same numbers).
"""

from __future__ import annotations

import glob
import os
from typing import Optional


def scipy_extension(subpackage: str, module: str) -> Optional[object]:
    """The compiled module ``scipy.<subpackage>.<module>`` loaded on its own, or None."""
    try:
        import importlib.machinery
        import importlib.util

        import scipy
        folder = os.path.join(scipy.__path__[0], subpackage)
        paths = glob.glob(os.path.join(folder, module + ".*.so")) + \
            glob.glob(os.path.join(folder, module + ".*.pyd")) + \
            glob.glob(os.path.join(folder, module + ".so"))
        if not paths:
            return None
        name = f"scipy.{subpackage}.{module}"
        loader = importlib.machinery.ExtensionFileLoader(name, paths[0])
        spec = importlib.util.spec_from_file_location(name, paths[0], loader=loader)
        if spec is None:
            return None
        mod = importlib.util.module_from_spec(spec)
        loader.exec_module(mod)
        return mod
    except Exception:
        return None
