"""The rhythm table (``<stem>.rhythm.csv``): one row per recording, written at the end of the
output pass. ``RhythmTap.push`` is given the epoch rows in order (with their ``spt`` / ``sib``
flags when sleep is on) and keeps only what the rhythm and windows tables read, in compact form:
each value column they use (ENMO, and the cut-point metric when it is another) as float64 in a
temporary file, the four flags (invalid, nonwear, SIB, SPT) as one byte, and the epoch starts as
the (index, start) of each run of consecutive epochs, in memory. That is 9 bytes an epoch (17 with
a second metric) where every field was 44: about 1.3 MB for a week of 5 s epochs, 4.7 MB for 30
days. ``close`` reads them back once (the windows table is computed from the same read),
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

# the flags' bits in the one byte an epoch keeps
_INVALID, _NONWEAR, _SIB, _SPT = 1, 2, 4, 8


def rhythm_path(mcap_path) -> Path:
    p = Path(mcap_path)
    stem = p.name[:-5] if p.name.endswith(".mcap") else p.name
    return p.with_name(stem + ".rhythm.csv")


def _read(f, n: int, dtype) -> np.ndarray:
    """``n`` values of ``dtype`` from the start of the temporary file ``f`` (which is closed)."""
    out = np.empty(n, dtype)
    f.seek(0)
    got = f.readinto(memoryview(out).cast("B"))
    f.close()
    if got != out.nbytes:
        raise OSError(f"rhythm spill: {got} of {out.nbytes} bytes read back")
    return out


class RhythmTap:
    """``metrics``: the value columns the tables read besides ENMO (the cut-point metric of the
    windows table: mad_mg, axis1 or vm)."""

    def __init__(self, path, zone, epoch_s: float, sleep: bool, metrics=()):
        self.path = Path(path)
        self.zone = zone
        self.epoch_s = float(epoch_s)
        self.epoch_ns = int(round(self.epoch_s * 1e9))
        self.sleep = sleep
        self.rows = 0
        self.columns = ["enmo_mg"] + [m for m in dict.fromkeys(metrics) if m != "enmo_mg"]
        self._values = {c: tempfile.TemporaryFile(prefix="stillpoint-rhythm-") for c in self.columns}
        self._flags = tempfile.TemporaryFile(prefix="stillpoint-rhythm-")
        self._run_index: list = []  # first epoch of each run of consecutive epoch starts
        self._run_start: list = []  # its start (UTC ns)
        self._next_ns = None  # the start the next epoch has if it continues the run
        self.row = None

    def push(self, rows, spt=None, sib=None) -> None:
        n = len(rows)
        if not n:
            return
        t = np.asarray(rows.start_ns, np.int64)
        brk = np.flatnonzero(np.diff(t) != self.epoch_ns) + 1
        if self._next_ns is None or int(t[0]) != self._next_ns:
            brk = np.concatenate([[0], brk])
        self._run_index.extend((self.rows + brk).tolist())
        self._run_start.extend(t[brk].tolist())
        self._next_ns = int(t[-1]) + self.epoch_ns
        for c, f in self._values.items():
            f.write(np.ascontiguousarray(getattr(rows, c), "<f8").tobytes())
        fl = np.where(~np.asarray(rows.clean, bool), _INVALID, 0).astype(np.uint8)
        fl |= np.where(np.asarray(rows.nonwear, bool), _NONWEAR, 0).astype(np.uint8)
        if sib is not None:
            fl |= np.where(np.asarray(sib) != 0, _SIB, 0).astype(np.uint8)
        if spt is not None:
            fl |= np.where(np.asarray(spt) != 0, _SPT, 0).astype(np.uint8)
        self._flags.write(fl.tobytes())
        self.rows += n

    def load(self) -> dict:
        """Every epoch's fields back (read once; the temporary files are closed): ``t_ns``, the
        value columns, ``invalid`` and ``nonwear`` (bool), ``sib`` and ``spt`` (int8 0/1)."""
        n = self.rows
        idx = np.asarray(self._run_index + [n], np.int64)
        t0 = np.asarray(self._run_start, np.int64)
        t = np.arange(n, dtype=np.int64) * self.epoch_ns
        t += np.repeat(t0 - idx[:-1] * self.epoch_ns, np.diff(idx))
        rec = {"t_ns": t}
        for c, f in self._values.items():
            rec[c] = _read(f, n, "<f8")
        fl = _read(self._flags, n, np.uint8)
        rec["invalid"] = (fl & _INVALID) != 0
        rec["nonwear"] = (fl & _NONWEAR) != 0
        rec["sib"] = ((fl & _SIB) != 0).view(np.int8)
        rec["spt"] = ((fl & _SPT) != 0).view(np.int8)
        return rec

    def close(self, days: list, rec=None) -> dict:
        rec = self.load() if rec is None else rec
        self.row = rhythm_row(rec["t_ns"], rec["enmo_mg"], rec["invalid"], self.zone, self.epoch_s,
                              sib=rec["sib"] if self.sleep else None,
                              spt=rec["spt"] if self.sleep else None, days=days)
        write_rhythm(self.path, [self.row])
        return self.row

    def abort(self) -> None:
        for f in self._values.values():
            f.close()
        self._flags.close()


def write_rhythm(path, rows: list) -> None:
    with atomic_output(path, binary=False, what="rhythm table") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(RHYTHM_COLUMNS)
        for r in rows:
            w.writerow([csv_cell(cell_text(r.get(c), 6)) for c in RHYTHM_COLUMNS])
