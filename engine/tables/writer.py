"""Write the epoch table (``<stem>.epochs.csv.gz``) and the day table (``<stem>.days.csv``) while the
output pass runs: ``TablesTap`` is pushed the raw Block, corrected batches and epoch metrics of every
pipeline step (see ``engine.run.OutputStage``), streams epoch rows into gzip text and keeps one
local day of rows for the day table. Both files go through ``drivers.outputs`` (``.part``, fsync,
atomic rename); a failed run leaves no table under the final names.

Epoch table columns: ``time_utc`` (ISO 8601, ``Z``; only when the zone is known: a table of
a recording whose zone is unknown has no UTC column), ``time_local`` (ISO 8601 with the offset
in force, or without offset when the zone is unknown: the device clock), ``n`` (samples),
``enmo_mg``, ``bfen_mg``, ``mad_mg``, ``anglez_deg``, ``temperature_c`` (empty without data),
then the flags ``nonwear``, ``clipping``, ``gap``, ``qc``, ``filter_warmup`` (0/1), and with sleep
on (a known zone; engine/sleep) ``spt`` (inside a night's sleep period) and ``sib`` (a sustained
inactivity bout), 0/1. Times are epoch starts. With sleep on, rows wait for their night's
decision (at most about 30 h of epochs) and ``<stem>.nights.csv`` is written too.
"""

from __future__ import annotations

import csv
import gzip
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import numpy as np

from stillpoint.drivers.names import csv_cell
from stillpoint.drivers.outputs import AtomicOutput, atomic_output, check_output_path

from ..operators.nonwear import DEFAULT_VERSION, clip_threshold_g
from ..timezones import Zone
from .days import ENMO_BANDS_MG, MVPA_BOUT_S, VALID_DAY_HOURS, DayAccumulator
from .epochs import FLAGS, EpochAssembler, EpochRows

EPOCH_COLUMNS = ["time_utc", "time_local", "n", "enmo_mg", "bfen_mg", "mad_mg", "anglez_deg",
                 "temperature_c"] + list(FLAGS)
_DECIMALS = {"enmo_mg": 3, "bfen_mg": 3, "mad_mg": 3, "anglez_deg": 3, "temperature_c": 2}

# gzip level of the epoch table: on a week of 5 s epochs (8.5 MB of CSV) level 1 takes 0.06 s
# for 2.37 MB, level 6 0.30 s for 2.06 MB (zlib, measured on tools/bench_process.py's file)
GZIP_LEVEL = 1


def epoch_columns(zone: Zone) -> list:
    """The epoch table's columns: ``time_utc`` only when the zone is known."""
    return EPOCH_COLUMNS if zone.known else EPOCH_COLUMNS[1:]


def table_paths(mcap_path) -> tuple[Path, Path]:
    """``<stem>.epochs.csv.gz`` and ``<stem>.days.csv`` beside an MCAP."""
    p = Path(mcap_path)
    stem = p.name[:-5] if p.name.endswith(".mcap") else p.name
    return p.with_name(stem + ".epochs.csv.gz"), p.with_name(stem + ".days.csv")


@dataclass
class TablesSettings:
    epochs_path: Path
    days_path: Path
    zone: Zone = field(default_factory=lambda: Zone(""))
    nonwear_version: str = DEFAULT_VERSION
    valid_day_hours: float = VALID_DAY_HOURS
    enmo_bands_mg: tuple = ENMO_BANDS_MG
    mvpa_bout_s: float = MVPA_BOUT_S
    sleep: Optional[object] = None  # engine.sleep.SleepOptions: sleep on when the zone is known
    nights_path: Optional[Path] = None

    def to_dict(self) -> dict:
        d = {"epochs": str(self.epochs_path), "days": str(self.days_path),
             "timezone": self.zone.label, "nonwear_version": self.nonwear_version,
             "valid_day_hours": self.valid_day_hours, "enmo_bands_mg": list(self.enmo_bands_mg),
             "mvpa_bout_s": self.mvpa_bout_s}
        if self.sleep is not None:
            d["sleep"] = self.sleep.to_dict()
        return d


def _num(v: np.ndarray, decimals: int) -> list:
    """Each value as ``%.<decimals>f`` text; empty when not finite."""
    fmt = f"%.{decimals}f"
    return [fmt % x if ok else "" for x, ok in zip(v.tolist(), np.isfinite(v).tolist())]


def _flag(f: np.ndarray) -> list:
    """Each flag as 0/1."""
    return [_BITS[x] for x in f.tolist()]


_BITS = ("0", "1")


def _iso(t_ns: np.ndarray, unit: str) -> np.ndarray:
    return np.datetime_as_string(t_ns.astype("datetime64[ns]").astype(f"datetime64[{unit}]"),
                                 unit=unit)


def _offset_text(off_s: np.ndarray) -> np.ndarray:
    out = np.empty(off_s.shape, object)
    for o in np.unique(off_s):
        sign = "-" if o < 0 else "+"
        a = abs(int(o)) // 60
        out[off_s == o] = f"{sign}{a // 60:02d}:{a % 60:02d}"
    return out.astype(str)


