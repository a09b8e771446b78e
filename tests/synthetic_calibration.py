"""Synthetic window-feature tables with a known calibration error (tests, accuracy table).

Not a signal simulator (that is ``engine.sim``): this draws the *window features* a recording
would produce directly, which is what the fit consumes. Still periods hold one orientation for a
run of windows; orientations are uniform on the sphere unless restricted; temperature follows a
daily cycle (skin-warm while worn) plus slow drift; the device's error is the GGIR-form model
inverted, so ``truth.apply(raw, T)`` lies on the unit sphere up to the window-mean noise.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from stillpoint.engine.features import WindowFeatures
from stillpoint.engine.calibration.estimate import CalibrationEstimate


def random_truth(rng: np.random.Generator, *, offset_mg: float = 40.0, gain_pct: float = 2.0,
                 tempoffset_mg_per_c: float = 1.0, temperature_ref: float = 27.0
                 ) -> CalibrationEstimate:
    """A typical device error: offsets of tens of mg, gains within +/-2%,
    temperature offsets up to 1 mg/degC."""
    return CalibrationEstimate(
        offset=rng.uniform(-offset_mg, offset_mg, 3) / 1000.0,
        scale=1.0 + rng.uniform(-gain_pct, gain_pct, 3) / 100.0,
        tempoffset=rng.uniform(-tempoffset_mg_per_c, tempoffset_mg_per_c, 3) / 1000.0,
        temperature_ref=temperature_ref, status="truth", method="truth", reason="true parameters")


def raw_from_calibrated(cal: np.ndarray, temperature: np.ndarray,
                        truth: CalibrationEstimate) -> np.ndarray:
    """Invert the GGIR-form model: the raw reading whose calibration is ``cal``."""
    t = (np.asarray(temperature) - truth.temperature_ref)[:, None] * truth.tempoffset
    return (cal - t) / truth.scale - truth.offset


def random_directions(rng: np.random.Generator, n: int,
                      min_axis: Optional[np.ndarray] = None) -> np.ndarray:
    """(n, 3) unit vectors, uniform on the sphere; ``min_axis`` (3,) keeps only directions whose
    components are all >= min_axis (e.g. [-1, -1, 0.2] for a one-sided sphere)."""
    out = np.empty((0, 3))
    while out.shape[0] < n:
        v = rng.normal(size=(2 * n + 16, 3))
        v /= np.linalg.norm(v, axis=1, keepdims=True)
        if min_axis is not None:
            v = v[np.all(v >= np.asarray(min_axis), axis=1)]
        out = np.vstack([out, v])
    return out[:n]


@dataclass
class SyntheticRecording:
    features: WindowFeatures  # every window of the recording
    truth: CalibrationEstimate  # the device's true calibration
    still: np.ndarray  # (k,) bool: windows drawn as still


def synthetic_recording(hours: float, truth: CalibrationEstimate, *, seed: int = 0,
                        noise_mg: float = 5.0, rate_hz: float = 100.0, window_s: float = 10.0,
                        still_fraction: float = 0.35, run_windows: int = 30,
                        temperature: str = "daily", min_axis: Optional[np.ndarray] = None,
                        table_hours: float = 0.0, start_ns: int = 1_700_000_000 * 10**9
                        ) -> SyntheticRecording:
    """Window features of a ``hours`` long recording.

    ``noise_mg``: per-sample noise SD; a still window's mean carries noise_mg/sqrt(samples).
    ``temperature``: "daily" (cycle 22-33 degC + drift), "flat" (constant 25 degC) or "missing".
    ``table_hours``: that much time at the start spent lying on a table (one orientation,
    identical window means, as quantised nonwear data looks).
    """
    rng = np.random.default_rng(seed)
    k = int(round(hours * 3600.0 / window_s))
    per_window = int(round(rate_hz * window_s))
    t_s = np.arange(k) * window_s
    start = start_ns + (np.arange(k, dtype=np.int64) * int(window_s * 1e9))
    # still runs: each run of `run_windows` windows is still with probability still_fraction
    n_runs = -(-k // run_windows)
    run_still = rng.random(n_runs) < still_fraction
    run_dir = random_directions(rng, n_runs, min_axis)
    still = np.repeat(run_still, run_windows)[:k]
    direction = np.repeat(run_dir, run_windows, axis=0)[:k]
    # temperature
    if temperature == "daily":
        temp = (27.5 + 4.5 * np.sin(2 * np.pi * t_s / 86400.0)
                + 1.0 * np.sin(2 * np.pi * t_s / (3.3 * 86400.0)) + rng.normal(0, 0.05, k))
    elif temperature == "flat":
        temp = np.full(k, 25.0)
    elif temperature == "missing":
        temp = np.full(k, np.nan)
    else:
        raise ValueError(f"unknown temperature profile {temperature!r}")
    mean_noise = noise_mg / 1000.0 / np.sqrt(per_window)
    cal = direction + rng.normal(0.0, mean_noise, (k, 3))
    moving = ~still
    # moving windows: body acceleration on top of gravity, large SD
    cal[moving] += rng.normal(0.0, 0.15, (int(moving.sum()), 3))
    sd = np.where(still[:, None], noise_mg / 1000.0 * rng.uniform(0.9, 1.1, (k, 3)),
                  rng.uniform(0.03, 0.4, (k, 3)))
    if table_hours > 0:
        n_tab = min(k, int(round(table_hours * 3600.0 / window_s)))
        cal[:n_tab] = np.array([0.0, 0.0, 1.0])
        still[:n_tab] = True
        sd[:n_tab] = noise_mg / 1000.0
        if temperature == "daily":
            temp[:n_tab] = 22.0 + 0.5 * np.sin(2 * np.pi * t_s[:n_tab] / 86400.0)
    t_for_raw = np.nan_to_num(temp, nan=truth.temperature_ref)
    raw = raw_from_calibrated(cal, t_for_raw, truth)
    if table_hours > 0:
        # a device at rest with quantised output: every window mean identical
        raw[:n_tab] = np.round(raw[0] * 256.0) / 256.0
    feats = WindowFeatures(start_ns=start, n=np.full(k, per_window, np.int64), mean=raw, sd=sd,
                           temperature=temp, norm_mean=np.linalg.norm(raw, axis=1),
                           segment=np.zeros(k, np.int64))
    return SyntheticRecording(feats, truth, still)


class SyntheticSource:
    """A Source whose samples reproduce a synthetic feature table (for tests of the reader pass).

    Each 10 s window becomes ``rate_hz * 10`` samples: the window mean plus Gaussian noise of the
    window's SD, quantised to ``counts_per_g``; one unit (sector-like) per window carries the
    window's temperature. Blocks hold ``windows_per_block`` windows.
    """

    def __init__(self, features: WindowFeatures, *, rate_hz: float = 20.0,
                 counts_per_g: float = 4096.0, windows_per_block: int = 60, seed: int = 0,
                 device_type: str = "AX3", device_id: str = "99999", window_s: float = 10.0):
        from stillpoint.engine.core.blocks import DeviceInfo, QCReport

        self.features = features
        self.rate_hz = float(rate_hz)
        self.counts_per_g = float(counts_per_g)
        self.windows_per_block = int(windows_per_block)
        self.seed = seed
        self.window_s = window_s
        self.info = DeviceInfo(device_type=device_type, device_id=device_id, session_id=1,
                               firmware="synthetic", sample_rate_nominal=self.rate_hz,
                               accel_range_g=8.0)
        self.qc = QCReport(unit="sector")
        self.closed = False

    def __iter__(self):
        from stillpoint.engine.core.blocks import Block

        rng = np.random.default_rng(self.seed)
        f = self.features
        per = int(round(self.rate_hz * self.window_s))
        step_ns = int(round(1e9 / self.rate_hz))
        for i in range(0, len(f), self.windows_per_block):
            sl = slice(i, i + self.windows_per_block)
            mean, sd, temp, start = f.mean[sl], f.sd[sl], f.temperature[sl], f.start_ns[sl]
            k = mean.shape[0]
            g = (np.repeat(mean, per, axis=0)
                 + rng.normal(size=(k * per, 3)) * np.repeat(sd, per, axis=0))
            counts = np.round(g * self.counts_per_g).astype(np.int32)
            t = (np.repeat(start, per) + np.tile(np.arange(per, dtype=np.int64) * step_ns, k))
            self.qc.total += k
            self.qc.valid += k
            yield Block(time_ns=t, accel=counts,
                        accel_counts_per_g=np.full(3, self.counts_per_g), accel_zero=np.zeros(3),
                        unit_index=np.arange(i, i + k, dtype=np.int64),
                        unit_sequence=np.arange(i, i + k, dtype=np.int64),
                        unit_start=np.arange(k, dtype=np.int64) * per,
                        temperature_c=np.asarray(temp, np.float64),
                        temperature_raw=np.full(k, -1, np.int32), light=np.zeros(k, np.int32),
                        battery_v=np.full(k, np.nan), events=np.zeros(k, np.uint8),
                        segment=0, first_sample=i * per)

    def close(self) -> None:
        self.closed = True


def write_synthetic_cwa(path, features: WindowFeatures, *, rate_hz: float = 25.0, seed: int = 0,
                        device_id: int = 4242, packed: bool = False) -> int:
    """Write the samples of :class:`SyntheticSource` to a real AX3 ``.cwa`` (1/256 g counts;
    temperature stored as the sector's 10-bit code). Returns the number of samples written."""
    from stillpoint.drivers.cwa import CwaWriter

    src = SyntheticSource(features, rate_hz=rate_hz, counts_per_g=256.0, seed=seed,
                          device_id=str(device_id))
    n = 0
    with_writer = CwaWriter(path, device_type="AX3", device_id=device_id, rate_hz=rate_hz,
                            range_g=8, packed=packed)
    try:
        for b in src:
            # degC = code * 75/256 - 50 (drivers.constants.cwa_temperature_c), inverted
            t = np.nan_to_num(b.temperature_per_sample(), nan=25.0)
            code = np.clip(np.round((t + 50.0) * 256.0 / 75.0), 0, 1023).astype(np.int64)
            accel = b.accel
            e = int(getattr(with_writer, "exponent", 0) or 0)
            if e:  # packed AX3 keeps multiples of 2^e: round here so the writer's shift is exact
                accel = (np.round(accel / 2.0 ** e) * 2 ** e).astype(np.int32)
            with_writer.write(b.time_ns, accel, temperature_raw=code)
            n += b.n
    finally:
        with_writer.close()
    return n
