"""Window features of a simulated wrist recording, built from the simulator's own wearer, temperature
and sensor model without writing a file (the discrepancy workflow's hidden-effect tests and 20-seed
table).

Everything comes from engine.sim: one device on the wrist (``make_devices``) gives the body's
schedule, the device temperature track (every 10 s), the accelerometer temperature through the
truth's thermal lag over that whole track, the bias-instability track, and the truly still 10 s
windows with their gravity vector in the device frame and the worn micro-motion's window mean and
RMS (``DeviceSim.still_windows``). For each still window:

* deterministic sensor model: ``apply_deterministic(gravity + micro-motion mean, truth, temperature_c=T,
  time_s=t_mid, accel_temperature_c=T_a)`` plus the bias track at the window's middle;
* white noise and quantisation (the simulator's ``DeviceSpec``: AX3 at +-8 g, unpacked 1/256 g by
  default, packed 4/256 g on request), two ways that give the same window statistics:

  - ``method="samples"``: the window's 1000 samples (100 Hz) are drawn (the simulator's
    ``standard_normals``), quantised to counts (``DeviceSpec.to_counts``) and decoded; the window
    mean and sample SD are taken over them. Vectorised over blocks of 256 windows.
  - ``method="moments"`` (default, ~50x faster): exact in mean and variance, Gaussian in shape.
    With x the deterministic value and s the noise SD, a sample reads Q(x + s z); its mean m(x)
    and variance v(x) are computed exactly from the normal probabilities of the quantisation
    levels within +-7 s. The window mean of n iid samples is then m + sqrt(v / n) z (central limit
    theorem; n = 1000) and the sample SD sqrt(v * chi2(n-1) / (n-1)).
    ``tests/engine/workflows/test_discrepancy_simwindows.py`` checks both agree.

The window temperature is what the AX3 file holds: the MCP9700 reading quantised to 75/256 degC
(drivers.constants.cwa_temperature_c; the simulator's .cwa writer rounds the same way), one value
per sector (~1 s), averaged over the window as the engine's window operator does.

Moving windows are emitted with their temperature and a large SD (the workflow's still selection
drops them) so that dT/dt is estimated from the whole window sequence, as on a recording.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from stillpoint.engine.calibration.quantisation import level_moments
from stillpoint.engine.sim import model as sim
from stillpoint.engine.sim.device import DeviceSim, make_devices
from stillpoint.engine.sim.wearer import WearerParams
from stillpoint.engine.sim.sensor import DeviceSpec, noise_sd_g, standard_normals

from ..features import WindowFeatures

WINDOW_S = 10.0
RATE_HZ = 100.0
RANGE_G = 8
SECTOR_S = 1.0  # temperature: one reading per sector (AX3 at 100 Hz: 80-120 samples, 0.8-1.2 s)
TEMP_STEP_C = 75.0 / 256.0  # MCP9700 10-bit reading, drivers/constants.cwa_temperature_c ([CWA] section 9)
BLOCK = 256  # windows per block of simulated samples


@dataclass
class SimWindows:
    features: WindowFeatures  # every 10 s window, in time order (moving ones with SD 0.2 g)
    still: np.ndarray  # (n,) bool: truly still windows
    truth: sim.SensorModel  # the device's resolved model (what the windows were read through)
    device: DeviceSim


def window_statistics(x: np.ndarray, noise_sd: np.ndarray, spec: DeviceSpec, quantise: bool, n: int,
                      rng: np.random.Generator, method: str = "moments", dither_sd=None):
    """(mean, sample SD), each (k, 3) g, of windows of ``n`` samples that read ``x`` (k, 3) plus
    white noise of SD ``noise_sd`` (3,), quantised to the device's counts when ``quantise``.
    ``dither_sd`` (k, 3): a zero-mean movement within each window (the worn micro-motion) of that
    RMS, which adds to the samples' spread and dithers the quantisation but, being a smooth
    oscillation already averaged into ``x``, adds no scatter to the window mean.
    ``method``: "samples" (draw them; the movement as a 1.1 Hz sine of random phase) or
    "moments" (exact mean/variance, Gaussian shape)."""
    if method not in ("moments", "samples"):
        raise ValueError(f"method must be 'moments' or 'samples', got {method!r}")
    nsd = np.asarray(noise_sd, np.float64)
    dit = np.zeros_like(x) if dither_sd is None else np.asarray(dither_sd, np.float64)
    if method == "moments":
        s = np.sqrt(nsd ** 2 + dit ** 2)
        if quantise:
            m, v = level_moments(x, s, float(spec.lsb_g[0]))
        else:
            m, v = x, s ** 2
        mean = m + np.sqrt(np.maximum(v - dit ** 2, 0.0) / n) * rng.standard_normal(x.shape)
        sd = np.sqrt(v * rng.chisquare(n - 1, size=x.shape) / (n - 1))
        return mean, sd
    mean = np.empty_like(x)
    sd = np.empty_like(x)
    cpg = spec.counts_per_g.astype(np.float64)
    wave = np.sqrt(2.0) * np.sin(2 * np.pi * 1.1 * WINDOW_S * np.arange(n) / n)  # 11 cycles
    for b in range(0, x.shape[0], BLOCK):
        xb = x[b:b + BLOCK]
        a = standard_normals(rng, (xb.shape[0], n, 3)) * nsd.astype(np.float32)
        a += xb[:, None, :].astype(np.float32)
        if dither_sd is not None:
            shift = rng.integers(0, n, (xb.shape[0], 3))
            a += (np.take(wave, (np.arange(n)[None, :, None] + shift[:, None, :]) % n)
                  * dit[b:b + BLOCK, None, :]).astype(np.float32)
        g = spec.to_counts(a.reshape(-1, 3)).reshape(a.shape) / cpg if quantise else a.astype(np.float64)
        mean[b:b + BLOCK] = g.mean(axis=1)
        sd[b:b + BLOCK] = g.std(axis=1, ddof=1)
    return mean, sd


def _window_temperature(dev: DeviceSim, w0: np.ndarray) -> np.ndarray:
    """The file's window temperature: quantised sector readings averaged over the window."""
    k = int(round(WINDOW_S / SECTOR_S))
    t = w0[:, None] + (np.arange(k) + 0.5) * SECTOR_S
    T = np.interp(t, dev.t_grid, dev.T_grid)
    raw = np.rint((T + 50.0) / TEMP_STEP_C)
    return np.mean(raw * TEMP_STEP_C - 50.0, axis=1)


