"""The full sensor: the deterministic model (model.apply_deterministic) plus the stochastic and
format terms (bias instability, white noise, clipping, quantisation), and each device's
resolution and range (``DeviceSpec``).

Resolutions (../shared/specs/cwa-format.md §6, geneactiv-format.md §5):

* AX3 (ADXL345, full resolution 1/256 g): packed mode keeps 10 bits + exponent, the firmware
  dropping the low e bits (e = 0, 1, 2, 3 for +-2, 4, 8, 16 g), so the step is 2^e/256 g;
  unpacked mode keeps 1/256 g. Range +-R g.
* AX6 (BMI160): 16-bit, 32768/R counts per g (2048 at +-16 g).
* GENEActiv: 12-bit raw with the device's calibration: g = (raw * 100 - offset) / gain, gain
  ~25600 (256 counts/g, +-8 g).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from .model import SensorModel, apply_deterministic, per_axis
from stillpoint.drivers import constants as C

CHUNK_S = 3600.0  # one hour of true time: the unit of generation and of the noise seeds

AX3_PACKED_EXPONENT = {2: 0, 4: 1, 8: 2, 16: 3}  # cwa-format.md §6.1 (also in drivers/cwa_writer.py)


@dataclass
class DeviceSpec:
    """What the simulated device stores: kind, range, resolution and the counts mapping."""

    kind: str  # "ax3", "ax6", "geneactiv"
    range_g: int
    packed: bool = False
    gyro_range_dps: Optional[float] = None
    gains: tuple = (25600, 25600, 25600)  # GENEActiv header calibration
    offsets: tuple = (0, 0, 0)
    idle_sleep: bool = True  # gt3x: the device sleeps while still (drivers/gt3x_writer.py)

    @staticmethod
    def make(kind: str, *, range_g: Optional[int] = None, packed: Optional[bool] = None,
             gyro_range_dps: Optional[float] = None, gains=None, offsets=None) -> "DeviceSpec":
        kind = kind.lower()
        if kind not in ("ax3", "ax6", "geneactiv", "gt3x"):
            raise ValueError(f"device must be ax3, ax6, geneactiv or gt3x, got {kind!r}")
        if kind == "gt3x":  # wGT3X-BT: +-8 g at 256 LSB/g, 12-bit ([GT3X] Activity.md 20)
            if range_g not in (None, 8):
                raise ValueError("the simulated ActiGraph (wGT3X-BT) records at +-8 g only")
            return DeviceSpec("gt3x", 8)
        if kind == "geneactiv":
            if range_g not in (None, 8):
                raise ValueError("GENEActiv records at +-8 g only")
            return DeviceSpec("geneactiv", 8, False, None, tuple(gains or (25600,) * 3),
                              tuple(offsets or (0, 0, 0)))
        r = int(range_g or (8 if kind == "ax3" else 16))
        if r not in (2, 4, 8, 16):
            raise ValueError(f"AX range must be 2, 4, 8 or 16 g, got {r}")
        if kind == "ax3":
            if gyro_range_dps is not None:
                raise ValueError("the AX3 has no gyroscope")
            return DeviceSpec("ax3", r, True if packed is None else bool(packed))
        if packed:
            raise ValueError("packed mode is AX3-only")
        # AX6: gyro on at 2000 dps by default; gyro_range_dps=0 records the accelerometer only
        gyro = 2000.0 if gyro_range_dps is None else (float(gyro_range_dps) or None)
        return DeviceSpec("ax6", r, False, gyro)

    # --------------------------------------------------------------- resolution
    @property
    def counts_per_g(self) -> np.ndarray:
        if self.kind == "geneactiv":
            return np.asarray(self.gains, np.float64) / 100.0
        if self.kind == "ax3":
            return np.full(3, 256.0)
        if self.kind == "gt3x":
            return np.full(3, C.GT3X_SCALE_BY_SERIAL_PREFIX["MOS"])
        return np.full(3, 32768.0 / self.range_g)

    @property
    def step_counts(self) -> int:
        """Quantisation step in counts (AX3 packed: 2^e)."""
        return 1 << AX3_PACKED_EXPONENT[self.range_g] if (self.kind == "ax3" and self.packed) else 1

    @property
    def lsb_g(self) -> np.ndarray:
        return self.step_counts / self.counts_per_g

    def count_limits(self) -> tuple[np.ndarray, np.ndarray]:
        """Smallest and largest storable counts per axis (after clipping at the range)."""
        if self.kind in ("geneactiv", "gt3x"):  # 12-bit two's complement
            return np.full(3, -2048), np.full(3, 2047)
        if self.kind == "ax6":
            return np.full(3, -32768), np.full(3, 32767)
        if self.packed:
            e = AX3_PACKED_EXPONENT[self.range_g]
            return np.full(3, -512 << e), np.full(3, 511 << e)
        full = self.range_g * 256  # ADXL345 full resolution: +-R g at 1/256 g
        return np.full(3, -full), np.full(3, full - 1)

    def to_counts(self, a_g: np.ndarray, mode: str = "nearest", clip: bool = True) -> np.ndarray:
        """Measured acceleration (n, 3) in g -> stored integer counts (n, 3) int32.

        Always clips at the storable range (a file cannot hold more); ``clip=False`` raises
        instead if a value is out of range. ``mode``: "nearest" or "floor" (dropping low bits
        by an arithmetic shift, as firmware does)."""
        step = self.step_counts
        dt = a_g.dtype if a_g.dtype in (np.float32, np.float64) else np.float64
        if self.kind == "geneactiv":
            x = np.array(a_g, dt)  # a_g * gain[j] + offset[j] on each axis
            per_axis(np.multiply, x, (np.asarray(self.gains, np.float64) / 100.0).astype(dt))
            per_axis(np.add, x, (np.asarray(self.offsets, np.float64) / 100.0).astype(dt))
        else:
            v = (self.counts_per_g / step).astype(dt)  # a_g * v[j] on each axis
            if np.all(v == v[0]):
                x = np.multiply(a_g, v[0])
            else:
                x = np.array(a_g, dt)
                per_axis(np.multiply, x, v)
        q = np.floor(x, out=x) if mode == "floor" else np.rint(x, out=x)
        lo, hi = self.count_limits()
        lo_s, hi_s = int(lo[0]) // step, int(hi[0]) // step  # the same on every axis
        if clip:
            np.clip(q, lo_s, hi_s, out=q)
        elif np.any(q < lo_s) or np.any(q > hi_s):
            raise ValueError("acceleration beyond the device range (clipping is off)")
        q = q.astype(np.int32)
        if step > 1:
            q *= step
        return q

    def to_g(self, counts: np.ndarray) -> np.ndarray:
        """Counts -> g as a reader decodes them."""
        c = np.asarray(counts, np.float64)
        if self.kind == "geneactiv":
            return (c * 100.0 - np.asarray(self.offsets, np.float64)) / np.asarray(self.gains, np.float64)
        return c / self.counts_per_g

    def gyro_to_counts(self, w_dps: np.ndarray) -> np.ndarray:
        return np.clip(np.rint(w_dps * (32768.0 / self.gyro_range_dps)), -32768, 32767).astype(np.int16)

    def to_dict(self) -> dict:
        d = {"kind": self.kind, "range_g": self.range_g, "packed": self.packed,
             "lsb_g": [float(x) for x in self.lsb_g],
             "counts_per_g": [float(x) for x in self.counts_per_g]}
        lo, hi = self.count_limits()
        d["clip_g"] = [[float(x) for x in self.to_g(lo[None, :])[0]],
                       [float(x) for x in self.to_g(hi[None, :])[0]]]
        if self.gyro_range_dps:
            d["gyro_range_dps"] = self.gyro_range_dps
        if self.kind == "geneactiv":
            d["gains"] = list(self.gains)
            d["offsets"] = list(self.offsets)
        return d


def noise_sd_g(model: SensorModel, rate_hz: float) -> np.ndarray:
    """Per-axis white-noise SD (g) at the sample rate: density * sqrt(bandwidth = rate / 2)."""
    if not model.on("noise"):
        return np.zeros(3)
    return model.axis_vector("noise", "ug_per_rthz") * 1e-6 * np.sqrt(rate_hz / 2.0)


def bias_track(model: SensorModel, t_grid: np.ndarray, seed: int) -> np.ndarray:
    """(g, 3) bias-instability offsets (g) on the slow grid: OU process, SD sigma, corr. tau."""
    out = np.zeros((t_grid.shape[0], 3))
    if not model.on("bias_instability") or t_grid.size == 0:
        return out
    from .model import _linear_recursion
    sig = model.axis_vector("bias_instability", "mg") / 1000.0
    tau = float(model.get("bias_instability", "tau_s", 3600.0))
    dt = np.diff(t_grid)
    a = np.exp(-dt / tau)
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 30]))
    z = rng.standard_normal((t_grid.shape[0], 3))
    for k in range(3):
        out[0, k] = sig[k] * z[0, k]
        _linear_recursion(a, sig[k] * np.sqrt(1 - a * a) * z[1:, k], out[0, k], out[1:, k])
    return out


def standard_normals(rng: np.random.Generator, shape) -> np.ndarray:
    """Standard normal draws (float32) by the Box-Muller transform of float32 uniforms: exact
    normals, ~4x faster than Generator.standard_normal on this class of CPU (white noise is the
    largest per-sample cost of the simulator)."""
    n = int(np.prod(shape))
    h = (n + 1) // 2
    u1 = rng.random(h, dtype=np.float32)
    u2 = rng.random(h, dtype=np.float32)
    r = np.negative(u1, out=u1)  # r = sqrt(-2 log1p(-u1)), in place
    np.log1p(r, out=r)  # 1 - u1 in (0, 1]: finite
    r *= np.float32(-2.0)
    np.sqrt(r, out=r)
    u2 *= np.float32(2.0 * np.pi)
    out = np.empty(2 * h, np.float32)
    np.cos(u2, out=out[:h])
    out[:h] *= r
    np.sin(u2, out=out[h:])
    out[h:] *= r
    return out[:n].reshape(shape)


def measure(true_g: np.ndarray, model: SensorModel, spec: DeviceSpec, *, temperature_c, time_s,
            accel_temperature_c, bias_g, rng: Optional[np.random.Generator], rate_hz: float,
            quantise: bool = True, noise: Optional[np.ndarray] = None) -> tuple[np.ndarray, np.ndarray]:
    """Apply the whole sensor model to one chunk: returns (measured g, stored counts). With
    ``quantise`` the counts are clipped and quantised and the measured g is the value before
    both; without it the measured g is clipped (if ``clipping`` is on) and counts is None. ``bias_g`` (n, 3) from ``bias_track`` interpolated to the samples;
    ``rng`` draws the white noise (None: no noise); ``noise``: the standard normals already drawn
    from it (``standard_normals(rng, (n, 3))``, float32, scaled in place) instead."""
    a = apply_deterministic(true_g, model, temperature_c=temperature_c, time_s=time_s,
                            accel_temperature_c=accel_temperature_c)
    if model.on("bias_instability") and bias_g is not None:
        a += bias_g
    sd = noise_sd_g(model, rate_hz)
    if (rng is not None or noise is not None) and np.any(sd > 0):
        z = standard_normals(rng, a.shape) if noise is None else noise
        per_axis(np.multiply, z, sd.astype(np.float32))  # z[:, j] * sd[j], then added
        if a.dtype == np.float32:
            a += z
        else:
            for j in range(3):
                a[:, j] += z[:, j]
    counts = None
    if quantise:  # a file can hold only the storable range: the counts are always clipped
        mode = model.get("quantisation", "mode", "nearest") if model.on("quantisation") else "nearest"
        counts = spec.to_counts(a, mode=mode)
    elif model.on("clipping"):
        lo, hi = spec.count_limits()
        np.clip(a, spec.to_g(lo[None, :])[0], spec.to_g(hi[None, :])[0], out=a)
    return a, counts


SENSOR_BLOCK = 32768  # samples per pass of the sensor model (a block's arrays stay in the CPU cache)


def measure_blocks(true_g: np.ndarray, model: SensorModel, spec: DeviceSpec, *, temperature_c,
                   time_s, accel_temperature_c, bias_g, rate_hz: float,
                   noise: Optional[np.ndarray], block: int = SENSOR_BLOCK) -> tuple[np.ndarray, np.ndarray]:
    """``measure`` (quantised) of a chunk with its white noise already drawn (``noise``, or None
    for a noiseless sensor), one block of rows at a time. Every step of the sensor model acts
    on each row alone, so the numbers are those of one call on the whole chunk; the block's
    intermediate arrays stay in the CPU cache instead of streaming a chunk's through memory.
    (A thermal lag computed here from the temperature series, without ``accel_temperature_c``,
    runs over the whole chunk in one call.)"""
    n = true_g.shape[0]
    if accel_temperature_c is None and model.on("thermal_lag"):
        block = max(n, 1)

    def rows(x, a, b):
        return None if x is None else x[a:b]

    meas = counts = None
    for a in range(0, max(n, 1), block):
        b = min(n, a + block)
        m, c = measure(true_g[a:b], model, spec, temperature_c=rows(temperature_c, a, b),
                       time_s=rows(time_s, a, b), accel_temperature_c=rows(accel_temperature_c, a, b),
                       bias_g=rows(bias_g, a, b), rng=None, rate_hz=rate_hz, noise=rows(noise, a, b))
        if b - a == n:
            return m, c
        if meas is None:
            meas, counts = np.empty((n, 3), m.dtype), np.empty((n, 3), c.dtype)
        meas[a:b] = m
        counts[a:b] = c
    return meas, counts
