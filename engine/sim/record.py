"""Streaming generation of simulated recordings: one or two devices on one body, written as real
.cwa/.bin files through the project's writers, plus the ground truth (JSON + per-10 s-window
label CSV).

API
---
``simulate_recording(path, device="ax3", site="wrist", days=7, hz=100, effects=None, seed=1,
truth_path=None, ...) -> Truth`` writes one file (+ truth) and returns the truth.
``simulate_pair(path_a, path_b, site_a="wrist", site_b="hip", ...) -> (Truth, Truth)``: two
devices driven by the same movement (same step times), each with its own sensor errors and clock.
``DeviceSim`` / ``make_devices(...)``: the in-memory generator; ``DeviceSim.chunks()`` yields
``SimChunk``s (true time, device time, true and measured acceleration, counts) without a file.

Determinism: the body schedule, every per-segment orientation, the slow tracks (temperature,
clock, bias) and the sensor's parameters come from the seed; the white noise of chunk k (one hour
of true time) comes from SeedSequence((seed, 3, device index, k)). Same seed -> same bytes.
Memory: one hour of samples per device at a time (100 Hz: 360k samples, ~60 MB of temporaries),
plus the slow tracks (one value per 10 s).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Iterator, Optional, Sequence, Union

import numpy as np

from .clock import ClockModel, make_clock
from .model import (DEFAULT_EFFECTS, ModelError, SensorModel, _jsonable, first_order_lag,
                    load_model, resolve_model)
from .sensor import DeviceSpec, bias_track, measure
from .temperature import TRACK_STEP_S, TemperatureParams, temperature_track
from .wearer import ACTIVITIES, MOTIONS, POSTURES, SITES, Schedule, SiteModel, WearerParams, make_schedule

CHUNK_S = 3600.0  # one hour of true time: the unit of generation and of the noise seeds
WINDOW_S = 10.0  # label windows
TRUTH_FORMAT = "stillpoint.sim_truth"
DEFAULT_START = "2025-03-03T10:00:00+00:00"  # a Monday, 10:00 (device handed out)
_NS = 1_000_000_000
GYRO_NOISE_DPS_RTHZ = 0.007  # BMI160 datasheet gyro noise density
GYRO_BIAS_SD_DPS = 0.5  # zero-rate offset spread (BMI160: +-3 deg/s max), not a named accel effect


def build_model(effects=None, *, model=None, overrides: Sequence = ()) -> SensorModel:
    """Combine a base model (SensorModel, dict or JSON path), a list of effect names (list,
    comma-separated string, "none", "default"), and (name, params) overrides."""
    base = SensorModel()
    if model is not None:
        if isinstance(model, SensorModel):
            base = model
        elif isinstance(model, dict):
            base = SensorModel.from_dict(model if "effects" in model else {"effects": model})
        else:
            base = load_model(model)
    names: list[str] = []
    if effects is None and model is None:
        names = list(DEFAULT_EFFECTS)
    elif isinstance(effects, SensorModel):
        base = effects
    elif isinstance(effects, dict):
        base = SensorModel.from_dict(effects if "effects" in effects else {"effects": effects})
    elif effects is not None:
        items = effects.split(",") if isinstance(effects, str) else list(effects)
        for it in items:
            it = it.strip()
            if not it or it.lower() == "none":
                continue
            if it.lower() == "default":
                names.extend(DEFAULT_EFFECTS)
            else:
                names.append(it)
    m = base
    for n in names:
        m = m.with_effect(n)
    for name, params in overrides:
        m = m.with_effect(name, **params)
    return m


@dataclass
class SimChunk:
    """One hour (or less) of one device's samples."""

    index: int
    true_s: np.ndarray  # (n,) true time since the start, s
    time_ns: np.ndarray  # (n,) int64 device-clock time, ns since the Unix epoch (what the file holds)
    true_g: np.ndarray  # (n, 3) true specific force in the device frame, g
    measured_g: np.ndarray  # (n, 3) what the sensor measured before quantisation, g
    counts: np.ndarray  # (n, 3) int32 stored counts
    gyro_counts: Optional[np.ndarray]  # (n, 3) int16 (AX6 with gyro)
    temperature_c: np.ndarray  # (n,) temperature-sensor value at each sample
    restarts: list = field(default_factory=list)  # positions p: restart logging before sample p

    @property
    def n(self) -> int:
        return int(self.true_s.shape[0])


