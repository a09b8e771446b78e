"""One simulated device on a body: the resolved sensor model, the slow tracks (temperature,
accelerometer temperature, bias, clock), and chunk-by-chunk generation of true and measured
samples (``DeviceSim``, ``SimChunk``); ``make_devices`` builds the devices of one body on a
shared schedule; ``build_model`` combines effect names, model files and overrides.

Determinism: the body schedule, every per-segment orientation, the slow tracks and the sensor's
parameters come from the seed; the white noise of chunk k (one hour of true time) comes from
SeedSequence((seed, 3, device index, k)). Same seed -> same samples, however they are consumed.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import datetime, timezone
from typing import Iterator, Optional, Sequence

import numpy as np

from stillpoint.engine.core.malloc import tune_for_blocks

from .clock import ClockModel, make_clock
from .model import DEFAULT_EFFECTS, ModelError, SensorModel, first_order_lag, load_model, resolve_model
from .sensor import CHUNK_S, DeviceSpec, bias_track, measure_blocks, noise_sd_g, standard_normals
from .temperature import TRACK_STEP_S, TemperatureParams, temperature_track
from .truth import WINDOW_S
from .wearer import SITES, Schedule, SiteModel, WearerParams, make_schedule

# chunks from which the motion is rendered in a child process (its start-up, ~0.3 s, is
# covered by the chunks the parent renders meanwhile; a thread suffices for short recordings)
PROCESS_MIN_CHUNKS = 24
DEFAULT_START = "2025-03-03T10:00:00+00:00"  # a Monday, 10:00 (device handed out)
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


def _grid_pos(t: np.ndarray, n_grid: int):
    """Index and fraction of times t on the regular TRACK_STEP_S grid (linear interpolation)."""
    x = t * (1.0 / TRACK_STEP_S)
    gi = np.minimum(x.astype(np.int64), n_grid - 2)
    return gi, x - gi


def _lerp(v: np.ndarray, gi: np.ndarray, fr: np.ndarray) -> np.ndarray:
    a = v[gi]
    return a + fr * (v[gi + 1] - a)


class _GridRuns:
    """The grid cells of sorted times as runs, for several tracks interpolated at the same times:
    ``lerp`` gives ``_lerp``'s numbers (the same two operations per sample) with the cell's
    value and step repeated over its run instead of gathered per sample (~3x faster).
    Unsorted cell indices fall back to the gathers."""

    def __init__(self, gi: np.ndarray):
        self.gi = gi
        n = gi.shape[0]
        self.sorted = bool(n and np.all(gi[1:] >= gi[:-1]))
        if self.sorted:
            self.lo, self.hi = int(gi[0]), int(gi[-1])
            edges = np.searchsorted(gi, np.arange(self.lo, self.hi + 2), side="left")
            self.counts = np.diff(edges)

    @classmethod
    def at(cls, t: np.ndarray, n_grid: int):
        """(runs, fr) for times t: ``_GridRuns(gi)`` and fr of ``_grid_pos(t, n_grid)``; for
        increasing t the runs come from the cell boundaries (no per-sample cell index) and
        fr = x - cell with the cell repeated over its run (the same numbers)."""
        x = t * (1.0 / TRACK_STEP_S)
        n = x.shape[0]
        if n == 0 or not bool(np.all(x[1:] >= x[:-1])):
            gi = np.minimum(x.astype(np.int64), n_grid - 2)
            return cls(gi), x - gi
        self = cls.__new__(cls)
        self.gi = None
        self.sorted = True
        self.lo, self.hi = min(int(x[0]), n_grid - 2), min(int(x[-1]), n_grid - 2)
        edges = np.searchsorted(x, np.arange(self.lo + 1, self.hi + 1), side="left")
        self.counts = np.diff(np.concatenate([[0], edges, [n]]))  # samples in cells lo..hi
        fr = x - np.repeat(np.arange(self.lo, self.hi + 1, dtype=np.float64), self.counts)
        return self, fr

    def lerp(self, v: np.ndarray, fr: np.ndarray) -> np.ndarray:
        if not self.sorted:
            return _lerp(v, self.gi, fr)
        seg = v[self.lo:self.hi + 2]
        out = np.repeat(seg[1:] - seg[:-1], self.counts)  # v[gi + 1] - v[gi]
        out *= fr
        out += np.repeat(seg[:-1], self.counts)
        return out


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
        if spec.kind == "gt3x":
            for name in ("restarts", "corrupt_sectors"):
                if self.model.on(name):
                    raise ModelError(f"{name}: not simulated for an ActiGraph .gt3x")
        self.site_model = SiteModel(schedule, site, self.seed)
        self.t_grid, self.T_grid = temperature_track(schedule, site, self.tparams, self.seed, duration_s)
        self.Ta_grid = (first_order_lag(self.T_grid, self.t_grid, float(self.model.get("thermal_lag", "tau_s")))
                        if self.model.on("thermal_lag") else self.T_grid)
        self.bias_grid = bias_track(self.model, self.t_grid, dev_seed)
        # float32 copies of the slow tracks for the per-sample interpolation (the clock stays
        # float64: it needs nanoseconds over days)
        self._bias_axes = np.ascontiguousarray(self.bias_grid.T, dtype=np.float32)
        self._T32 = self.T_grid.astype(np.float32)
        self._Ta32 = self.Ta_grid.astype(np.float32)
        self.clock: ClockModel = make_clock(self.model, self.t_grid, self.T_grid, self.hz)
        r = np.random.default_rng(np.random.SeedSequence([self.seed, 4, self.dev_index]))
        self.gyro_bias = r.normal(0, GYRO_BIAS_SD_DPS, 3)
        self.n_slots = int(np.ceil(duration_s * self.clock.rate_true_hz))
        self.light_grid = self.light_raw(self.t_grid)
        self.n_chunks = int(np.ceil(duration_s / CHUNK_S))
        self._accel_noise = bool(np.any(noise_sd_g(self.model, self.hz) > 0))

    # --------------------------------------------------------------- chunks
    def _render(self, k: int):
        """Stage 1 of chunk k (pure, thread-safe): sample times, the true motion and the white
        noise draws (chunk k's own generator, handed on to stage 2)."""
        rate = self.clock.rate_true_hz
        i0 = int(np.ceil(k * CHUNK_S * rate))
        i1 = min(self.n_slots, int(np.ceil((k + 1) * CHUNK_S * rate)))
        if i1 <= i0:
            return None
        t, keep = self.clock.sample_times(i0, i1)
        # restarts: first kept sample after each restart gap
        restarts = []
        for _a, b in self.clock.restarts:
            if t.size and t[0] <= b <= t[-1] + 1.0 / rate:
                pos = int(np.searchsorted(t, b, side="left"))
                restarts.append(int(np.count_nonzero(keep[:pos])))
        if not keep.all():
            t = t[keep]
        gyro = self.spec.kind == "ax6" and self.spec.gyro_range_dps is not None
        f, w = self.site_model.render(t, gyro=gyro, dtype=np.float32)
        rng = np.random.default_rng(np.random.SeedSequence([self.seed, 3, self.dev_index, k]))
        # the accelerometer's normals are drawn first (as ``measure`` would), the gyro's after
        z = standard_normals(rng, (t.shape[0], 3)) if self._accel_noise else None
        return t, f, w, sorted(set(restarts)), rng, z

    def _measure(self, k: int, rendered) -> SimChunk:
        """Stage 2 of chunk k: the sensor (noise from chunk k's own seed) and the device clock."""
        t, f, w, restarts, rng, z = rendered
        runs, fr = _GridRuns.at(t, self.t_grid.shape[0])
        fr32 = fr.astype(np.float32)
        T = runs.lerp(self._T32, fr32)
        Ta = runs.lerp(self._Ta32, fr32) if self.Ta_grid is not self.T_grid else T
        bias = None
        if self.model.on("bias_instability"):
            bias = np.empty((t.shape[0], 3), np.float32)
            for j in range(3):  # 1-D gathers from contiguous per-axis tracks (2-D gathers are slow)
                bias[:, j] = runs.lerp(self._bias_axes[j], fr32)
        meas, counts = measure_blocks(f, self.model, self.spec, temperature_c=T, time_s=t,
                                      accel_temperature_c=Ta, bias_g=bias, rate_hz=self.hz, noise=z)
        gcounts = None
        if w is not None:
            w = w + self.gyro_bias + rng.standard_normal(w.shape) * (GYRO_NOISE_DPS_RTHZ * np.sqrt(self.hz / 2))
            gcounts = self.spec.gyro_to_counts(w)
        d = runs.lerp(self.clock.offset_s, fr)  # t + offset, in place
        d += t
        d *= 1e9
        time_ns = np.round(d, out=d).astype(np.int64)
        time_ns += self.start_ns
        return SimChunk(k, t, time_ns, f, meas, counts, gcounts, T, restarts)

    def chunk(self, k: int) -> Optional[SimChunk]:
        """Chunk k (one hour of true time), or None past the end."""
        r = self._render(k)
        return None if r is None else self._measure(k, r)

    def chunks(self, prefetch=True) -> Iterator[SimChunk]:
        """All chunks in order. With ``prefetch`` the motion of the next chunks is rendered
        while chunk k is measured and consumed: in a child process for a recording of at least
        ``PROCESS_MIN_CHUNKS`` chunks when the process may use more than one core and the rate
        is not too high for its shared slots (engine/sim/render_process.py ``suits``), else on
        a worker thread; ``prefetch="thread"`` or
        ``"process"`` chooses. The output is identical either way."""
        tune_for_blocks()
        if prefetch is True:
            from stillpoint.engine.core.prefetch import cores_available
            from .render_process import suits
            prefetch = ("process" if self.n_chunks >= PROCESS_MIN_CHUNKS and cores_available() > 1
                        and suits(self) else "thread")
        if prefetch == "process":
            from .render_process import rendered
            for k, r in rendered(self):
                if r is None:
                    continue
                c = self._measure(k, r)
                if c.n:
                    yield c
            return
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
        the gravity vector in the device frame (k, 3) g, the worn micro-motion's window mean and
        RMS about it (``micro_mean``, ``micro_sd``, (k, 3) g; zero off the body), temperature and
        accelerometer temperature (degC). Same windows and vectors as ``labels`` gives for a full run
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
        micro_mean = np.empty((idx.shape[0], 3))
        micro_sd = np.empty((idx.shape[0], 3))
        for i in np.unique(seg):
            sel = seg == i
            grav[sel] = self.site_model.params(int(i)).R_base[2, :]
            micro_mean[sel], micro_sd[sel] = self.site_model.micromotion_window_moments(
                int(i), w0[sel], WINDOW_S)
        return {"window": idx, "true_start_s": w0, "device_start_ns": lab["device_start_ns"][idx],
                "gravity": grav, "micro_mean": micro_mean, "micro_sd": micro_sd,
                "temperature_c": lab["temperature_c"][idx],
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
