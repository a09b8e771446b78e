"""The windows table (``<stem>.windows.csv``): one row per window and window type (WW, MM, OO),
written at the end of the output pass from the epoch records the rhythm table read back
(engine/rhythm/table.py) and the nights."""

from __future__ import annotations

import csv
from pathlib import Path

from stillpoint.drivers.names import cell_text, csv_cell
from stillpoint.drivers.outputs import atomic_output

from .windows import WINDOW_COLUMNS, time_use


def windows_path(mcap_path) -> Path:
    p = Path(mcap_path)
    stem = p.name[:-5] if p.name.endswith(".mcap") else p.name
    return p.with_name(stem + ".windows.csv")


def write_windows(path, rec, nights, zone, epoch_s: float, outcomes=None) -> list:
    cut = outcomes.cut if outcomes is not None else None
    value = rec[cut.column] if cut is not None else rec["enmo_mg"]
    rows = time_use(rec["t_ns"], value, ~rec["invalid"], rec["nonwear"], rec["sib"].astype(bool),
                    rec["spt"].astype(bool), nights, zone, epoch_s, cut)
    with atomic_output(path, binary=False, what="windows table") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(WINDOW_COLUMNS)
        for r in rows:
            w.writerow([csv_cell(cell_text(r.get(c))) for c in WINDOW_COLUMNS])
    return rows