def simulate_windows(truth: sim.SensorModel, days: float = 7.0, seed: int = 0, *,
                     packed: bool = False, method: str = "moments",
                     wearer: Optional[WearerParams] = None) -> SimWindows:
    """Window features of a ``days``-long wrist recording whose sensor is ``truth``.

    ``truth`` is resolved per device by the simulator (explicit values kept). ``packed``: AX3
    packed mode (4/256 g step at +-8 g) instead of unpacked (1/256 g). ``method``: "moments"
    or "samples" (see the module docstring). ``wearer``: the simulator's behaviour parameters
    (default: its typical adult)."""
    if method not in ("moments", "samples"):
        raise ValueError(f"method must be 'moments' or 'samples', got {method!r}")
    dev = make_devices(sites=["wrist"], devices=["ax3"], days=days, hz=RATE_HZ, seed=seed,
                       models=[truth], range_g=RANGE_G, packed=packed, wearer=wearer)[0]
    model = dev.model
    sw = dev.still_windows()
    idx = sw["window"]
    t_mid = sw["true_start_s"] + 0.5 * WINDOW_S
    x = sim.apply_deterministic(sw["gravity"] + sw["micro_mean"], model,
                                temperature_c=sw["temperature_c"], time_s=t_mid,
                                accel_temperature_c=sw["accel_temperature_c"])
    if model.on("bias_instability"):
        x = x + np.column_stack([np.interp(t_mid, dev.t_grid, dev.bias_grid[:, j]) for j in range(3)])
    n = int(round(WINDOW_S * RATE_HZ))
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 41]))
    mean, sd = window_statistics(x, noise_sd_g(model, RATE_HZ), dev.spec, model.on("quantisation"),
                                 n, rng, method, dither_sd=sw["micro_sd"])

    nw = int(np.ceil(dev.duration_s / WINDOW_S))
    w0_all = np.arange(nw) * WINDOW_S
    still = np.zeros(nw, bool)
    still[idx] = True
    mean_all = np.empty((nw, 3))
    sd_all = np.full((nw, 3), 0.2)
    mv = ~still
    u = rng.normal(size=(int(mv.sum()), 3))
    mean_all[mv] = u / np.linalg.norm(u, axis=1, keepdims=True)
    mean_all[idx] = mean
    sd_all[idx] = sd
    temp = _window_temperature(dev, w0_all)
    start_ns = np.round(w0_all * 1e9).astype(np.int64)
    feats = WindowFeatures.from_arrays(mean_all, sd_all, temp, start_ns=start_ns,
                                       n=np.full(nw, n))
    return SimWindows(feats, still, model, dev)
