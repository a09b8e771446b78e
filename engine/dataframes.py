"""pandas DataFrames of a recording's samples and of its epoch/day/night tables (the optional
``pandas`` extra: ``pip install 'stillpoint[pandas]'``), as ``stillpoint.read`` and
``stillpoint.tables``.

Time index, by the one rule of ``engine/timezones.py``: when the zone is known (a GENEActiv
header, ``timezone=``, an MCAP made with a zone) the index is UTC (``datetime64[ns, UTC]``,
named ``time``); otherwise it is the device clock, naive (no zone), named ``time_local``, and
``df.attrs["timezone"]`` says "device local time, zone unknown". ``df.attrs`` also holds the
device, the rate and, for ``read``, the calibration applied.

Memory: ``read`` streams the file block by block and holds only the output: every sample
(float32 columns, ~20 bytes a sample with the time: a week at 100 Hz is ~1.2 GB), or with
``resample=HZ`` the resampled rows alone (a week at 1 Hz is ~12 MB). ``tables`` reads the
table files (a week of 5 s epochs: ~120k rows).
"""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Optional

import numpy as np

from stillpoint.engine.core.errors import StillpointError
from stillpoint.engine.core.blocks import PER_SAMPLE_IDLE_SLEEP

PANDAS_HINT = "the DataFrame API needs pandas: pip install 'stillpoint[pandas]'"
MAX_GAP_S = 1.0  # resample: no value is made across a gap in the samples longer than this


def _pandas():
    try:
        import pandas as pd
    except ImportError:
        raise StillpointError(PANDAS_HINT) from None
    return pd


def _index(pd, t_ns: np.ndarray, known: bool):
    idx = pd.DatetimeIndex(np.asarray(t_ns, "datetime64[ns]"), name="time" if known else "time_local")
    return idx.tz_localize("UTC") if known else idx


def _estimate(path, fmt: str, calibrate, timezone, override: bool):
    """The CalibrationEstimate to apply (None: none) for ``calibrate``: False/None (raw g),
    True (an MCAP's logged estimate; a recording's own autocalibration), a
    ``CalibrationEstimate`` or its dict."""
    from stillpoint.engine.calibration.estimate import CalibrationEstimate
    if calibrate is None or calibrate is False:
        return None
    if isinstance(calibrate, CalibrationEstimate):
        return calibrate
    if isinstance(calibrate, dict):
        return CalibrationEstimate.from_dict(calibrate)
    if calibrate is not True:
        raise StillpointError("calibrate= takes True, False, a CalibrationEstimate or its dict")
    if fmt == "mcap":
        from stillpoint.engine.mcap.replay import McapRawSource
        with McapRawSource(path) as src:
            est = src.logged_calibration()
    else:
        from stillpoint.engine.calibration.recording import calibrate_recording
        from stillpoint.engine.timezones import reader_timezone
        tz, _ = reader_timezone(path, fmt, timezone, override)
        est = calibrate_recording(path, open_options={} if tz is None else {"timezone": tz}).estimate
    return est if est.applied else None


