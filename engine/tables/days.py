"""The day table: one row per local calendar day (midnight to midnight in the participant's zone)
and a file summary row, from the epoch rows as they stream.

Only **clean** epochs (no flag: nonwear, clipping, gap, qc, filter_warmup) enter the means, the
intensity minutes, MVPA and M10/L5; ``wear_hours`` counts clean epochs. Per day:

* ``day_hours``: the local day's length (23 or 25 at DST changes with an IANA zone; 24 otherwise);
  ``recorded_hours``: the part of it inside the recording; ``data_hours``: epochs with data;
  ``nonwear_hours``, ``clipping_hours``, ``qc_hours``: epochs with data and that flag;
* ``valid_day``: ``wear_hours >= valid_day_hours`` (default 16);
* ``enmo_mean_mg``, ``mad_mean_mg``: mean ENMO and mean MAD over clean epochs;
* ``min_enmo_<a>_<b>mg``: minutes of clean epochs with a <= ENMO < b for the band edges (default
  40/100/400 mg, GGIR's common light/moderate/vigorous thresholds);
* ``mvpa_bout_min``: minutes in runs of consecutive clean epochs with ENMO >= the MVPA threshold
  (the second band edge, 100 mg) lasting at least ``mvpa_bout_s`` (60 s); every epoch of the run
  must meet it (GGIR's bout rules tolerate 20 % below);
* ``m10_mg`` / ``l5_mg``: GGIR's M10 and L5: the highest mean ENMO over 10 consecutive hours and
  the lowest over 5, windows starting every 10 min inside the day (one past the day's end
  completed from its first hours, as GGIR); a window counts when at least half of its epochs are
  clean (GGIR imputes the rest from the average day instead), on valid days only;
  ``m10_start`` / ``l5_start``: local clock time of the window start; ``ra``: the day's relative
  amplitude (M10 - L5) / (M10 + L5);
* ``data_coverage`` / ``qc_coverage``: data hours and QC-flagged hours over ``day_hours``.

With activity outcomes (``engine.outcomes.daily``: a cut-point set's minutes per band and GGIR
bouts per band, steps per day and peak cadence) their columns follow, computed from the same
day's epochs.

The summary row (``date`` = ``all``) sums the hours, counts valid days in ``valid_day``, gives the
mean ENMO and MAD over every clean epoch of the file, and the minutes per band, MVPA and M10/L5 averaged
over valid days (empty when there is none), as are the outcome columns.
Every row also carries the time zone used, the calibration status and ``calibration_source``: the
estimate the numbers were corrected with (``recording_final``, ``prior``, ``static`` or ``none``;
``engine.calibration.estimate.calibration_source``).
"""

from __future__ import annotations

import datetime as _dt
from typing import Optional

import numpy as np

from ..timezones import Zone
from .epochs import EpochRows

DAY_NS = 86400 * 10**9
VALID_DAY_HOURS = 16.0
ENMO_BANDS_MG = (40.0, 100.0, 400.0)
MVPA_BOUT_S = 60.0
M_STEP_S = 600.0  # GGIR M5L5res: windows every 10 min
MIN_WINDOW_CLEAN = 0.5


def _band_names(bands) -> list[str]:
    edges = [0.0] + [float(b) for b in bands]
    names = []
    for i, lo in enumerate(edges):
        hi = edges[i + 1] if i + 1 < len(edges) else None
        names.append(f"min_enmo_{lo:g}_{hi:g}mg" if hi is not None else f"min_enmo_ge{lo:g}mg")
    return names


def day_columns(bands=ENMO_BANDS_MG) -> list[str]:
    return (["date", "day_hours", "recorded_hours", "data_hours", "wear_hours", "nonwear_hours",
             "clipping_hours", "qc_hours", "valid_day", "enmo_mean_mg", "mad_mean_mg"] +
            _band_names(bands) +
            ["mvpa_bout_min", "m10_mg", "m10_start", "l5_mg", "l5_start", "ra", "data_coverage",
             "qc_coverage", "timezone", "calibration", "calibration_source"])