def format_rows(rows: EpochRows, zone: Zone, epoch_ns: int, extra=()) -> str:
    if not len(rows):
        return ""
    unit = "s" if epoch_ns % 10**9 == 0 else "ms"
    t = rows.start_ns
    if zone.known:
        utc = np.char.add(_iso(t, unit), "Z").tolist()
        off = zone.offsets_s(t)
        local = np.char.add(_iso(t + off * 10**9, unit), _offset_text(off)).tolist()
    else:
        utc = None
        local = _iso(t, unit).tolist()
    cols = ([utc] if utc is not None else []) + [local, [str(x) for x in rows.n.tolist()]]
    for name in EPOCH_COLUMNS[3:8]:
        cols.append(_num(getattr(rows, name), _DECIMALS[name]))
    for f in FLAGS:
        cols.append(_flag(getattr(rows, f)))
    for v in extra:  # the sleep columns
        cols.append(_flag(v.astype(bool)))
    return "\n".join(map(",".join, zip(*cols))) + "\n"


def _cell(v) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return "" if not np.isfinite(v) else f"{v:.4f}".rstrip("0").rstrip(".")
    return str(v)


class TablesTap:
    """Pushed by the output stage; writes both tables; ``close()`` returns the table summary."""

    def __init__(self, ts: TablesSettings, rate_hz: float, epoch_s: float, band, source, info,
                 sink=None):
        self.ts = ts
        self.epoch_ns = int(round(epoch_s * 1e9))
        check_output_path(ts.epochs_path, what="epoch table")
        check_output_path(ts.days_path, what="day table")
        self.sleep = None
        self.sink = sink
        if ts.sleep is not None:
            from ..sleep.tap import open_sleep
            self.sleep = open_sleep(ts, epoch_s)
        self.assembler = EpochAssembler(rate_hz, epoch_s, band, source=source,
                                        nonwear_version=ts.nonwear_version,
                                        clip_g=clip_threshold_g(getattr(info, "accel_range_g", None)))
        self.days = DayAccumulator(ts.zone, epoch_s, valid_day_hours=ts.valid_day_hours,
                                   bands=ts.enmo_bands_mg, mvpa_bout_s=ts.mvpa_bout_s)
        self._out = AtomicOutput(ts.epochs_path, what="epoch table")
        self._gz = gzip.GzipFile(filename="", mode="wb", fileobj=self._out.file, mtime=0,
                                 compresslevel=GZIP_LEVEL)
        head = epoch_columns(ts.zone) + (["spt", "sib"] if self.sleep is not None else [])
        self._gz.write((",".join(head) + "\n").encode())
        self.rows = 0
        self.flag_counts = {f: 0 for f in FLAGS}
        self.clean = 0
        self._closed = False

    def _write(self, slices, final: bool = False) -> None:
        if self.sleep is not None:
            slices = self.sleep.rows(slices, final)
        for rows in slices:
            extra = ()
            if self.sleep is not None:
                rows, extra = rows[0], rows[1:]
            if not len(rows):
                continue
            self.rows += len(rows)
            for f in FLAGS:
                self.flag_counts[f] += int(getattr(rows, f).sum())
            self.clean += int(rows.clean.sum())
            self._gz.write(format_rows(rows, self.ts.zone, self.epoch_ns, extra).encode())
            self.days.push(rows)

    def push(self, block, batches, metrics) -> None:
        self._write(self.assembler.push(block, batches, metrics))

    def flush(self, metrics=None) -> None:
        self._write(self.assembler.flush(metrics), final=True)

    def close(self, calibration_status: str = "") -> dict:
        self._gz.close()
        self._out.commit()
        days = self.days.close()
        summary = self.days.summary()
        for d in days + [summary]:
            d["calibration"] = calibration_status
        cols = self.days.columns
        if self.sleep is not None:
            cols = self.sleep.close(days, self.sink, self.ts.zone, cols)
        with atomic_output(self.ts.days_path, binary=False, what="day table") as f:
            w = csv.writer(f, lineterminator="\n")
            w.writerow(cols)
            for d in days + [summary]:
                w.writerow([csv_cell(_cell(d.get(c))) for c in cols])
        self._closed = True
        nw = self.assembler.nonwear
        out = {"epochs": str(self.ts.epochs_path), "days": str(self.ts.days_path),
               "timezone": self.ts.zone.label, "nonwear_version": self.ts.nonwear_version,
               "epoch_rows": self.rows, "clean_epochs": self.clean, "flags": self.flag_counts,
               "nonwear_windows": nw.nonwear_windows, "clipping_windows": nw.clipping_windows,
               "filter_warmup_s": self.assembler.warmup_ns / 1e9,
               "day_rows": len(days), "file": summary}
        if self.assembler.epochs_not_in_table:
            out["epochs_not_in_table"] = self.assembler.epochs_not_in_table
        if self.sleep is not None:
            out["sleep"] = self.sleep.summary()
        return out

    def abort(self) -> None:
        if self._closed:
            return
        try:
            self._gz.close()
        except Exception:
            pass
        self._out.abandon()
        self._closed = True
