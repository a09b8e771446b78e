"""Read a table of window features from CSV (e.g. GGIR's ``spheredata``) into ``WindowFeatures``.

Required columns: ``meanx, meany, meanz, sdx, sdy, sdz`` (g). Optional: ``temperature`` (degC;
absent -> NaN, i.e. "temperature missing"), ``window_index`` (10 s window number, gives the
window start time), ``euclidean_norm``. Other columns are ignored. Header names are matched
case-insensitively, ignoring spaces, dots and underscores (so GGIR's "Euclidean Norm" matches).
Missing values may be empty, ``NA`` or ``NaN``.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from stillpoint.drivers.byteio import check_recording_path
from stillpoint.engine.core.errors import RecordingError

from ..features import WindowFeatures
from .fit import WINDOW_S

REQUIRED = ("meanx", "meany", "meanz", "sdx", "sdy", "sdz")
_NA = {"", "na", "nan", "null", "none"}


def _norm(name: str) -> str:
    return "".join(ch for ch in name.strip().strip('"').lower() if ch not in " ._-")


def _float(text: str) -> float:
    t = text.strip().strip('"')
    if t.lower() in _NA:
        return float("nan")
    return float(t)


def read_features_csv(path, *, window_s: float = WINDOW_S) -> WindowFeatures:
    """Parse the CSV; a bad header or value raises RecordingError naming the file and line."""
    p = Path(path)
    check_recording_path(p, allow_empty=True)
    with open(p, newline="", encoding="utf-8-sig") as f:
        reader = csv.reader(f)
        try:
            header = next(reader)
        except StopIteration:
            raise RecordingError(p, "empty file: expected a header line") from None
        except (csv.Error, UnicodeDecodeError) as e:
            raise RecordingError(p, f"not a CSV table: {e}", where="line 1") from None
        names = [_norm(h) for h in header]
        missing = [c for c in REQUIRED if c not in names]
        if missing:
            raise RecordingError(p, f"missing column(s) {', '.join(missing)}; a features table "
                                    f"needs {', '.join(REQUIRED)} (temperature optional)",
                                 where="line 1")
        want = list(REQUIRED) + [c for c in ("temperature", "windowindex", "euclideannorm")
                                 if c in names]
        idx = [names.index(c) for c in want]
        rows = []
        try:
            for line_no, row in enumerate(reader, start=2):
                if not row or all(not c.strip() for c in row):
                    continue
                try:
                    rows.append([_float(row[i]) for i in idx])
                except (ValueError, IndexError):
                    raise RecordingError(p, f"bad row {row[:10]!r}: expected numbers in columns "
                                            f"{', '.join(want)}", where=f"line {line_no}") from None
        except (csv.Error, UnicodeDecodeError) as e:
            raise RecordingError(p, f"not a CSV table: {e}", where=f"line {reader.line_num}") \
                from None
    data = np.array(rows, np.float64).reshape(-1, len(want))
    col = {c: data[:, j] for j, c in enumerate(want)}
    k = data.shape[0]
    mean = np.column_stack([col["meanx"], col["meany"], col["meanz"]])
    sd = np.column_stack([col["sdx"], col["sdy"], col["sdz"]])
    temperature = col.get("temperature", np.full(k, np.nan))
    if "windowindex" in col and np.all(np.isfinite(col["windowindex"])):
        start_ns = np.round(col["windowindex"] * window_s * 1e9).astype(np.int64)
    else:
        start_ns = np.arange(k, dtype=np.int64) * int(round(window_s * 1e9))
    norm = col.get("euclideannorm")
    return WindowFeatures.from_arrays(mean, sd, temperature, start_ns=start_ns, norm_mean=norm)
