"""Nonwear imputation as GGIR does it (``g.impute``, wadpac/GGIR ``R/g.impute.R`` @388064b7), for
day values comparable with GGIR's.

GGIR cuts the recording into consecutive 24-hour pieces from its first epoch (lines 373-384), takes
for every epoch slot of the day the mean of that slot over all pieces where the epoch is not
masked (nonwear, clipping: ``r5long != 0``, lines 366-372, 397), and replaces every masked epoch by
its slot's mean (lines 412-417); a slot never observed gets 0 (lines 404-410). It imputes only
when the recording is longer than one piece (``ndays > 1``, line 377). Here an epoch is masked
when it is not clean (nonwear, clipping, gap, QC, filter warm-up); slots count rows of the epoch
table (one per epoch from the first, gaps included).

``AverageDay`` collects the slot sums while the epoch rows stream (memory: two arrays of one day's
epochs) and keeps each epoch's day, values and clean flag in a temporary file (25 bytes an
epoch); ``imputed_days`` reads that file back a slice at a time and gives, per local day, the day
values computed on the imputed epochs, each column name ending ``_imputed``:
``enmo_mean_mg_imputed``, ``mad_mean_mg_imputed`` (mean over the day's epochs), GGIR's M10 and L5
on the imputed epochs (``m10_mg_imputed``, ``m10_start_imputed``, ``l5_mg_imputed``,
``l5_start_imputed``: GGIR computes M5L5 on its imputed series, R/g.analyse.perday.R:518, so
nonwear at night cannot push L5 into the evening; each day first brought to 24 h as GGIR does,
``ggir_day``; valid days only, as the day table's), the relative amplitude of those
(``ra_imputed``) and, with
a cut-point set, the band minutes and bout minutes of ``engine.outcomes.daily``.
"""

from __future__ import annotations

import datetime as _dt
import tempfile

import numpy as np

SUFFIX = "_imputed"
METRICS = ("enmo_mg", "mad_mg")
SLICE_ROWS = 1 << 15
_RECORD = np.dtype([("day", "<i4"), ("tod_s", "<i4"), ("enmo_mg", "<f8"), ("mad_mg", "<f8"),
                    ("clean", "?")])
M_COLUMNS = ("m10_mg", "m10_start", "l5_mg", "l5_start", "ra")


class AverageDay:
    def __init__(self, epoch_s: float):
        self.epoch_s = float(epoch_s)
        self.per_day = int(round(86400.0 / epoch_s))
        self.rows = 0
        self.sums = {m: np.zeros(self.per_day) for m in METRICS}
        self.counts = {m: np.zeros(self.per_day, np.int64) for m in METRICS}
        self._spill = tempfile.TemporaryFile(prefix="stillpoint-impute-")

    def push(self, values: dict, clean: np.ndarray, day: np.ndarray, local_ns=None) -> None:
        """One slice of epoch rows: metric values, clean flags, local day numbers and local
        times (ns; for the M10/L5 start times)."""
        n = clean.shape[0]
        slot = (self.rows + np.arange(n)) % self.per_day
        rec = np.empty(n, _RECORD)
        rec["day"], rec["clean"] = day, clean
        rec["tod_s"] = 0 if local_ns is None else (np.asarray(local_ns) % 86400_000_000_000) // 10**9
        for m in METRICS:
            v = values[m]
            rec[m] = v
            ok = clean & np.isfinite(v)
            np.add.at(self.sums[m], slot[ok], v[ok])
            np.add.at(self.counts[m], slot[ok], 1)
        self._spill.write(rec.tobytes())
        self.rows += n

    @property
    def imputes(self) -> bool:
        """GGIR imputes only a recording longer than one day."""
        return self.rows > self.per_day

    def profile(self, metric: str) -> np.ndarray:
        c = self.counts[metric]
        return np.where(c > 0, self.sums[metric] / np.maximum(c, 1), 0.0)

    def fill(self, metric: str, values: np.ndarray, clean: np.ndarray) -> np.ndarray:
        """The recording's ``metric`` from its first epoch row with every epoch that is not clean
        replaced by its slot's mean (GGIR's imputed series); unchanged when GGIR would not
        impute."""
        v = np.asarray(values, np.float64)
        if not self.imputes:
            return v
        slot = np.arange(v.shape[0]) % self.per_day
        return np.where(np.asarray(clean, bool) & np.isfinite(v), v, self.profile(metric)[slot])

    def slices(self):
        """The spilled rows back, in order, a slice at a time."""
        self._spill.seek(0)
        while True:
            buf = self._spill.read(SLICE_ROWS * _RECORD.itemsize)
            if not buf:
                return
            yield np.frombuffer(buf, _RECORD)

    def close(self) -> None:
        self._spill.close()


