"""JSON-safe values for reports, summaries and JSON log messages.

``jsonable(x)`` turns numpy scalars and arrays into plain Python values, non-finite floats into
``None`` (JSON has no NaN or infinity), dataclasses into dicts, dict keys into text, bytes into
latin-1 text and sets into sorted lists, recursively through dicts, lists and tuples. Everything
else is returned as is. ``dumps(x)``: the JSON text of a log message or metadata value (keys
sorted; never NaN).
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, is_dataclass

import numpy as np


def jsonable(x):
    """``x`` as JSON-ready data (see the module docstring)."""
    if isinstance(x, dict):
        return {(k if isinstance(k, str) else str(k)): jsonable(v) for k, v in x.items()}
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
    if is_dataclass(x) and not isinstance(x, type):
        return jsonable(asdict(x))
    return x


def dumps(obj) -> str:
    """JSON text of ``jsonable(obj)``, keys sorted, no NaN."""
    return json.dumps(jsonable(obj), sort_keys=True, allow_nan=False)
