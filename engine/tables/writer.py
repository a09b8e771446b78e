"""Write the epoch table (``<stem>.epochs.csv.gz``) and the day table (``<stem>.days.csv``) while the
output pass runs: ``TablesTap`` is pushed the raw Block, corrected batches and epoch metrics of every
pipeline step (see ``engine.run.OutputStage``), streams epoch rows into gzip text and keeps one
local day of rows for the day table. It is two halves with one job each: ``EpochFeed`` (the
per-sample half: the ``EpochAssembler`` and the step counter) hands the epoch rows and steps it
makes final to ``EpochTableWriter`` (the epoch-level half: the tables' text, gzip, days, outcomes,
sleep, rhythm, windows), which needs no sample and may run in the log's child process
(engine/run/taps.py). Both files go through ``engine/core/outputs.py`` (``.part``, fsync,
atomic rename); a failed run leaves no table under the final names.

Epoch table columns: ``time_utc`` (ISO 8601, ``Z``; only when the zone is known: a table of
a recording whose zone is unknown has no UTC column), ``time_local`` (ISO 8601 with the offset
in force, or without offset when the zone is unknown: the device clock), ``n`` (samples),
``enmo_mg``, ``bfen_mg``, ``mad_mg``, ``anglez_deg``, ``temperature_c`` (empty without data),
then the flags ``nonwear``, ``clipping``, ``gap``, ``qc``, ``filter_warmup`` (0/1), for an
ActiGraph ``.gt3x`` ``idle_sleep`` (share of the epoch's samples in idle sleep), then, when the
run computes them, ActiLife counts ``axis1``, ``axis2``, ``axis3`` (integers) and ``vm`` (2
decimals) and MIMS-units ``mims`` (3 decimals), empty without data, and ``corrected`` (1: the
epoch's samples were corrected with a calibration estimate; 0: no estimate was applied, or the
epoch has no samples). Times are epoch starts. With
activity outcomes (``TablesSettings.outcomes``: a cut-point set, steps) the
epoch table ends with their columns (``engine.outcomes.daily``); rows then wait until the step
counter has decided every step before their end (at most about twice its horizon). With sleep on
(``TablesSettings.sleep`` and a known zone; engine/sleep) the last two columns are ``spt``
(inside a night's sleep period) and ``sib`` (a sustained inactivity bout), 0/1; rows then wait
for their night's decision (at most about 30 h of epochs) and ``<stem>.nights.csv`` is written.
"""

from __future__ import annotations

import csv
import gzip
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import numpy as np

from stillpoint.drivers.names import cell_text, csv_cell
from stillpoint.engine.core.outputs import AtomicOutput, atomic_output, check_output_path

from ..core.times import iso_texts, offset_texts
from ..operators.nonwear import DEFAULT_VERSION, clip_threshold_g
from ..outcomes.daily import DailyOutcomes, OutcomeSettings
from ..timezones import Zone
from .days import DAY_NS, ENMO_BANDS_MG, MVPA_BOUT_S, VALID_DAY_HOURS, DayAccumulator, _slice
from .epochs import COUNT_COLUMNS, FLAGS, EpochAssembler, EpochRows

EPOCH_COLUMNS = ["time_utc", "time_local", "n", "enmo_mg", "bfen_mg", "mad_mg", "anglez_deg",
                 "temperature_c"] + list(FLAGS) + ["corrected"]
_DECIMALS = {"enmo_mg": 3, "bfen_mg": 3, "mad_mg": 3, "anglez_deg": 3, "temperature_c": 2,
             "axis1": 0, "axis2": 0, "axis3": 0, "vm": 2, "mims": 3}


def metric_columns(counts: bool, mims: bool) -> list:
    """The optional metric columns of a run's epoch table (after the flags)."""
    return (list(COUNT_COLUMNS) if counts else []) + (["mims"] if mims else [])

# gzip level of the epoch table: the fastest, for slightly larger files (docs/performance.md#code-figures)
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
    outcomes: OutcomeSettings = field(default_factory=OutcomeSettings)
    sleep: Optional[object] = None  # engine.sleep.SleepOptions: sleep on (device clock without a zone)
    nights_path: Optional[Path] = None
    rhythm_path: Optional[Path] = None  # <stem>.rhythm.csv (engine/rhythm); None: not written
    windows_path: Optional[Path] = None  # <stem>.windows.csv (engine/timeuse; with sleep and rhythm)

    def to_dict(self) -> dict:
        out = {"epochs": str(self.epochs_path), "days": str(self.days_path),
               "timezone": self.zone.label, "nonwear_version": self.nonwear_version,
               "valid_day_hours": self.valid_day_hours, "enmo_bands_mg": list(self.enmo_bands_mg),
               "mvpa_bout_s": self.mvpa_bout_s}
        if self.outcomes.active:
            out["outcomes"] = self.outcomes.to_dict()
        if self.sleep is not None:
            out["sleep"] = self.sleep.to_dict()
        return out