def _date(day: int) -> str:
    return (_dt.date(1970, 1, 1) + _dt.timedelta(days=int(day))).isoformat()


def imputed_days(average: AverageDay, outcomes=None) -> dict:
    """date -> {column: value} of the day values on imputed epochs; {} when GGIR would not
    impute (a recording of one day or less)."""
    if not average.imputes:
        return {}
    prof = {m: average.profile(m) for m in METRICS}
    out: dict = {}
    row = 0
    day, parts = None, []

    first_day = None

    def finish(day, parts):
        from ..tables.days import m_window, relative_amplitude
        e = np.concatenate([p[0] for p in parts])
        m = np.concatenate([p[1] for p in parts])
        d = {"enmo_mean_mg" + SUFFIX: float(e.mean()), "mad_mean_mg" + SUFFIX: float(m.mean())}
        day_e = ggir_day(e, prof["enmo_mg"], average.per_day, day == first_day)
        every = np.ones(day_e.shape[0], bool)
        for key, hours, pick in (("m10", 10.0, np.argmax), ("l5", 5.0, np.argmin)):
            val, start = m_window(day_e, every, None, hours, pick, average.epoch_s, start_of_day_ns=0)
            d[f"{key}_mg" + SUFFIX], d[f"{key}_start" + SUFFIX] = val, start
        d["ra" + SUFFIX] = relative_amplitude(d["m10_mg" + SUFFIX], d["l5_mg" + SUFFIX])
        if outcomes is not None and outcomes.cut is not None:
            v = e if outcomes.cut.column == "enmo_mg" else m
            for name, val in outcomes.day(v, np.ones(v.shape[0], bool),
                                          np.zeros(v.shape[0], np.int64), {}).items():
                if name.startswith(("min_", "bout_min_")):
                    d[name + SUFFIX] = val
        out[_date(day)] = d

    for rec in average.slices():
        n = rec.shape[0]
        slot = (row + np.arange(n)) % average.per_day
        row += n
        clean = rec["clean"]
        e = np.where(clean & np.isfinite(rec["enmo_mg"]), rec["enmo_mg"], prof["enmo_mg"][slot])
        m = np.where(clean & np.isfinite(rec["mad_mg"]), rec["mad_mg"], prof["mad_mg"][slot])
        days = rec["day"]
        cuts = np.flatnonzero(days[1:] != days[:-1]) + 1
        for a, b in zip(np.r_[0, cuts], np.r_[cuts, n]):
            if day is not None and int(days[a]) != day:
                finish(day, parts)
                parts = []
            day = int(days[a])
            if first_day is None:
                first_day = day
            parts.append((e[a:b], m[a:b], rec["tod_s"][a:b]))
    if day is not None:
        finish(day, parts)
    return out


def ggir_day(e: np.ndarray, profile: np.ndarray, per_day: int, first: bool) -> np.ndarray:
    """One local day's imputed epochs brought to 24 h as GGIR's part 2 does before its M5L5
    (R/g.analyse.perday.R:356-392): a short first day is preceded by the average day's first
    slots, a 23-h day gets the average day's slots of its third hour inserted after its second,
    another short day is followed by the average day's last slots; a 25-h day is kept as it is
    (GGIR's row removal there indexes columns, so it removes nothing). The average day's slots
    count from the recording's first epoch, as GGIR's do."""
    n = e.shape[0]
    short = per_day - n
    if short <= 0:
        return e
    if first:
        return np.concatenate([profile[:short], e])
    hour = per_day // 24
    if n == 23 * hour:
        return np.concatenate([e[:2 * hour], profile[2 * hour:3 * hour], e[2 * hour:]])
    return np.concatenate([e, profile[per_day - short:]])


def imputed_columns(outcomes=None) -> list:
    cols = ["enmo_mean_mg" + SUFFIX, "mad_mean_mg" + SUFFIX] + [c + SUFFIX for c in M_COLUMNS]
    if outcomes is not None and outcomes.cut is not None:
        cols += [c + SUFFIX for c in outcomes.base_day_columns()
                 if c.startswith(("min_", "bout_min_"))]
    return cols