@dataclass
class Truth:
    """Everything the simulation knows; ``to_dict`` is the truth JSON."""

    path: Optional[str]
    device: dict
    site: str
    seed: int
    start_ns: int
    duration_s: float
    rate_hz_nominal: float
    rate_hz_true: float
    sensor_model: SensorModel
    clock: dict
    wearer: dict
    temperature: dict
    samples_written: int = 0
    corrupt_sectors: list = field(default_factory=list)
    labels_path: Optional[str] = None
    truth_path: Optional[str] = None
    summary: dict = field(default_factory=dict)
    pair: Optional[dict] = None

    def to_dict(self) -> dict:
        return _jsonable({
            "format": TRUTH_FORMAT, "version": 1, "path": self.path, "device": self.device,
            "site": self.site, "seed": self.seed, "start_ns": self.start_ns,
            "start_utc": _iso(self.start_ns), "duration_s": self.duration_s,
            "rate_hz_nominal": self.rate_hz_nominal, "rate_hz_true": self.rate_hz_true,
            "samples_written": self.samples_written, "sensor_model": self.sensor_model.to_dict(),
            "clock": self.clock, "corrupt_sectors": self.corrupt_sectors,
            "labels": {"path": self.labels_path, "window_s": WINDOW_S,
                       "columns": list(LABEL_COLUMNS), "activities": list(ACTIVITIES),
                       "postures": list(POSTURES), "motions": list(MOTIONS)},
            "wearer": self.wearer, "temperature": self.temperature, "summary": self.summary,
            "pair": self.pair})

    def save(self, path) -> None:
        Path(path).write_text(json.dumps(self.to_dict(), indent=1) + "\n")

    @property
    def labels(self) -> Optional[dict]:
        """Per-window labels as arrays (read from the labels CSV; kept in memory when no truth
        files were written)."""
        if getattr(self, "_labels", None) is None and self.labels_path:
            self._labels = load_labels(self.labels_path)
        return getattr(self, "_labels", None)


def _iso(ns: int) -> str:
    return datetime.fromtimestamp(ns / 1e9, tz=timezone.utc).isoformat(timespec="microseconds")


def load_truth(path) -> dict:
    """The truth JSON as a dict (``sensor_model`` is loadable with SensorModel.from_dict)."""
    d = json.loads(Path(path).read_text())
    if d.get("format") != TRUTH_FORMAT:
        raise ModelError(f"{path}: not a simulator truth file")
    return d


def truth_device_time(truth: dict, true_s) -> np.ndarray:
    """Device clock (ns since the epoch) at true times (s since the start), from a truth dict."""
    c = truth["clock"]
    t = np.asarray(true_s, np.float64)
    d = t + np.interp(t, np.asarray(c["table"]["true_s"]), np.asarray(c["table"]["device_minus_true_s"]))
    return truth["start_ns"] + np.round(d * 1e9).astype(np.int64)


def relative_clock_s(truth_a: dict, truth_b: dict, true_s) -> np.ndarray:
    """Device B's clock minus device A's clock (s) at true times (s since the common start): the
    lag an alignment method should find between two devices of a pair (truth dicts)."""
    return (truth_device_time(truth_b, true_s) - truth_device_time(truth_a, true_s)) / 1e9


LABEL_COLUMNS = ("window", "true_start_s", "device_start_ns", "samples", "still", "activity",
                 "posture", "motion", "temperature_c", "accel_temperature_c", "true_mean_x",
                 "true_mean_y", "true_mean_z", "true_sd_x", "true_sd_y", "true_sd_z")


def load_labels(path) -> dict:
    """Per-window labels CSV -> dict of numpy arrays (columns as in LABEL_COLUMNS)."""
    with open(path) as f:
        header = f.readline().strip().split(",")
    data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    out = {}
    for i, name in enumerate(header):
        col = data[:, i]
        out[name] = col.astype(np.int64) if name in ("window", "device_start_ns", "samples", "still",
                                                      "activity", "posture", "motion") else col
    return out


def _grid_pos(t: np.ndarray, n_grid: int):
    """Index and fraction of times t on the regular TRACK_STEP_S grid (linear interpolation)."""
    x = t * (1.0 / TRACK_STEP_S)
    gi = np.minimum(x.astype(np.int64), n_grid - 2)
    return gi, x - gi


def _lerp(v: np.ndarray, gi: np.ndarray, fr: np.ndarray) -> np.ndarray:
    a = v[gi]
    return a + fr * (v[gi + 1] - a)