def _num(v: np.ndarray, decimals: int) -> list:
    """Each value as ``%.<decimals>f`` text; empty when not finite. The column is formatted by
    one ``%`` of a repeated template (the same text per value as ``fmt % x``, without a Python
    step per value), then split."""
    values = v.tolist()
    if not values:
        return []
    text = ((f"%.{decimals}f\n" * len(values)) % tuple(values)).split("\n")
    text.pop()  # after the last newline
    bad = ~np.isfinite(v)
    if bad.any():
        for i in np.flatnonzero(bad).tolist():
            text[i] = ""
    return text


def _flag(f: np.ndarray) -> list:
    """Each flag as 0/1."""
    return [_BITS[x] for x in f.tolist()]


_BITS = ("0", "1")


def format_rows(rows: EpochRows, zone: Zone, epoch_ns: int, extra=(), idle: bool = False,
                metrics=(), corrected: bool = True) -> str:
    """The rows as CSV text; ``extra``: more columns (lists of cell text), appended; ``idle``:
    the ``idle_sleep`` column after the flags (an ActiGraph source); ``metrics``: optional metric
    columns (``metric_columns``) after it; ``corrected``: whether an estimate was applied (the
    last column before ``extra``: 1 on rows with samples)."""
    if not len(rows):
        return ""
    unit = "s" if epoch_ns % 10**9 == 0 else "ms"
    t = rows.start_ns
    if zone.known:
        utc = np.char.add(iso_texts(t, unit), "Z").tolist()
        off = zone.offsets_s(t)
        local = np.char.add(iso_texts(t + off * 10**9, unit), offset_texts(off)).tolist()
    else:
        utc = None
        local = iso_texts(t, unit).tolist()
    cols = ([utc] if utc is not None else []) + [local, [str(x) for x in rows.n.tolist()]]
    for name in EPOCH_COLUMNS[3:8]:
        cols.append(_num(getattr(rows, name), _DECIMALS[name]))
    for f in FLAGS:
        cols.append(_flag(getattr(rows, f)))
    if idle:
        v = rows.idle_sleep if rows.idle_sleep is not None else np.zeros(len(rows))
        cols.append(_num(v, 4))
    for name in metrics:
        cols.append(_num(getattr(rows, name), _DECIMALS[name]))
    cols.append(_flag(rows.n > 0) if corrected else ["0"] * len(rows))
    cols.extend(extra)
    return "\n".join(map(",".join, zip(*cols))) + "\n"


class EpochFeed:
    """The per-sample half of the tables: the ``EpochAssembler`` (anglez, nonwear, the metrics'
    sums, QC and warm-up flags) and the step counter, pushed each output step; hands the epoch
    rows they make final, and the steps counted, to an ``EpochTableWriter`` (or to anything with
    its ``rows``, ``advance`` and ``finish``: the writer may run in the log's process)."""

    def __init__(self, ts: TablesSettings, rate_hz: float, epoch_s: float, band, source, info,
                 extras=()):
        self.assembler = EpochAssembler(rate_hz, epoch_s, band, source=source,
                                        nonwear_version=ts.nonwear_version,
                                        clip_g=clip_threshold_g(getattr(info, "accel_range_g", None)),
                                        extras=tuple(extras))
        self.outcomes = ts.outcomes.active  # the writer waits for the steps (``advance``)
        self.steps = None
        if self.outcomes and ts.outcomes.steps:
            from ..outcomes.steps import StepOperator
            self.steps = StepOperator(ts.outcomes.steps)

    def _step_times(self) -> dict:
        return self.steps.take() if self.steps is not None else {}

    def push(self, writer, block, batches, metrics, extras=None) -> None:
        if self.steps is not None:
            for b in batches:
                self.steps.push(b)
        for rows in self.assembler.push(block, batches, metrics, extras):
            if len(rows):
                writer.rows(rows)
        if self.outcomes:
            times = self._step_times()
            writer.advance(times, self.steps.final_before_ns if self.steps is not None else None)

    def flush(self, writer, metrics=None, extras=None) -> None:
        if self.steps is not None:
            self.steps.flush()
        for rows in self.assembler.flush(metrics, extras):
            if len(rows):
                writer.rows(rows)
        writer.finish(self._step_times())

    def assembly(self) -> dict:
        """What the table summary says of the assembly (``EpochTableWriter.close``)."""
        nw = self.assembler.nonwear
        return {"nonwear_windows": nw.nonwear_windows, "clipping_windows": nw.clipping_windows,
                "filter_warmup_s": self.assembler.warmup_ns / 1e9,
                "epochs_not_in_table": self.assembler.epochs_not_in_table}


