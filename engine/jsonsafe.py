"""JSON-safe values for reports, summaries and JSON log messages.

``jsonable(x)`` turns numpy scalars and arrays into plain Python values, non-finite floats into
``None`` (JSON has no NaN or infinity), bytes into latin-1 text and sets into sorted lists,
recursively through dicts, lists and tuples. Everything else is returned as is.
"""

from __future__ import annotations

import math

import numpy as np


def jsonable(x):
    if isinstance(x, dict):
        return {k: jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return jsonable(x.tolist())
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, (float, np.floating)):
        v = float(x)
        return v if math.isfinite(v) else None
    if isinstance(x, (bytes, bytearray)):
        return x.decode("latin-1")
    if isinstance(x, (set, frozenset)):
        return sorted(jsonable(v) for v in x)
    return x