def m_window(e, clean, local, hours, pick, epoch_s, start_of_day_ns=None):
    """GGIR's M10 / L5 of one day (``g.getM5L5`` as ``g.analyse.perday`` calls it,
    R/g.analyse.perday.R:509-518, R/g.getM5L5.R:7-37): the mean of ``hours`` consecutive hours
    starting every 10 min from the day's first epoch, the starts running to 20 min before the
    day's end (``last_hri``) and a window past the day's end completed from the day's own first
    epochs (``einclude``, line 22); ties: the middle start. ``pick`` is ``np.argmax`` (M10) or
    ``np.argmin`` (L5). Needs a day of more than 1.2 ``hours`` and a positive mean (GGIR's
    ``do.M5L5``). A window counts when at least half its epochs are clean (the mean is over
    those); on imputed epochs every epoch is clean. Returns (value, ``HH:MM`` start): the local
    clock of the start epoch, or with ``start_of_day_ns`` the time from it (an imputed day padded
    to 24 h from midnight, as GGIR reports it)."""
    n = len(e)
    epm = 60.0 / epoch_s
    if n <= epm * 60 * hours * 1.2:
        return None, None
    x = np.where(clean, e, 0.0)
    if not np.any(clean) or x.sum() / max(int(clean.sum()), 1) <= 0:
        return None, None
    res = M_STEP_S / 60.0  # M5L5res, minutes
    t1 = n / (60 * epm) + (hours - res / 60)
    rows = int((t1 - hours) * (60 / res))  # R's matrix(NA, nwindow_f) truncates
    last = min(rows, int(np.floor((t1 - hours) * (60 / res) - 1)))
    if rows < 1 or last < 0:
        return None, None
    hri = np.arange(0, last + 1)
    e1 = np.round(hri * res * epm).astype(np.int64)  # 0-based first epoch
    e2 = np.round((hri + hours * (60 / res)) * res * epm).astype(np.int64)  # exclusive end
    xx = np.concatenate([x, x])  # a window past the end wraps to the day's first epochs
    cc = np.concatenate([clean, clean]).astype(np.int64)
    cs = np.concatenate([[0.0], np.cumsum(xx)])
    cn = np.concatenate([[0], np.cumsum(cc)])
    w = e2 - e1
    cnt = cn[e2] - cn[e1]
    ok = cnt >= MIN_WINDOW_CLEAN * w
    if not ok.any():
        return None, None
    mean = np.where(ok, (cs[e2] - cs[e1]) / np.maximum(cnt, 1), np.nan)
    best = np.nanmax(mean) if pick is np.argmax else np.nanmin(mean)
    # windows of the same mean: R compares its means exactly, and equal stretches (imputed or
    # still epochs) give exactly equal means there; running sums differ in the last bits
    ties = np.flatnonzero(np.abs(mean - best) <= 1e-10 * abs(best) + 1e-12)
    i = int(ties[int(np.ceil(ties.shape[0] / 2)) - 1])  # sort(...)[ceiling(n / 2)]
    if start_of_day_ns is None:
        t = int(local[e1[i]] % DAY_NS) // 10**9
    else:
        t = int(round(e1[i] * epoch_s))
    return float(mean[i]), f"{t // 3600:02d}:{(t // 60) % 60:02d}"


def relative_amplitude(m10, l5):
    """(M10 - L5) / (M10 + L5) (van Someren 1999); None without both or when both are 0."""
    if m10 is None or l5 is None or (m10 + l5) == 0:
        return None
    return (m10 - l5) / (m10 + l5)


def _runs(mask: np.ndarray):
    """(start, length) of the runs of True."""
    d = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    s = np.flatnonzero(d == 1)
    e = np.flatnonzero(d == -1)
    return s, e - s