class EpochTableWriter:
    """The epoch-level half of the tables: takes the epoch rows (``rows``) and the steps counted
    (``advance``, ``finish``) in order and writes the epoch table, the day table and what they
    carry (outcomes, sleep and its log messages, rhythm, windows); ``close()`` returns the table
    summary. Needs no sample: it runs where the log is written (the engine, or the log's child
    process: engine/run/taps.py)."""

    def __init__(self, ts: TablesSettings, epoch_s: float, *, idle: bool = False, metrics=(),
                 sink=None, corrected: bool = True, calibration_source: str = ""):
        self.ts = ts
        # optional metric columns the run computes ("counts", "mims": ``metric_columns``)
        self.metrics = list(metrics)
        # the one estimate the rows were corrected with, applied from the first sample (the
        # epoch table's ``corrected``, the day table's ``calibration_source``)
        self.corrected = corrected
        self.calibration_source = calibration_source
        self.epoch_ns = int(round(epoch_s * 1e9))
        check_output_path(ts.epochs_path, what="epoch table")
        check_output_path(ts.days_path, what="day table")
        self.sink = sink
        self.sleep = None
        if ts.sleep is not None:
            from ..sleep.tap import open_sleep
            self.sleep = open_sleep(ts, epoch_s)
        self.outcomes = DailyOutcomes(ts.outcomes, epoch_s) if ts.outcomes.active else None
        self.rhythm = None
        if ts.rhythm_path is not None:
            from ..rhythm.table import RhythmTap
            check_output_path(ts.rhythm_path, what="rhythm table")
            cut = self.outcomes.cut if self.outcomes is not None else None
            self.rhythm = RhythmTap(ts.rhythm_path, ts.zone, epoch_s, sleep=self.sleep is not None,
                                    metrics=(cut.column,) if cut is not None else ())
        self._waiting: list = []  # rows waiting for their steps
        self._held: list = []  # (rows, extra columns, step counts) of the local day being read
        self._held_day = None
        self.average_day = None
        if self.outcomes is not None and ts.outcomes.impute:
            from ..outcomes.impute import AverageDay
            self.average_day = AverageDay(epoch_s)
        self._step_times = {s: np.zeros(0, np.int64) for s in ts.outcomes.steps}
        self.days = DayAccumulator(ts.zone, epoch_s, valid_day_hours=ts.valid_day_hours,
                                   bands=ts.enmo_bands_mg, mvpa_bout_s=ts.mvpa_bout_s,
                                   outcomes=self.outcomes)
        self._out = AtomicOutput(ts.epochs_path, what="epoch table")
        self._gz = gzip.GzipFile(filename="", mode="wb", fileobj=self._out.file, mtime=0,
                                 compresslevel=GZIP_LEVEL)
        self.idle = idle  # the idle_sleep column (an ActiGraph source)
        head = epoch_columns(ts.zone)[:-1] + (["idle_sleep"] if self.idle else []) + self.metrics \
            + ["corrected"] \
            + (self.outcomes.epoch_columns() if self.outcomes else []) \
            + (self.sleep.columns if self.sleep is not None else [])
        self._gz.write((",".join(head) + "\n").encode())
        self.rows_written = 0
        self.flag_counts = {f: 0 for f in FLAGS}
        self.clean = 0
        self._closed = False

    # ------------------------------------------------------------------ inputs, in order
    def rows(self, rows: EpochRows) -> None:
        """Epoch rows the assembler made final (consecutive, in time order, not empty)."""
        if self.outcomes is not None:
            self._waiting.append(rows)  # until ``advance`` says their steps are counted
            return
        self._count(rows)
        self._put(rows, [], None)

    def advance(self, step_times: dict, final_before_ns: Optional[int]) -> None:
        """With outcomes, after each step's rows: the steps counted in it (times, ns, per step
        algorithm) and the time before which no step can come any more (None: no step counter)."""
        self._write_outcomes(step_times, final_before_ns)

    def finish(self, step_times: dict) -> None:
        """The end of the rows: the last steps counted, then every row still held is written."""
        if self.outcomes is not None:
            self._write_outcomes(step_times, None)
            self._finish_day()
        if self.sleep is not None:
            self._put(None, [], None, final=True)

    def _count(self, rows) -> None:
        self.rows_written += len(rows)
        for f in FLAGS:
            self.flag_counts[f] += int(getattr(rows, f).sum())
        self.clean += int(rows.clean.sum())

    def _write_outcomes(self, step_times: dict, fb: Optional[int]) -> None:
        """Rows with the outcome columns; a row waits until no step before its end can come
        (``fb``: None, every row may go)."""
        for s, t in step_times.items():
            if t.shape[0]:  # sorted: a restart may send the clock back
                self._step_times[s] = np.sort(np.concatenate([self._step_times[s], t]))
        while self._waiting:
            rows = self._waiting[0]
            if fb is not None:
                ends = rows.start_ns + self.epoch_ns
                k = int(np.searchsorted(ends, fb, side="right"))
                if k == 0:
                    break
                if k < len(rows):
                    self._waiting[0] = _slice(rows, k, len(rows))
                    rows = _slice(rows, 0, k)
                else:
                    self._waiting.pop(0)
            else:
                self._waiting.pop(0)
            self._emit_outcomes(rows)

    def _emit_outcomes(self, rows) -> None:
        self._count(rows)
        extra, counts = [], {}
        o = self.outcomes
        if o.cut is not None:
            extra.append(o.epoch_labels(getattr(rows, o.cut.column), rows.clean))
        for s in self.ts.outcomes.steps:
            t = self._step_times[s]
            edges = np.searchsorted(t, np.append(rows.start_ns, rows.start_ns[-1] + self.epoch_ns))
            n = np.diff(edges)
            self._step_times[s] = t[edges[-1]:]
            counts[s] = n
            extra.append([str(x) for x in n.tolist()])
        z = self.ts.zone
        day = np.floor_divide(z.local_ns(rows.start_ns) if z.known else rows.start_ns, DAY_NS)
        if self.average_day is not None:
            self.average_day.push({"enmo_mg": rows.enmo_mg, "mad_mg": rows.mad_mg}, rows.clean, day,
                                  z.local_ns(rows.start_ns) if z.known else rows.start_ns)
        if o.cut is None:
            self._put(rows, extra, counts)
            return
        # the bouts column needs the whole local day: the day's rows wait for its end
        cuts = np.flatnonzero(np.diff(day)) + 1
        for a, b in zip(np.r_[0, cuts], np.r_[cuts, len(rows)]):
            if self._held_day is not None and int(day[a]) != self._held_day:
                self._finish_day()
            self._held_day = int(day[a])
            self._held.append((_slice(rows, a, b), [c[a:b] for c in extra],
                               {k: v[a:b] for k, v in counts.items()}))

    def _finish_day(self) -> None:
        """Write the held day's rows with each epoch's bouts (``engine.outcomes.daily``)."""
        if not self._held:
            return
        o = self.outcomes
        vals = np.concatenate([getattr(r, o.cut.column) for r, _, _ in self._held])
        clean = np.concatenate([r.clean for r, _, _ in self._held])
        labels = o.epoch_bouts(vals, clean)
        a = 0
        for rows, extra, counts in self._held:
            self._put(rows, extra + [labels[a:a + len(rows)]], counts)
            a += len(rows)
        self._held, self._held_day = [], None

    def _put(self, rows, extra, counts, final: bool = False) -> None:
        """Write rows with their extra columns; with sleep on, once their nights are decided."""
        items = [(rows, extra, counts)] if rows is not None else []
        if self.sleep is not None:
            items = self.sleep.feed(items, final)
        for r, x, c in items:
            self._gz.write(format_rows(r, self.ts.zone, self.epoch_ns, x, idle=self.idle,
                                       metrics=self.metrics, corrected=self.corrected).encode())
            self.days.push(r, steps=c)
            if self.rhythm is not None:
                if self.sleep is not None:  # the sleep tap's last two columns: spt, sib
                    self.rhythm.push(r, np.array(x[-2]) == "1", np.array(x[-1]) == "1")
                else:
                    self.rhythm.push(r)

    def close(self, calibration_status: str = "", assembly: Optional[dict] = None) -> dict:
        """Finish every table; the summary, with what ``EpochFeed.assembly`` said of the rows."""
        a = assembly or {}
        self._gz.close()
        self._out.commit()
        days = self.days.close()
        if self.average_day is not None:  # GGIR's imputation needs the whole average day
            from ..outcomes.impute import imputed_days
            imp = imputed_days(self.average_day, self.outcomes)
            self.average_day.close()  # its slot means stay for the windows table
            from ..outcomes.impute import M_COLUMNS, SUFFIX
            for d in days:
                d.update(imp.get(d["date"], {}))
                if not d.get("valid_day"):  # M10/L5 on valid days only, as the day table's
                    d.update({c + SUFFIX: None for c in M_COLUMNS})
        summary = self.days.summary()
        for d in days + [summary]:
            d["calibration"] = calibration_status
            d["calibration_source"] = self.calibration_source
        cols = self.days.columns
        if self.sleep is not None:
            cols = self.sleep.close(days, self.sink, self.ts.zone, cols)
        rhythm = windows = None
        if self.rhythm is not None:
            rec = self.rhythm.load()
            rhythm = self.rhythm.close(days, rec)
            if self.sleep is not None and self.ts.windows_path is not None:
                from ..timeuse.table import write_windows
                windows = write_windows(self.ts.windows_path, rec, self.sleep.stage.nights,
                                        self.ts.zone, self.epoch_ns / 1e9, self.outcomes,
                                        self.average_day)
        with atomic_output(self.ts.days_path, binary=False, what="day table") as f:
            w = csv.writer(f, lineterminator="\n")
            w.writerow(cols)
            for d in days + [summary]:
                w.writerow([csv_cell(cell_text(d.get(c))) for c in cols])
        self._closed = True
        out = {"epochs": str(self.ts.epochs_path), "days": str(self.ts.days_path),
               "timezone": self.ts.zone.label, "nonwear_version": self.ts.nonwear_version,
               "epoch_rows": self.rows_written, "clean_epochs": self.clean,
               "flags": self.flag_counts, "nonwear_windows": a.get("nonwear_windows"),
               "clipping_windows": a.get("clipping_windows"),
               "filter_warmup_s": a.get("filter_warmup_s"), "day_rows": len(days), "file": summary}
        if a.get("epochs_not_in_table"):
            out["epochs_not_in_table"] = a["epochs_not_in_table"]
        if self.outcomes is not None:
            out["outcomes"] = self.ts.outcomes.to_dict()
        if self.sleep is not None:
            out["sleep"] = self.sleep.summary()
        if rhythm is not None:
            out["rhythm"] = str(self.ts.rhythm_path)
        if windows is not None:
            out["windows"] = str(self.ts.windows_path)
        return out

    def abort(self) -> None:
        if self._closed:
            return
        if self.average_day is not None:
            self.average_day.close()
        if self.rhythm is not None:
            self.rhythm.abort()
        try:
            self._gz.close()
        except Exception:
            pass
        self._out.abandon()
        self._closed = True


