"""The windows table (``<stem>.windows.csv``): one row per window and window type (WW, MM, OO),
written at the end of the output pass from the epoch records the rhythm table read back
(engine/rhythm/table.py) and the nights."""

from __future__ import annotations

import csv
from pathlib import Path

from stillpoint.drivers.names import cell_text, csv_cell
from stillpoint.engine.core.outputs import atomic_output

from ..outcomes.impute import METRICS as IMPUTED_METRICS
from .windows import WINDOW_COLUMNS, time_use


def windows_path(mcap_path) -> Path:
    p = Path(mcap_path)
    stem = p.name[:-5] if p.name.endswith(".mcap") else p.name
    return p.with_name(stem + ".windows.csv")


def write_windows(path, rec, nights, zone, epoch_s: float, outcomes=None, average_day=None) -> list:
    """``average_day``: the run's imputation (``--impute``): band minutes and bouts on GGIR's
    imputed series (metrics the imputation keeps: ENMO, MAD), else on clean epochs only."""
    cut = outcomes.cut if outcomes is not None else None
    column = cut.column if cut is not None else "enmo_mg"
    value = rec[column]
    imputed = average_day is not None and average_day.imputes and column in IMPUTED_METRICS
    if imputed:
        value = average_day.fill(column, value, ~rec["invalid"])
    rows = time_use(rec["t_ns"], value, ~rec["invalid"], rec["nonwear"], rec["sib"].astype(bool),
                    rec["spt"].astype(bool), nights, zone, epoch_s, cut, imputed=imputed)
    with atomic_output(path, binary=False, what="windows table") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(WINDOW_COLUMNS)
        for r in rows:
            w.writerow([csv_cell(cell_text(r.get(c))) for c in WINDOW_COLUMNS])
    return rows
