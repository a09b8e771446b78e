"""Inputs of the discrepancy workflow: window features from a feature table (CSV), a recording
(.cwa/.bin, through the engine's streaming window operator) or an MCAP log, and the selection of
nonmovement windows with the covariates the sensor model needs (temperature, dT/dt, time).

dT/dt is estimated on the full window sequence (moving windows included, when the input has them)
before still windows are selected: a centred difference of the window temperatures over +-3 min,
linearly interpolated in time; 0 where the neighbouring data are more than 15 min away.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np

from stillpoint.engine.core.errors import RecordingError
from stillpoint.drivers.byteio import check_recording_path

from ..features import WindowFeatures
from .sensor_fit import WindowData

SD_THRESHOLD_G = 0.013  # van Hees 2014 nonmovement criterion (calibration-algorithm.md section 1)
MEAN_LIMIT_G = 2.0  # drops clipped windows (same source)
DTDT_HALF_SPAN_S = 180.0
DTDT_MAX_GAP_S = 900.0
WINDOW_S = 10.0


@dataclass
class PreparedInput:
    data: WindowData  # nonmovement windows, de-duplicated
    windows_total: int
    windows_still: int
    duplicates_dropped: int
    hours: float
    temperature_available: bool
    dtdt_from_all_windows: bool
    source: str
    rate_hz: Optional[float] = None  # sample rate when known (recordings, MCAP logs)
    device: Optional[str] = None
    count_step_g: Optional[np.ndarray] = None  # (3,) quantisation step of the stored values

    def describe(self) -> dict:
        return {"source": self.source, "windows_total": self.windows_total,
                "windows_nonmovement": self.windows_still,
                "duplicates_dropped": self.duplicates_dropped, "hours": round(self.hours, 3),
                "temperature_available": self.temperature_available,
                "dtdt_from_all_windows": self.dtdt_from_all_windows,
                "rate_hz": self.rate_hz, "device": self.device,
                "quantisation_step_mg": (None if self.count_step_g is None else
                                         [round(float(v) * 1000.0, 4) for v in self.count_step_g])}


def temperature_rate(t_s: np.ndarray, temp: np.ndarray, half_span_s: float = DTDT_HALF_SPAN_S,
                     max_gap_s: float = DTDT_MAX_GAP_S) -> np.ndarray:
    """dT/dt (degC/s) at times t_s from the window temperature sequence (vectorised)."""
    ok = np.isfinite(temp)
    out = np.zeros(t_s.shape[0])
    if ok.sum() < 3:
        return out
    ts, tv = t_s[ok], temp[ok]
    lo = np.clip(t_s - half_span_s, ts[0], ts[-1])
    hi = np.clip(t_s + half_span_s, ts[0], ts[-1])
    span = hi - lo
    d = (np.interp(hi, ts, tv) - np.interp(lo, ts, tv)) / np.where(span > 0, span, 1.0)
    # the data bracketing both ends must be close: otherwise we'd difference across a gap
    def gap_at(x):
        j = np.clip(np.searchsorted(ts, x), 1, len(ts) - 1)
        return ts[j] - ts[j - 1]
    good = (span >= half_span_s) & (gap_at(lo) <= max_gap_s) & (gap_at(hi) <= max_gap_s)
    # no gap inside the span either
    first = np.searchsorted(ts, lo)
    last = np.searchsorted(ts, hi)
    cg = np.concatenate([[0.0], np.cumsum(np.diff(ts) > max_gap_s)])
    good &= cg[np.clip(last, 0, len(ts) - 1)] == cg[np.clip(first, 0, len(ts) - 1)]
    out[good] = d[good]
    return out


def prepare(features: WindowFeatures, source: str = "features", sd_threshold: float = SD_THRESHOLD_G,
            already_still: bool = False) -> PreparedInput:
    """Select nonmovement windows (SD < threshold on all axes, |mean| < 2 g), drop consecutive
    duplicates (device on a table), attach temperature, dT/dt and time since start."""
    k = len(features)
    if k == 0:
        raise ValueError("no windows in the input")
    order = np.argsort(features.start_ns, kind="stable")
    f = features.select(order)
    t_s = (f.start_ns - f.start_ns[0]) / 1e9 + WINDOW_S / 2
    temp = np.asarray(f.temperature, np.float64)
    dtdt = temperature_rate(t_s, temp)
    if already_still:
        still = np.all(np.isfinite(f.mean), axis=1)
    else:
        still = (np.all(f.sd < sd_threshold, axis=1) & np.all(np.abs(f.mean) < MEAN_LIMIT_G, axis=1)
                 & np.all(np.isfinite(f.mean), axis=1))
    idx = np.flatnonzero(still)
    dup = np.zeros(idx.shape[0], bool)
    if idx.shape[0] > 1:
        same = np.all(f.mean[idx[1:]] == f.mean[idx[:-1]], axis=1) & (idx[1:] == idx[:-1] + 1)
        dup[1:] = same
    keep = idx[~dup]
    temp_ok = bool(np.all(np.isfinite(temp[keep]))) and keep.size > 0 and float(np.std(temp[keep])) > 0.01
    series_temp = None
    if temp_ok:
        fin = np.isfinite(temp)
        series_temp = np.interp(t_s, t_s[fin], temp[fin]) if not fin.all() else temp
    data = WindowData(mean=f.mean[keep].copy(),
                      temperature=temp[keep] if temp_ok else np.full(keep.size, np.nan),
                      dtdt=dtdt[keep] if temp_ok else np.zeros(keep.size),
                      t_days=t_s[keep] / 86400.0, sd=f.sd[keep].copy(),
                      series_t_s=t_s if temp_ok else None,
                      series_temp=series_temp,
                      series_index=keep if temp_ok else None)
    return PreparedInput(data, k, int(idx.size), int(dup.sum()), float(t_s[-1] + WINDOW_S / 2) / 3600,
                         temp_ok, bool(idx.size < k), source)


def read_feature_table(path) -> WindowFeatures:
    """A CSV of window features: meanx,meany,meanz,sdx,sdy,sdz,temperature (extra columns ignored).
    Window time from ``start_ns`` (ns), ``time_s`` (s) or ``window_index`` (x 10 s), else row order."""
    p = Path(path)
    try:
        with open(p, newline="") as fh:
            reader = csv.reader(fh)
            header = [h.strip().strip('"').lower() for h in next(reader)]
            rows = [r for r in reader if r]
    except (OSError, StopIteration, csv.Error, UnicodeDecodeError) as e:
        raise RecordingError(p, f"cannot read the feature table: {e}") from None
    col = {h: i for i, h in enumerate(header)}
    need = ["meanx", "meany", "meanz", "sdx", "sdy", "sdz"]
    missing = [c for c in need if c not in col]
    if missing:
        raise RecordingError(p, f"feature table lacks columns {missing} (has {header})")

    def column(name, default=None):
        if name not in col:
            return default
        out = np.empty(len(rows))
        for i, r in enumerate(rows):
            try:
                v = r[col[name]].strip().strip('"')
                out[i] = float(v) if v not in ("", "NA", "NaN", "nan") else np.nan
            except (ValueError, IndexError):
                raise RecordingError(p, f"row {i + 2}: column {name!r} is not a number: "
                                        f"{r[col[name]] if col[name] < len(r) else '(missing)'!r}") from None
        return out

    mean = np.column_stack([column("meanx"), column("meany"), column("meanz")])
    sd = np.column_stack([column("sdx"), column("sdy"), column("sdz")])
    temp = column("temperature", np.full(len(rows), np.nan))
    if "start_ns" in col:
        start = column("start_ns").astype(np.int64)
    elif "time_s" in col:
        start = (column("time_s") * 1e9).astype(np.int64)
    elif "window_index" in col:
        start = (column("window_index") * WINDOW_S * 1e9).astype(np.int64)
    else:
        start = None
    if len(rows) == 0:
        raise RecordingError(p, "feature table has no rows")
    return WindowFeatures.from_arrays(mean, sd, temp, start_ns=start)


def sniff_input(path) -> str:
    """"table" for a CSV feature table, else the recording format from the driver's sniffer."""
    p = Path(path)
    check_recording_path(p)
    with open(p, "rb") as fh:
        head = fh.read(256)
    low = head.lower()
    if b"meanx" in low and b"," in low:
        return "table"
    from stillpoint.drivers import sniff_format
    return sniff_format(p)


def load(path, sd_threshold: float = SD_THRESHOLD_G) -> PreparedInput:
    """Read any supported input and prepare its nonmovement windows."""
    kind = sniff_input(path)
    if kind == "table":
        f = read_feature_table(path)
        # GGIR's sphere data are nonmovement windows already: the SD test then keeps every row
        return prepare(f, source=f"feature table {Path(path).name}", sd_threshold=sd_threshold)
    from .sources import stream_features
    sf = stream_features(path)
    what = "MCAP log" if kind == "mcap" else "recording"
    p = prepare(sf.features, source=f"{what} {Path(path).name}", sd_threshold=sd_threshold)
    p.rate_hz, p.device, p.count_step_g = sf.rate_hz, sf.device, sf.count_step_g
    return p