class TablesTap:
    """Pushed by the output pass (``push(block, batches, metrics, extras)``, ``flush``): both
    halves of the tables in this process, the per-sample ``EpochFeed`` handing its rows to the
    ``EpochTableWriter``; ``close()`` returns the table summary."""

    def __init__(self, ts: TablesSettings, rate_hz: float, epoch_s: float, band, source, info,
                 sink=None, extras=(), *, corrected: bool = True, calibration_source: str = ""):
        self.writer = EpochTableWriter(ts, epoch_s, **writer_options(info, extras), sink=sink,
                                       corrected=corrected, calibration_source=calibration_source)
        try:
            self.feed = EpochFeed(ts, rate_hz, epoch_s, band, source, info, extras)
        except BaseException:
            self.writer.abort()
            raise

    @property
    def calibration_source(self) -> str:
        return self.writer.calibration_source

    @calibration_source.setter
    def calibration_source(self, value: str) -> None:
        self.writer.calibration_source = value

    def push(self, block, batches, metrics, extras=None) -> None:
        self.feed.push(self.writer, block, batches, metrics, extras)

    def flush(self, metrics=None, extras=None) -> None:
        self.feed.flush(self.writer, metrics, extras)

    def close(self, calibration_status: str = "") -> dict:
        return self.writer.close(calibration_status, self.feed.assembly())

    def abort(self) -> None:
        self.writer.abort()


def writer_options(info, extras) -> dict:
    """The ``EpochTableWriter`` options a source and the run's optional metrics decide: the
    ``idle_sleep`` column (an ActiGraph source) and the metric columns (counts, MIMS-units)."""
    return {"idle": getattr(info, "device_type", None) == "ActiGraph",
            "metrics": metric_columns("counts" in extras, "mims" in extras)}