class _Resampler:
    """Linear interpolation onto the instants that are multiples of 1/``hz`` (so the grid does
    not depend on how the file is cut into blocks), carrying the last sample of each block into
    the next; no instant is made across a gap longer than ``MAX_GAP_S``."""

    def __init__(self, hz: float):
        if not hz > 0:
            raise StillpointError(f"resample= must be a positive rate in Hz, got {hz!r}")
        self.step = int(round(1e9 / float(hz)))
        self.prev_t: Optional[np.ndarray] = None
        self.prev_v: Optional[np.ndarray] = None

    def push(self, t: np.ndarray, v: np.ndarray):
        if self.prev_t is not None:
            t = np.concatenate([self.prev_t, t])
            v = np.concatenate([self.prev_v, v])
        self.prev_t, self.prev_v = t[-1:], v[-1:]
        if t.shape[0] < 2:
            return np.zeros(0, np.int64), np.zeros((0, v.shape[1]), v.dtype)
        first = -(-int(t[0]) // self.step) * self.step
        grid = np.arange(first, int(t[-1]), self.step, dtype=np.int64)  # t[-1] waits for the next
        if grid.size == 0:
            return grid, np.zeros((0, v.shape[1]), v.dtype)
        k = np.clip(np.searchsorted(t, grid, side="right") - 1, 0, t.shape[0] - 2)
        ok = (t[k + 1] - t[k]) <= MAX_GAP_S * 1e9
        grid, k = grid[ok], k[ok]
        w = ((grid - t[k]) / np.maximum(t[k + 1] - t[k], 1)).astype(np.float64)[:, None]
        out = v[k] + (v[k + 1] - v[k]) * w
        return grid, out.astype(v.dtype)

    def flush(self):
        if self.prev_t is not None and int(self.prev_t[0]) % self.step == 0:
            return self.prev_t.copy(), self.prev_v.copy()
        return np.zeros(0, np.int64), np.zeros((0, 0 if self.prev_v is None else self.prev_v.shape[1]))


def read(path, *, calibrate=False, resample: Optional[float] = None,
         timezone: Optional[str] = None, timezone_override: bool = False):
    """The samples of a recording (.cwa, .bin, .gz of either, or a stillpoint MCAP's raw
    stream) as a DataFrame: ``x``, ``y``, ``z`` (g), ``temperature_c``, and ``gx``, ``gy``,
    ``gz`` (deg/s) for an AX6, ``idle_sleep`` (bool) for an ActiGraph .gt3x (the seconds the
    device slept, its last sample repeated), indexed by time (see the module docstring).

    ``calibrate``: False (raw g, the default); True (an MCAP: the estimate its run applied; a
    recording: its own autocalibration, a first pass over the file; nothing is applied when the
    fit is not usable, and ``attrs["calibration"]`` says why); or a ``CalibrationEstimate``
    (or its dict) to apply. ``resample``: a rate in Hz: every column interpolated linearly onto
    the instants that are multiples of 1/rate (none across gaps longer than 1 s); None keeps
    the samples. ``timezone``: the zone of a .cwa's clock (IANA name or offset), as
    ``process --timezone``; a GENEActiv header's zone stands unless ``timezone_override``."""
    pd = _pandas()
    from stillpoint.drivers import sniff_format
    from stillpoint.engine.recordings import open_recording
    from stillpoint.engine.timezones import reader_timezone
    path = Path(path)
    fmt = sniff_format(path)
    tz, zone = reader_timezone(path, fmt, timezone, timezone_override)
    est = _estimate(path, fmt, calibrate, timezone, timezone_override)
    rs = _Resampler(resample) if resample is not None else None
    times, values = [], []
    src = open_recording(path, **({} if tz is None else {"timezone": tz}))
    try:
        info = src.info
        names = None
        for b in src:
            if b.n == 0:
                continue
            a = b.accel_g()
            temp = b.temperature_per_sample()
            if est is not None:
                a = est.apply(a, temp)
            cols = [a, np.asarray(temp, np.float64)[:, None]]
            g = b.gyro_dps()
            if g is not None:
                cols.append(g)
            idle = b.per_sample.get(PER_SAMPLE_IDLE_SLEEP)
            if idle is not None:
                cols.append(idle.astype(np.float64)[:, None])
            v = np.concatenate(cols, axis=1).astype(np.float32)
            names = names or (["x", "y", "z", "temperature_c"] + (["gx", "gy", "gz"] if g is not None else [])
                              + (["idle_sleep"] if idle is not None else []))
            t = np.asarray(b.time_at(np.arange(b.n)), np.int64)
            if rs is not None:
                t, v = rs.push(t, v)
            times.append(t)
            values.append(v)
        if rs is not None:
            t, v = rs.flush()
            if t.size:
                times.append(t)
                values.append(v.astype(np.float32))
    finally:
        src.close()
    names = names or ["x", "y", "z", "temperature_c"]
    t = np.concatenate(times) if times else np.zeros(0, np.int64)
    v = np.concatenate(values) if values else np.zeros((0, len(names)), np.float32)
    df = pd.DataFrame(v, columns=names, index=_index(pd, t, zone.known))
    if "idle_sleep" in names and rs is None:
        df["idle_sleep"] = df["idle_sleep"] > 0
    df.attrs.update({"path": str(path), "device": info.device_key, "timezone": zone.label,
                     "rate_hz": float(resample) if resample else info.sample_rate_nominal,
                     "calibration": est.to_dict() if est is not None else None})
    return df


def _read_table(pd, path: Path, time_cols: tuple):
    df = pd.read_csv(path, keep_default_na=True)
    for c in time_cols:
        if c in df.columns and df[c].notna().any():
            utc = c.endswith("_utc")
            df[c] = pd.to_datetime(df[c], utc=utc) if utc else pd.to_datetime(
                df[c].astype(str).str.slice(0, 19), errors="coerce")
    return df


def _table_frames(pd, epochs: Path, days: Path) -> dict:
    ep = _read_table(pd, epochs, ("time_utc", "time_local"))
    known = "time_utc" in ep.columns and ep["time_utc"].notna().any()
    ep = ep.set_index("time_utc" if known else "time_local")
    out = {"epochs": ep, "days": _read_table(pd, days, ())}
    nights = days.with_name(days.name[: -len(".days.csv")] + ".nights.csv") \
        if days.name.endswith(".days.csv") else None
    if nights is not None and nights.is_file():
        out["nights"] = _read_table(pd, nights, ())
    for df in out.values():
        df.attrs["timezone"] = "UTC" if known else "device local time, zone unknown"
    return out


def tables(path, *, timezone: Optional[str] = None) -> dict:
    """The epoch and day tables (and the night table when the run wrote one) of a processed
    recording as DataFrames: ``{"epochs": ..., "days": ..., ["nights": ...]}``. The epoch
    table is indexed by ``time_utc`` when the zone is known, else ``time_local`` (naive).

    ``path``: a stillpoint MCAP (the tables beside it, ``<stem>.epochs.csv.gz`` /
    ``<stem>.days.csv``; made from the log in a temporary folder when they are not there), an
    epoch table (``*.epochs.csv.gz``; its day table beside it), or a recording (.cwa/.bin: run
    through ``process`` in batch mode into a temporary folder first)."""
    pd = _pandas()
    from stillpoint.drivers import sniff_format
    from stillpoint.engine.tables import table_paths
    p = Path(path)
    if p.name.endswith(".epochs.csv.gz"):
        stem = p.name[: -len(".epochs.csv.gz")]
        return _table_frames(pd, p, p.with_name(stem + ".days.csv"))
    fmt = sniff_format(p)
    if fmt == "mcap":
        ep, days = table_paths(p)
        if timezone is None and ep.is_file() and days.is_file():
            return _table_frames(pd, ep, days)
        from stillpoint.engine.workflows.tables_from_mcap import tables_from_mcap
        with tempfile.TemporaryDirectory(prefix="stillpoint-tables-") as d:
            ep, days = Path(d) / "t.epochs.csv.gz", Path(d) / "t.days.csv"
            tables_from_mcap(p, ep, days, timezone=timezone)
            return _table_frames(pd, ep, days)
    from stillpoint.engine.run import RunSettings, process_file
    from stillpoint.engine.tables import TablesSettings
    with tempfile.TemporaryDirectory(prefix="stillpoint-tables-") as d:
        out = Path(d) / "run.mcap"
        ep, days = table_paths(out)
        process_file(p, out, RunSettings(mode="batch", timezone=timezone),
                     tables=TablesSettings(ep, days))
        return _table_frames(pd, ep, days)

