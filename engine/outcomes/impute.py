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
epochs); ``imputed_days`` reads the finished epoch table back a slice at a time and gives, per
local day, the day values computed on the imputed epochs, each column name ending ``_imputed``:
``enmo_mean_mg_imputed``, ``mad_mean_mg_imputed`` (mean over the day's epochs) and, with a
cut-point set, the band minutes and bout minutes of ``engine.outcomes.daily``.
"""

from __future__ import annotations

import gzip

import numpy as np

SUFFIX = "_imputed"
METRICS = ("enmo_mg", "mad_mg")
_FLAGS = ("nonwear", "clipping", "gap", "qc", "filter_warmup")
SLICE_ROWS = 1 << 15


class AverageDay:
    def __init__(self, epoch_s: float):
        self.per_day = int(round(86400.0 / epoch_s))
        self.rows = 0
        self.sums = {m: np.zeros(self.per_day) for m in METRICS}
        self.counts = {m: np.zeros(self.per_day, np.int64) for m in METRICS}

    def push(self, values: dict, clean: np.ndarray) -> None:
        n = clean.shape[0]
        slot = (self.rows + np.arange(n)) % self.per_day
        for m in METRICS:
            v = values[m]
            ok = clean & np.isfinite(v)
            np.add.at(self.sums[m], slot[ok], v[ok])
            np.add.at(self.counts[m], slot[ok], 1)
        self.rows += n

    @property
    def imputes(self) -> bool:
        """GGIR imputes only a recording longer than one day."""
        return self.rows > self.per_day

    def profile(self, metric: str) -> np.ndarray:
        c = self.counts[metric]
        return np.where(c > 0, self.sums[metric] / np.maximum(c, 1), 0.0)


def _read_slices(path):
    """(dates, enmo, mad, clean) arrays of the epoch table, a slice of rows at a time."""
    with gzip.open(path, "rt", encoding="utf-8") as f:
        head = f.readline().rstrip("\n").split(",")
        col = {c: i for i, c in enumerate(head)}
        while True:
            lines = f.readlines(SLICE_ROWS * 96)
            if not lines:
                return
            cells = [ln.rstrip("\n").split(",") for ln in lines]
            dates = np.array([c[col["time_local"]][:10] for c in cells])

            def num(name):
                return np.array([float(c[col[name]]) if c[col[name]] else np.nan for c in cells])

            flags = np.zeros(len(cells), bool)
            for fl in _FLAGS:
                flags |= np.array([c[col[fl]] == "1" for c in cells])
            yield dates, num("enmo_mg"), num("mad_mg"), ~flags


def imputed_days(epochs_path, average: AverageDay, epoch_s: float, outcomes=None) -> dict:
    """date -> {column: value} of the day values on imputed epochs; {} when GGIR would not
    impute (a recording of one day or less)."""
    if not average.imputes:
        return {}
    prof = {m: average.profile(m) for m in METRICS}
    out: dict = {}
    row = 0
    day, parts = None, []

    def finish(date, parts):
        e = np.concatenate([p[0] for p in parts])
        m = np.concatenate([p[1] for p in parts])
        d = {"enmo_mean_mg" + SUFFIX: float(e.mean()), "mad_mean_mg" + SUFFIX: float(m.mean())}
        if outcomes is not None and outcomes.cut is not None:
            v = e if outcomes.cut.column == "enmo_mg" else m
            for name, val in outcomes.day(v, np.ones(v.shape[0], bool), np.zeros(v.shape[0], np.int64),
                                          {}).items():
                if name.startswith(("min_", "bout_min_")):
                    d[name + SUFFIX] = val
        out[date] = d

    for dates, enmo, mad, clean in _read_slices(epochs_path):
        n = dates.shape[0]
        slot = (row + np.arange(n)) % average.per_day
        row += n
        e = np.where(clean & np.isfinite(enmo), enmo, prof["enmo_mg"][slot])
        m = np.where(clean & np.isfinite(mad), mad, prof["mad_mg"][slot])
        cuts = np.flatnonzero(dates[1:] != dates[:-1]) + 1
        for a, b in zip(np.r_[0, cuts], np.r_[cuts, n]):
            if day is not None and dates[a] != day:
                finish(day, parts)
                parts = []
            day = str(dates[a])
            parts.append((e[a:b], m[a:b]))
    if day is not None:
        finish(day, parts)
    return out


def imputed_columns(outcomes=None) -> list:
    cols = ["enmo_mean_mg" + SUFFIX, "mad_mean_mg" + SUFFIX]
    if outcomes is not None and outcomes.cut is not None:
        cols += [c + SUFFIX for c in outcomes.base_day_columns()
                 if c.startswith(("min_", "bout_min_"))]
    return cols