class DayAccumulator:
    def __init__(self, zone: Zone, epoch_s: float, *, valid_day_hours: float = VALID_DAY_HOURS,
                 bands=ENMO_BANDS_MG, mvpa_bout_s: float = MVPA_BOUT_S, calibration: str = "",
                 outcomes=None):
        self.zone = zone
        self.epoch_s = float(epoch_s)
        self.epoch_h = self.epoch_s / 3600.0
        self.valid_day_hours = float(valid_day_hours)
        self.bands = tuple(float(b) for b in bands)
        self.mvpa_mg = self.bands[1] if len(self.bands) > 1 else self.bands[0]
        self.mvpa_bout_s = float(mvpa_bout_s)
        self.calibration = calibration
        self.outcomes = outcomes  # engine.outcomes.daily.DailyOutcomes or None
        self.columns = day_columns(self.bands) + (outcomes.day_columns() if outcomes else [])
        self._day: Optional[int] = None
        self._parts: list[EpochRows] = []
        self._steps: list[dict] = []
        self._local: list[np.ndarray] = []
        self.days: list[dict] = []
        # epoch-level totals (for the summary and the day-sum = epoch-sum check); the sums are
        # added day by day (``_finish``), so they do not depend on how the rows came in
        self.totals = {"epochs": 0, "clean": 0, "enmo_clean_sum": 0.0, "mad_clean_sum": 0.0}

    # ------------------------------------------------------------------ streaming
    def push(self, rows: EpochRows, steps: Optional[dict] = None) -> None:
        """``steps``: per-row step counts by parameter set (with step outcomes)."""
        if not len(rows):
            return
        local = self.zone.local_ns(rows.start_ns) if self.zone.known else rows.start_ns.copy()
        day = np.floor_divide(local, DAY_NS)
        self.totals["epochs"] += len(rows)
        c = rows.clean
        self.totals["clean"] += int(c.sum())
        cuts = np.flatnonzero(np.diff(day)) + 1
        for a, b in zip(np.r_[0, cuts], np.r_[cuts, len(rows)]):
            d = int(day[a])
            if self._day is not None and d != self._day:
                self._finish()
            self._day = d
            self._parts.append(_slice(rows, a, b))
            self._local.append(local[a:b])
            self._steps.append({k: v[a:b] for k, v in (steps or {}).items()})

    def close(self) -> list[dict]:
        if self._day is not None:
            self._finish()
        return self.days

    # ------------------------------------------------------------------ one day
    def _day_hours(self, d: int) -> float:
        if self.zone.iana:
            return (self.zone.utc_of_local_midnight_ns(d + 1) -
                    self.zone.utc_of_local_midnight_ns(d)) / 3.6e12
        return 24.0

    def _finish(self) -> None:
        r = EpochRows.concat(self._parts)
        local = np.concatenate(self._local)
        steps = {k: np.concatenate([p[k] for p in self._steps]) for k in
                 (self._steps[0] if self._steps else {})}
        d = self._day
        self._parts, self._local, self._steps, self._day = [], [], [], None
        h = self.epoch_h
        has = ~r.gap
        clean = r.clean
        e = r.enmo_mg
        row = {
            "date": (_dt.date(1970, 1, 1) + _dt.timedelta(days=d)).isoformat(),
            "day_hours": self._day_hours(d),
            "recorded_hours": len(r) * h,
            "data_hours": int(has.sum()) * h,
            "wear_hours": int(clean.sum()) * h,
            "nonwear_hours": int((r.nonwear & has).sum()) * h,
            "clipping_hours": int((r.clipping & has).sum()) * h,
            "qc_hours": int((r.qc & has).sum()) * h,
        }
        row["valid_day"] = int(row["wear_hours"] >= self.valid_day_hours - 1e-9)
        row["enmo_mean_mg"] = float(e[clean].mean()) if clean.any() else None
        row["mad_mean_mg"] = float(r.mad_mg[clean].mean()) if clean.any() else None
        self.totals["enmo_clean_sum"] += float(np.nansum(e[clean]))
        self.totals["mad_clean_sum"] += float(np.nansum(r.mad_mg[clean]))
        edges = [0.0] + list(self.bands) + [np.inf]
        for name, lo, hi in zip(_band_names(self.bands), edges[:-1], edges[1:]):
            row[name] = int((clean & (e >= lo) & (e < hi)).sum()) * self.epoch_s / 60.0
        s, n = _runs(clean & (e >= self.mvpa_mg))
        long = n * self.epoch_s >= self.mvpa_bout_s - 1e-9
        row["mvpa_bout_min"] = float(n[long].sum()) * self.epoch_s / 60.0
        for key, hours, pick in (("m10", 10.0, np.argmax), ("l5", 5.0, np.argmin)):
            val, start = (self._window(e, clean, local, hours, pick) if row["valid_day"]
                          else (None, None))
            row[f"{key}_mg"], row[f"{key}_start"] = val, start
        row["ra"] = relative_amplitude(row["m10_mg"], row["l5_mg"])
        dh = row["day_hours"]
        row["data_coverage"] = row["data_hours"] / dh
        row["qc_coverage"] = row["qc_hours"] / dh
        row["timezone"] = self.zone.label
        row["calibration"] = self.calibration
        if self.outcomes is not None:
            row.update(self.outcomes.day(getattr(r, self.outcomes.cut.column)
                                         if self.outcomes.cut else r.enmo_mg, clean, local, steps))
        self.days.append(row)

    def _window(self, e, clean, local, hours, pick):
        return m_window(e, clean, local, hours, pick, self.epoch_s)

    # ------------------------------------------------------------------ summary
    def summary(self) -> dict:
        valid = [d for d in self.days if d["valid_day"]]
        row = {"date": "all"}
        for k in ("day_hours", "recorded_hours", "data_hours", "wear_hours", "nonwear_hours",
                  "clipping_hours", "qc_hours"):
            row[k] = float(sum(d[k] for d in self.days))
        row["valid_day"] = len(valid)
        clean = self.totals["clean"]
        row["enmo_mean_mg"] = self.totals["enmo_clean_sum"] / clean if clean else None
        row["mad_mean_mg"] = self.totals["mad_clean_sum"] / clean if clean else None
        for k in _band_names(self.bands) + ["mvpa_bout_min", "m10_mg", "l5_mg", "ra"]:
            v = [d[k] for d in valid if d[k] is not None]
            row[k] = float(np.mean(v)) if v else None
        row["m10_start"] = row["l5_start"] = None
        row["data_coverage"] = row["data_hours"] / row["day_hours"] if row["day_hours"] else None
        row["qc_coverage"] = row["qc_hours"] / row["day_hours"] if row["day_hours"] else None
        row["timezone"] = self.zone.label
        row["calibration"] = self.calibration
        if self.outcomes is not None:
            for k in self.outcomes.day_columns():
                v = [d[k] for d in valid if d.get(k) is not None]
                numeric = not k.endswith("_start_imputed")  # a clock time has no mean here
                row[k] = float(np.mean(v)) if (v and numeric) else None
        return row


def _slice(r: EpochRows, a: int, b: int) -> EpochRows:
    from dataclasses import fields
    return EpochRows(**{f.name: (None if getattr(r, f.name) is None else getattr(r, f.name)[a:b])
                        for f in fields(EpochRows)})