# ----------------------------------------------------------------------------- one device
class DeviceSim:
    """One simulated device on the body (see the module docstring)."""

    def __init__(self, schedule: Schedule, *, site: str, spec: DeviceSpec, model: SensorModel,
                 seed: int, dev_index: int, hz: float, duration_s: float, start_ns: int,
                 temperature: TemperatureParams = None, device_id: int = 0):
        self.schedule = schedule
        self.site = site
        self.spec = spec
        self.seed = int(seed)
        self.dev_index = int(dev_index)
        self.hz = float(hz)
        self.duration_s = float(duration_s)
        self.start_ns = int(start_ns)
        self.device_id = int(device_id)
        self.tparams = temperature or TemperatureParams()
        dev_seed = int(np.random.SeedSequence([self.seed, 2, self.dev_index]).generate_state(1)[0])
        self.model = resolve_model(model, seed=dev_seed, device=spec.kind, duration_s=duration_s)
        if spec.kind == "geneactiv" and self.model.on("restarts"):
            raise ModelError("restarts: a GENEActiv cannot restart logging within one file")
        self.site_model = SiteModel(schedule, site, self.seed)
        self.t_grid, self.T_grid = temperature_track(schedule, site, self.tparams, self.seed, duration_s)
        self.Ta_grid = (first_order_lag(self.T_grid, self.t_grid, float(self.model.get("thermal_lag", "tau_s")))
                        if self.model.on("thermal_lag") else self.T_grid)
        self.bias_grid = bias_track(self.model, self.t_grid, dev_seed)
        self._bias_axes = np.ascontiguousarray(self.bias_grid.T)
        self.clock: ClockModel = make_clock(self.model, self.t_grid, self.T_grid, self.hz)
        r = np.random.default_rng(np.random.SeedSequence([self.seed, 4, self.dev_index]))
        self.gyro_bias = r.normal(0, GYRO_BIAS_SD_DPS, 3)
        self.n_slots = int(np.ceil(duration_s * self.clock.rate_true_hz))
        self.light_grid = self.light_raw(self.t_grid)
        self.n_chunks = int(np.ceil(duration_s / CHUNK_S))

    # --------------------------------------------------------------- chunks
    def _render(self, k: int):
        """Stage 1 of chunk k (pure, thread-safe): sample times and the true motion."""
        rate = self.clock.rate_true_hz
        i0 = int(np.ceil(k * CHUNK_S * rate))
        i1 = min(self.n_slots, int(np.ceil((k + 1) * CHUNK_S * rate)))
        if i1 <= i0:
            return None
        t, keep = self.clock.sample_times(i0, i1)
        # restarts: first kept sample after each restart gap
        restarts = []
        for a, b in self.clock.restarts:
            if t.size and t[0] <= b <= t[-1] + 1.0 / rate:
                pos = int(np.searchsorted(t, b, side="left"))
                restarts.append(int(np.count_nonzero(keep[:pos])))
        t = t[keep]
        gyro = self.spec.kind == "ax6" and self.spec.gyro_range_dps is not None
        f, w = self.site_model.render(t, gyro=gyro, dtype=np.float32)
        return t, f, w, sorted(set(restarts))

    def _measure(self, k: int, rendered) -> SimChunk:
        """Stage 2 of chunk k: the sensor (noise from chunk k's own seed) and the device clock."""
        t, f, w, restarts = rendered
        gi, fr = _grid_pos(t, self.t_grid.shape[0])
        T = _lerp(self.T_grid, gi, fr)
        Ta = _lerp(self.Ta_grid, gi, fr) if self.Ta_grid is not self.T_grid else T
        bias = None
        if self.model.on("bias_instability"):
            bias = np.empty((t.shape[0], 3), np.float32)
            for j in range(3):  # 1-D gathers from contiguous per-axis tracks (2-D gathers are slow)
                bias[:, j] = _lerp(self._bias_axes[j], gi, fr)
        rng = np.random.default_rng(np.random.SeedSequence([self.seed, 3, self.dev_index, k]))
        meas, counts = measure(f, self.model, self.spec, temperature_c=T, time_s=t,
                               accel_temperature_c=Ta, bias_g=bias, rng=rng, rate_hz=self.hz)
        gcounts = None
        if w is not None:
            w = w + self.gyro_bias + rng.standard_normal(w.shape) * (GYRO_NOISE_DPS_RTHZ * np.sqrt(self.hz / 2))
            gcounts = self.spec.gyro_to_counts(w)
        d = t + _lerp(self.clock.offset_s, gi, fr)
        time_ns = self.start_ns + np.round(d * 1e9).astype(np.int64)
        return SimChunk(k, t, time_ns, f, meas, counts, gcounts, T, restarts)

    def chunk(self, k: int) -> Optional[SimChunk]:
        """Chunk k (one hour of true time), or None past the end."""
        r = self._render(k)
        return None if r is None else self._measure(k, r)

    def chunks(self, prefetch: bool = True) -> Iterator[SimChunk]:
        """All chunks in order. With ``prefetch`` the motion of chunk k+1 is rendered in a
        worker thread while chunk k is measured and consumed (numpy releases the GIL; the
        output is identical either way)."""
        if not prefetch or self.n_chunks < 2:
            for k in range(self.n_chunks):
                c = self.chunk(k)
                if c is not None and c.n:
                    yield c
            return
        from concurrent.futures import ThreadPoolExecutor
        with ThreadPoolExecutor(max_workers=1) as ex:
            fut = ex.submit(self._render, 0)
            for k in range(self.n_chunks):
                r = fut.result()
                if k + 1 < self.n_chunks:
                    fut = ex.submit(self._render, k + 1)
                if r is None:
                    continue
                c = self._measure(k, r)
                if c.n:
                    yield c

    # --------------------------------------------------------------- aux channels
    def light_raw(self, t: np.ndarray) -> np.ndarray:
        """Light ADC per sample from a simple lux model (day/night, indoors/outdoors, drawer)."""
        sch = self.schedule
        seg = sch.segment_at(t)
        act = sch.activity[seg]
        hour = (sch.start_hour + t / 3600.0) % 24.0
        day = np.clip(np.sin(np.pi * (hour - 6.0) / 14.0), 0.0, None)
        lux = np.where(day > 0, 50.0 + 400.0 * day, 2.0)
        lux = np.where(np.isin(act, (6, 7)), 200.0 + 8000.0 * day, lux)  # outdoors when walking/running
        lux = np.where(act == 1, 0.5, lux)  # drawer
        lux = np.where(act == 2, 1.0, lux)  # asleep, dark
        if self.spec.kind == "geneactiv":
            return np.clip(np.rint(lux * 300.0 / 800.0), 0, 1023).astype(np.int64)
        # AX: lux = 10^((raw + 512) * 6 / 1024)  (cwa-format.md §9)
        raw = np.log10(np.maximum(lux, 1e-3)) * 1024.0 / 6.0 - 512.0
        return np.clip(np.rint(raw), 0, 1023).astype(np.int64)

    def battery_v(self, t: np.ndarray) -> np.ndarray:
        return 4.15 - 0.35 * np.clip(t / max(self.duration_s, 1.0), 0, 1)

    # --------------------------------------------------------------- labels
    def moving_mask(self) -> np.ndarray:
        """(windows,) bool: the window overlaps movement or a posture transition (schedule)."""
        if getattr(self, "_moving", None) is None:
            sch = self.schedule
            nw = int(np.ceil(self.duration_s / WINDOW_S))
            moving = np.zeros(nw + 2, np.int64)
            a = sch.start
            b = np.where(sch.motion != 0, sch.end, sch.start + sch.trans_s)
            sel = b > a
            ia = np.clip((a[sel] // WINDOW_S).astype(np.int64), 0, nw)
            ib = np.clip(((b[sel] - 1e-9) // WINDOW_S).astype(np.int64) + 1, 0, nw)
            np.add.at(moving, ia, 1)
            np.add.at(moving, ib, -1)
            self._moving = np.cumsum(moving)[:nw] > 0
        return self._moving

    def labels(self, sums: np.ndarray, sq: np.ndarray, counts: np.ndarray, first_window: int = 0) -> dict:
        """Labels of windows first_window .. first_window + len(counts) - 1; sums/sq/counts are
        the accumulated true specific force of those windows."""
        sch = self.schedule
        nw = counts.shape[0]
        win = first_window + np.arange(nw)
        w0 = win * WINDOW_S
        expected = WINDOW_S * self.clock.rate_true_hz
        full = counts >= np.floor(expected) - 1
        still = (~self.moving_mask()[win]) & full
        mid = w0 + 0.5 * WINDOW_S
        seg = sch.segment_at(mid)
        T = np.interp(mid, self.t_grid, self.T_grid)
        Ta = np.interp(mid, self.t_grid, self.Ta_grid)
        with np.errstate(invalid="ignore", divide="ignore"):
            mean = sums / counts[:, None]
            var = (sq - counts[:, None] * mean * mean) / np.maximum(counts[:, None] - 1, 1)
        sd = np.sqrt(np.clip(var, 0, None))
        dev_ns = self.start_ns + np.round(self.clock.device_time(w0) * 1e9).astype(np.int64)
        return {"window": win, "true_start_s": w0, "device_start_ns": dev_ns,
                "samples": counts, "still": still.astype(np.int64),
                "activity": sch.activity[seg].astype(np.int64),
                "posture": sch.posture[seg].astype(np.int64),
                "motion": sch.motion[seg].astype(np.int64), "temperature_c": T,
                "accel_temperature_c": Ta, "true_mean_x": mean[:, 0], "true_mean_y": mean[:, 1],
                "true_mean_z": mean[:, 2], "true_sd_x": sd[:, 0], "true_sd_y": sd[:, 1],
                "true_sd_z": sd[:, 2]}

    def still_windows(self) -> dict:
        """The truly still 10 s windows without rendering any sample (fast: for window-level
        studies such as the discrepancy workflow's): true start (s), device-clock start (ns),
        the gravity vector in the device frame (k, 3) g, temperature and accelerometer
        temperature (degC). Same windows and vectors as ``labels`` gives for a full run
        (windows cut by a halt or restart excepted)."""
        sch = self.schedule
        nw = int(np.ceil(self.duration_s / WINDOW_S))
        full = np.full(nw, int(np.floor(WINDOW_S * self.clock.rate_true_hz)))
        lab = self.labels(np.zeros((nw, 3)), np.zeros((nw, 3)), full)
        idx = np.nonzero(lab["still"] == 1)[0]
        w0 = idx * WINDOW_S
        for a, b in self.clock.gaps():  # windows touching a halt/restart gap are not full
            idx = idx[(w0 + WINDOW_S <= a) | (w0 >= b)]
            w0 = idx * WINDOW_S
        seg = sch.segment_at(w0 + 0.5 * WINDOW_S)
        grav = np.empty((idx.shape[0], 3))
        for i in np.unique(seg):
            grav[seg == i] = self.site_model.params(int(i)).R_base[2, :]
        return {"window": idx, "true_start_s": w0, "device_start_ns": lab["device_start_ns"][idx],
                "gravity": grav, "temperature_c": lab["temperature_c"][idx],
                "accel_temperature_c": lab["accel_temperature_c"][idx]}

    def clock_truth(self) -> dict:
        step = max(1, int(600.0 / TRACK_STEP_S))
        g = self.clock.grid_s[::step]
        d = {"model": self.clock.params, "rate_hz_true": self.clock.rate_true_hz,
             "rate_error_pct": float(self.model.get("rate_error", "pct", 0.0)),
             "table": {"true_s": g.tolist(),
                       "device_minus_true_s": np.interp(g, self.clock.grid_s, self.clock.offset_s).tolist()},
             "halts": [], "restarts": []}
        for kind, lst in (("halts", self.clock.halts), ("restarts", self.clock.restarts)):
            for a, b in lst:
                d[kind].append({"start_true_s": a, "end_true_s": b, "duration_s": b - a,
                                "start_device_ns": int(self.start_ns + round(float(self.clock.device_time(a)) * 1e9)),
                                "end_device_ns": int(self.start_ns + round(float(self.clock.device_time(b)) * 1e9))})
        return d


def write_labels(path, labels: dict) -> None:
    """Labels CSV: integer columns as integers, others with 6 decimals (nan for empty windows)."""
    with open(path, "w") as f:
        f.write(",".join(LABEL_COLUMNS) + "\n")
        _write_label_rows(f, labels)


def _write_label_rows(f, labels: dict, rows_per_block: int = 4096) -> None:
    cols = list(LABEL_COLUMNS)
    ints = {"window", "device_start_ns", "samples", "still", "activity", "posture", "motion"}
    n = labels[cols[0]].shape[0]
    for a in range(0, n, rows_per_block):
        b = min(n, a + rows_per_block)
        texts = [labels[c][a:b].astype(np.int64).astype(str) if c in ints
                 else np.char.mod("%.6f", labels[c][a:b].astype(np.float64)) for c in cols]
        f.write("".join(",".join(row) + "\n" for row in zip(*texts)))


# ----------------------------------------------------------------------------- set-up
def _start_ns(start) -> int:
    if start is None:
        start = DEFAULT_START
    if isinstance(start, (int, np.integer)):
        return int(start)
    if isinstance(start, str):
        start = datetime.fromisoformat(start)
    if start.tzinfo is None:
        start = start.replace(tzinfo=timezone.utc)
    return int(round(start.timestamp() * 1e9))


def _device_hz(device: str, hz: float) -> float:
    """GENEActiv "85.7 Hz" is 300 samples per 3.5 s = 600/7 Hz (drivers/constants.GNA_RATE_85_7)."""
    from stillpoint.drivers.constants import GNA_RATE_85_7
    return GNA_RATE_85_7 if device.lower() == "geneactiv" and abs(hz - 85.7) < 0.01 else float(hz)


def make_devices(*, sites: Sequence[str], devices: Sequence[str], days: float, hz: float,
                 effects=None, seed: int = 1, start=None, range_g=None, packed=None,
                 gyro_range_dps=None, wearer: Optional[WearerParams] = None,
                 temperature: Optional[TemperatureParams] = None, models: Optional[Sequence] = None,
                 geneactiv_calibration: bool = True) -> list[DeviceSim]:
    """Devices on one body (shared schedule). ``models``: one SensorModel per device (else
    ``effects`` for all)."""
    if days <= 0:
        raise ValueError("days must be positive")
    if hz <= 0:
        raise ValueError("hz must be positive")
    duration = float(days) * 86400.0
    start_ns = _start_ns(start)
    start_hour = (start_ns / 1e9 / 3600.0) % 24.0
    wearer = wearer or WearerParams()
    schedule = make_schedule(wearer, duration, seed, start_hour=start_hour)
    out = []
    for i, (site, dev) in enumerate(zip(sites, devices)):
        if site not in SITES:
            raise ValueError(f"site must be one of {', '.join(SITES)}, got {site!r}")
        dev = dev.lower()
        dev_hz = _device_hz(dev, hz)
        gains = offsets = None
        if dev == "geneactiv" and geneactiv_calibration:
            r = np.random.default_rng(np.random.SeedSequence([int(seed), 5, i]))
            gains = tuple(int(x) for x in np.rint(r.normal(25600, 250, 3)))  # header calibration
            offsets = tuple(int(x) for x in np.rint(r.normal(0, 600, 3)))
        spec = DeviceSpec.make(dev, range_g=range_g, packed=packed,
                               gyro_range_dps=gyro_range_dps if dev == "ax6" else None,
                               gains=gains, offsets=offsets)
        m = models[i] if models is not None else build_model(effects)
        dev_id = int(np.random.SeedSequence([int(seed), 6, i]).generate_state(1)[0] % 60000) + 1000
        out.append(DeviceSim(schedule, site=site, spec=spec, model=m, seed=seed, dev_index=i, hz=dev_hz,
                             duration_s=duration, start_ns=start_ns, temperature=temperature,
                             device_id=dev_id))
    return out


# ----------------------------------------------------------------------------- writing
class _FileSink:
    """A device's writer plus the label accumulators."""

    def __init__(self, sim: DeviceSim, path, *, labels_path=None, session_id: int = 1):
        self.sim = sim
        self.path = Path(path)
        self.labels_path = Path(labels_path) if labels_path else None
        # a .gz output is written plain first (corrupt sectors are applied to the plain file),
        # then compressed on close
        self.gz = self.path.name.endswith(".gz")
        self.plain = self.path.with_name(self.path.name[:-3] + ".part") if self.gz else self.path
        spec = sim.spec
        if spec.kind in ("ax3", "ax6"):
            from stillpoint.drivers.cwa import CwaWriter
            self.writer = CwaWriter(self.plain, device_type=spec.kind.upper(), device_id=sim.device_id,
                                    session_id=session_id, rate_hz=sim.hz, range_g=spec.range_g,
                                    packed=spec.packed if spec.kind == "ax3" else False,
                                    gyro_range_dps=spec.gyro_range_dps,
                                    metadata={"_p": sim.site, "_sc": f"sim-seed-{sim.seed}"})
        else:
            from stillpoint.drivers.geneactiv import GeneactivWriter
            self.writer = GeneactivWriter(self.plain, serial=f"{sim.device_id:06d}", rate_hz=sim.hz,
                                          gains=spec.gains, offsets=spec.offsets,
                                          header_fields={"Device Location Code": sim.site})
        # labels are streamed: a chunk (1 h) holds whole windows (10 s), so the windows up to a
        # chunk's end are final once it is pushed; memory stays flat in the recording length
        self.nw = int(np.ceil(sim.duration_s / WINDOW_S))
        self.next_window = 0
        self._labels_f = None
        self._in_memory = [] if self.labels_path is None else None
        if self.labels_path is not None:
            self._labels_f = open(self.labels_path, "w")
            self._labels_f.write(",".join(LABEL_COLUMNS) + "\n")
        self.stats = {"still": 0, "windows": 0, "activity": np.zeros(len(ACTIVITIES), np.int64),
                      "worn_T": []}
        self.samples = 0

    def _emit(self, labels: dict) -> None:
        st = self.stats
        st["still"] += int(labels["still"].sum())
        st["windows"] += labels["still"].shape[0]
        st["activity"] += np.bincount(labels["activity"], minlength=len(ACTIVITIES))
        st["worn_T"].append(labels["temperature_c"][labels["activity"] > 1].astype(np.float32))
        if self._labels_f is not None:
            _write_label_rows(self._labels_f, labels)
        else:
            self._in_memory.append(labels)

    def _emit_until(self, w_end: int, sums=None, sq=None, counts=None) -> None:
        """Emit windows next_window .. w_end - 1 (zeros where no sample fell)."""
        n = w_end - self.next_window
        if n <= 0:
            return
        if counts is None:
            sums, sq, counts = np.zeros((n, 3)), np.zeros((n, 3)), np.zeros(n, np.int64)
        self._emit(self.sim.labels(sums, sq, counts, first_window=self.next_window))
        self.next_window = w_end

    def push(self, c: SimChunk) -> None:
        nw = self.nw
        w0 = min(int(c.true_s[0] // WINDOW_S), nw - 1)
        w1 = min(int(c.true_s[-1] // WINDOW_S), nw - 1)
        self._emit_until(w0)  # windows without samples (halt / restart gaps) before this chunk
        w0 = self.next_window
        edges = np.searchsorted(c.true_s, np.arange(w0, w1 + 1) * WINDOW_S, side="left")
        edges[0] = 0
        nz = np.diff(np.append(edges, c.n)) > 0  # windows with samples in this chunk
        starts = edges[nz]
        wins = np.arange(w0, w1 + 1)[nz] - w0
        k = w1 + 1 - w0
        counts = np.zeros(k, np.int64)
        sums, sq = np.zeros((k, 3)), np.zeros((k, 3))
        counts[wins] = np.diff(np.append(starts, c.n))
        g = c.true_g.astype(np.float64)
        sums[wins] = np.add.reduceat(g, starts, axis=0)
        sq[wins] = np.add.reduceat(g * g, starts, axis=0)
        self._emit_until(w1 + 1, sums, sq, counts)
        cuts = [0] + list(c.restarts) + [c.n]
        for p, (a, b) in enumerate(zip(cuts[:-1], cuts[1:])):
            if p > 0 and hasattr(self.writer, "restart"):
                self.writer.restart()
            if b <= a:
                continue
            self._write(c, a, b)
        self.samples += c.n

    def _write(self, c: SimChunk, a: int, b: int) -> None:
        sim = self.sim
        t = c.true_s[a:b]
        gi = np.minimum((t * (1.0 / TRACK_STEP_S)).astype(np.int64), sim.t_grid.shape[0] - 1)
        light = sim.light_grid[gi]  # slow channels from the 10 s grid (a sector keeps one value)
        if sim.spec.kind in ("ax3", "ax6"):
            traw = np.rint((c.temperature_c[a:b] + 50.0) * (256.0 / 75.0)).astype(np.int64)
            np.clip(traw, 0, 1023, out=traw)
            braw = np.clip(np.rint(sim.battery_v(sim.t_grid) * 1024.0 / 6.0 - 512.0), 1, 255).astype(np.int64)[gi]
            self.writer.write(c.time_ns[a:b], c.counts[a:b],
                              gyro_counts=None if c.gyro_counts is None else c.gyro_counts[a:b],
                              temperature_raw=traw, light_raw=light, battery_raw=braw)
        else:
            self.writer.write(c.time_ns[a:b], c.counts[a:b], light_raw=light,
                              temperature_c=np.round(c.temperature_c[a:b], 1),
                              battery_v=np.round(sim.battery_v(sim.t_grid), 4)[gi])

    def close(self) -> list:
        self._emit_until(self.nw)
        if self._labels_f is not None:
            self._labels_f.close()
        self.writer.close()
        corrupt = []
        m = self.sim.model
        if m.on("corrupt_sectors"):
            corrupt = self._corrupt(m.effects["corrupt_sectors"])
        if self.gz:
            import gzip
            import shutil
            with open(self.plain, "rb") as src, gzip.GzipFile(self.path, "wb", compresslevel=6, mtime=0) as dst:
                shutil.copyfileobj(src, dst, 1 << 20)
            self.plain.unlink()
        return corrupt

    def _corrupt(self, p: dict) -> list:
        if self.sim.spec.kind == "geneactiv":
            from .corrupt import corrupt_bin_pages
            n_units = _count_bin_pages(self.plain)
        else:
            n_units = (self.plain.stat().st_size - 1024) // 512
        if "indices" in p:
            idx = sorted(int(i) for i in p["indices"] if 0 <= int(i) < n_units)
        else:
            r = np.random.default_rng(np.random.SeedSequence([self.sim.seed, 7, self.sim.dev_index]))
            k = min(int(p.get("count", 3)), max(n_units - 2, 0))
            idx = sorted(int(i) for i in r.choice(np.arange(1, max(n_units - 1, 1)), k, replace=False)) if k else []
        if self.sim.spec.kind == "geneactiv":
            corrupt_bin_pages(self.plain, idx)
        else:
            from stillpoint.drivers.cwa import corrupt_sector
            for i in idx:
                corrupt_sector(self.plain, i, "checksum")
        return idx


def _count_bin_pages(path) -> int:
    n = 0
    with open(path, "rb") as f:
        for line in f:
            if line.startswith(b"Recorded Data"):
                n += 1
    return n


def _paths(path, truth_path, labels_path):
    """(truth path, labels path), or (None, None) for truth_path=False."""
    if truth_path is False:
        return None, None
    tp = Path(truth_path) if truth_path else _default_truth_path(Path(path))
    if labels_path:
        return tp, Path(labels_path)
    stem = tp.name[: -len(".truth.json")] if tp.name.endswith(".truth.json") else tp.stem
    return tp, tp.with_name(stem + ".labels.csv")


def _finish(sim: DeviceSim, sink: _FileSink, corrupt: list, truth_path: Optional[Path], pair=None) -> Truth:
    st = sink.stats
    worn_T = np.concatenate(st["worn_T"]) if st["worn_T"] else np.zeros(0)
    summary = {
        "still_window_fraction": float(st["still"] / max(st["windows"], 1)),
        "still_hours_per_day": float(st["still"] * WINDOW_S / 3600.0 / max(sim.duration_s / 86400.0, 1e-9)),
        "worn_temperature_c_p5_p95": ([float(np.percentile(worn_T, 5)), float(np.percentile(worn_T, 95))]
                                      if worn_T.size else None),
        "activity_hours": {a: float(st["activity"][i] * WINDOW_S / 3600.0) for i, a in enumerate(ACTIVITIES)},
        "steps": int(np.count_nonzero((sim.schedule.steps >= 0) & (sim.schedule.steps < sim.duration_s))),
    }
    truth = Truth(path=str(sink.path), device=dict(sim.spec.to_dict(), device_id=sim.device_id),
                  site=sim.site, seed=sim.seed, start_ns=sim.start_ns, duration_s=sim.duration_s,
                  rate_hz_nominal=sim.hz, rate_hz_true=sim.clock.rate_true_hz,
                  sensor_model=sim.model, clock=sim.clock_truth(),
                  wearer=sim.schedule.params.to_dict(), temperature=sim.tparams.to_dict(),
                  samples_written=sink.samples, corrupt_sectors=corrupt, summary=summary, pair=pair)
    if truth_path is not None:
        truth.labels_path = str(sink.labels_path)
        truth.truth_path = str(truth_path)
        truth.save(truth_path)
    else:
        parts = sink._in_memory
        truth._labels = {k: np.concatenate([p[k] for p in parts]) for k in LABEL_COLUMNS} if parts else None
    return truth


def _default_truth_path(path: Path) -> Path:
    name = path.name
    for suf in (".cwa.gz", ".bin.gz", ".cwa", ".bin"):
        if name.endswith(suf):
            return path.with_name(name[: -len(suf)] + ".truth.json")
    return path.with_name(name + ".truth.json")


def iter_chunks(*, device: str = "ax3", site: str = "wrist", days: float = 1.0, hz: float = 100.0,
                effects=None, seed: int = 1, **kw) -> Iterator[SimChunk]:
    """In-memory generator (no file): the chunks of one simulated device. The DeviceSim (with
    the resolved model, clock and tracks) is ``make_devices(...)[0]`` with the same arguments."""
    [sim] = make_devices(sites=[site], devices=[device], days=days, hz=hz, effects=effects,
                         seed=seed, **kw)
    return sim.chunks()


def simulate_recording(path, *, device: str = "ax3", site: str = "wrist", days: float = 7.0,
                       hz: float = 100.0, effects=None, seed: int = 1, truth_path=None,
                       labels_path=None, start=None, range_g=None, packed=None,
                       gyro_range_dps=None, wearer: Optional[WearerParams] = None,
                       temperature: Optional[TemperatureParams] = None) -> Truth:
    """Simulate one device and write it to ``path`` (.cwa for ax3/ax6, .bin for geneactiv) plus
    the truth JSON (default: beside the file, ``<name>.truth.json``; ``truth_path=False``: none)
    and the per-window labels CSV (``<name>.labels.csv``)."""
    [sim] = make_devices(sites=[site], devices=[device], days=days, hz=hz, effects=effects, seed=seed,
                         start=start, range_g=range_g, packed=packed, gyro_range_dps=gyro_range_dps,
                         wearer=wearer, temperature=temperature)
    tp, lp = _paths(path, truth_path, labels_path)
    sink = _FileSink(sim, path, labels_path=lp)
    try:
        for c in sim.chunks():
            sink.push(c)
    finally:
        corrupt = sink.close()
    return _finish(sim, sink, corrupt, tp)


def simulate_pair(path_a, path_b, *, site_a: str = "wrist", site_b: str = "hip",
                  device_a: str = "ax3", device_b: Optional[str] = None, days: float = 7.0,
                  hz: float = 100.0, hz_b: Optional[float] = None, effects=None, effects_b=None,
                  seed: int = 1, truth_a=None, truth_b=None, start=None, range_g=None,
                  packed=None, gyro_range_dps=None, wearer: Optional[WearerParams] = None,
                  temperature: Optional[TemperatureParams] = None) -> tuple[Truth, Truth]:
    """Two devices on one body (same movement and step times; own orientation, dynamics,
    sensor errors and clock each). Written chunk by chunk in lockstep."""
    device_b = device_b or device_a
    m_a = build_model(effects)
    m_b = build_model(effects_b) if effects_b is not None else build_model(effects)
    sims = make_devices(sites=[site_a, site_b], devices=[device_a, device_b], days=days, hz=hz,
                        seed=seed, start=start, range_g=range_g, packed=packed,
                        gyro_range_dps=gyro_range_dps, wearer=wearer, temperature=temperature,
                        models=[m_a, m_b])
    if hz_b is not None and hz_b != hz:
        b = sims[1]
        sims[1] = DeviceSim(b.schedule, site=b.site, spec=b.spec, model=m_b, seed=seed, dev_index=1,
                            hz=_device_hz(b.spec.kind, hz_b), duration_s=b.duration_s, start_ns=b.start_ns,
                            temperature=temperature, device_id=b.device_id)
    paths = [_paths(path_a, truth_a, None), _paths(path_b, truth_b, None)]
    sinks = [_FileSink(sims[0], path_a, labels_path=paths[0][1]),
             _FileSink(sims[1], path_b, labels_path=paths[1][1])]
    try:
        for k in range(max(s.n_chunks for s in sims)):
            for s, sink in zip(sims, sinks):
                c = s.chunk(k) if k < s.n_chunks else None
                if c is not None and c.n:
                    sink.push(c)
    finally:
        corrupt = [sink.close() for sink in sinks]
    pair = {"sites": [site_a, site_b], "paths": [str(path_a), str(path_b)]}
    ta = _finish(sims[0], sinks[0], corrupt[0], paths[0][0], dict(pair, this=0))
    tb = _finish(sims[1], sinks[1], corrupt[1], paths[1][0], dict(pair, this=1))
    return ta, tb
