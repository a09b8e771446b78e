"""The rhythm table (``<stem>.rhythm.csv``): one row per recording, written at the end of the
output pass. ``RhythmTap.push`` is given the epoch rows in order (with their ``spt`` / ``sib``
flags when sleep is on) and keeps each epoch's start, ENMO, MAD, counts, validity and sleep flags
in a temporary file (44 bytes an epoch: about 5.3 MB for a week of 5 s epochs, 23 MB for 30
days); ``close`` reads them back once (the windows table is computed from the same read),
computes ``series.rhythm_row`` and writes the table. Memory against length:
tools/benchmarks/bench_rhythm_memory.py."""

from __future__ import annotations

import csv
import tempfile
from pathlib import Path

import numpy as np

from stillpoint.drivers.names import cell_text, csv_cell
from stillpoint.engine.core.outputs import atomic_output

from .series import RHYTHM_COLUMNS, rhythm_row

# axis1 and vm: ActiLife counts (NaN unless the run computes them), for count cut-points
_RECORD = np.dtype([("t_ns", "<i8"), ("enmo_mg", "<f8"), ("mad_mg", "<f8"), ("axis1", "<f8"),
                    ("vm", "<f8"), ("invalid", "?"), ("nonwear", "?"), ("sib", "i1"), ("spt", "i1")])


def rhythm_path(mcap_path) -> Path:
    p = Path(mcap_path)
    stem = p.name[:-5] if p.name.endswith(".mcap") else p.name
    return p.with_name(stem + ".rhythm.csv")


class RhythmTap:
    def __init__(self, path, zone, epoch_s: float, sleep: bool):
        self.path = Path(path)
        self.zone = zone
        self.epoch_s = float(epoch_s)
        self.sleep = sleep
        self.rows = 0
        self._spill = tempfile.TemporaryFile(prefix="stillpoint-rhythm-")
        self.row = None

    def push(self, rows, spt=None, sib=None) -> None:
        n = len(rows)
        if not n:
            return
        rec = np.empty(n, _RECORD)
        rec["t_ns"], rec["enmo_mg"], rec["mad_mg"] = rows.start_ns, rows.enmo_mg, rows.mad_mg
        rec["axis1"], rec["vm"] = rows.axis1, rows.vm
        rec["invalid"], rec["nonwear"] = ~rows.clean, rows.nonwear
        rec["sib"] = 0 if sib is None else sib
        rec["spt"] = 0 if spt is None else spt
        self._spill.write(rec.tobytes())
        self.rows += n

    def load(self) -> np.ndarray:
        """Every epoch's record back (read once; the temporary file is closed)."""
        self._spill.seek(0)
        rec = np.frombuffer(self._spill.read(), _RECORD)
        self._spill.close()
        return rec

    def close(self, days: list, rec=None) -> dict:
        rec = self.load() if rec is None else rec
        self.row = rhythm_row(rec["t_ns"], rec["enmo_mg"], rec["invalid"], self.zone, self.epoch_s,
                              sib=rec["sib"] if self.sleep else None,
                              spt=rec["spt"] if self.sleep else None, days=days)
        write_rhythm(self.path, [self.row])
        return self.row

    def abort(self) -> None:
        self._spill.close()


def write_rhythm(path, rows: list) -> None:
    with atomic_output(path, binary=False, what="rhythm table") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(RHYTHM_COLUMNS)
        for r in rows:
            w.writerow([csv_cell(cell_text(r.get(c), 6)) for c in RHYTHM_COLUMNS])
