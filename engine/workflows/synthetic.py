"""Window-level simulation of a wrist recording for the discrepancy workflow's hidden-effect tests.

Simulating raw samples for a week takes seconds per seed; the workflow only sees 10 s window
features, so for many seeds we simulate at that level: a wearer timeline (sleep with posture
changes, daytime still bouts, nonwear on a table), the device temperature (skin-coupled when worn,
a daily cycle, cooling towards ambient in nonwear), the true orientation of every still window,
then the simulator's sensor model's deterministic part (``engine.sim.model.apply_deterministic``)
plus window-level errors: the model's bias instability (Gauss-Markov wander, when on), the bias
that quantisation leaves in a window mean when the noise does not dither it (when
``quantisation`` is on; step ``WearerSettings.lsb_g``, AX3 unpacked 1/256 g by default, packed
+-8 g is 4/256 g), and micro-movements within the 13 mg still criterion. Moving windows are emitted
too (large SD) so that still selection and dT/dt estimation run exactly as on a recording.

``simulate_windows(truth, days, seed)`` -> (WindowFeatures, still mask); truth is an engine.sim
SensorModel.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter

from ..features import WindowFeatures
from stillpoint.engine.sim import model as sim

WINDOW_S = 10.0
PER_DAY = int(86400 / WINDOW_S)


@dataclass
class WearerSettings:
    """Defaults give an adult wrist; temperatures in degC, times in minutes unless stated."""

    sleep_start_h: float = 23.0
    sleep_hours: float = 8.0
    posture_change_min: float = 40.0  # mean time between posture changes in sleep
    day_still_fraction: float = 0.25  # fraction of waking time in still bouts
    day_still_bout_min: float = 4.0  # median still bout during the day
    nonwear_per_day: float = 0.5  # expected nonwear bouts (device on a table) per day
    nonwear_hours: float = 2.0
    skin_c: float = 32.5  # worn, at rest, mean
    skin_daily_amp_c: float = 1.5  # warmer at night
    active_cooling_c: float = 2.0  # worn while moving: cooler
    ambient_c: float = 22.0
    device_tau_min: float = 12.0  # device housing follows skin/ambient with this time constant
    micro_motion_mg: float = 1.5  # SD of a still window's mean from micro-movements, per axis
    noise_mg: float = 4.5  # SD of white noise of single samples (for the window SD feature)
    samples_per_window: int = 1000
    rate_hz: float = 100.0  # for the model's noise density -> sample SD
    lsb_g: float = 1.0 / 256.0  # quantisation step when on: AX3 unpacked (packed +-8 g: 4/256)


def quantisation_bias(x: np.ndarray, lsb: float, sigma: np.ndarray, harmonics: int = 6) -> np.ndarray:
    """E[Q(x + n)] - x for a rounding quantiser of step ``lsb`` and Gaussian noise of SD ``sigma``
    (the noise and movement within a window): the window mean of quantised samples is biased by
    a periodic function of the true value, damped as the noise dithers it. From the sawtooth's
    Fourier series, Q(v) = v + (lsb / pi) sum_k (-1)^k sin(2 pi k v / lsb) / k."""
    out = np.zeros_like(x)
    for k in range(1, harmonics + 1):
        damp = np.exp(-2.0 * (np.pi * k * sigma / lsb) ** 2)
        out += ((-1) ** k / k) * damp * np.sin(2.0 * np.pi * k * x / lsb)
    return out * (lsb / np.pi)


def _random_unit(rng, n):
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _wrist_orientation(rng, n):
    """Mostly uniform on the sphere, part clustered around resting forearm postures."""
    u = _random_unit(rng, n)
    rest = np.array([[-0.9, 0.1, 0.4], [0.2, -0.2, -0.95], [0.1, 0.95, 0.2], [0.6, 0.0, 0.8]])
    pick = rng.random(n) < 0.35
    k = rng.integers(0, len(rest), n)
    c = rest[k] + rng.normal(scale=0.25, size=(n, 3))
    c /= np.linalg.norm(c, axis=1, keepdims=True)
    u[pick] = c[pick]
    return u


def _timeline(rng, days, s: WearerSettings):
    """Per-window state: 0 moving (worn), 1 still (worn), 2 nonwear (still, on a table), bout ids."""
    n = int(days * PER_DAY)
    hour = (np.arange(n) * WINDOW_S / 3600.0) % 24.0
    state = np.zeros(n, np.int8)
    bout = np.zeros(n, np.int64)
    bid = 0
    i = 0
    while i < n:
        h = hour[i]
        asleep = ((h - s.sleep_start_h) % 24.0) < s.sleep_hours
        if asleep:
            dur = max(1, int(rng.exponential(s.posture_change_min) * 6))
            state[i:i + dur] = 1
            bid += 1
            bout[i:i + dur] = bid
            i += dur
            mv = int(rng.integers(3, 12))  # turning over: 30-120 s of movement
            i += mv
            continue
        if rng.random() < s.nonwear_per_day * 5.0 / (16 * 60):  # one check per ~5 min of waking
            dur = int(rng.uniform(0.5, 1.5) * s.nonwear_hours * 360)
            state[i:i + dur] = 2
            bid += 1
            bout[i:i + dur] = bid
            i += dur
            continue
        if rng.random() < s.day_still_fraction:
            dur = max(1, int(rng.lognormal(np.log(s.day_still_bout_min * 6), 0.8)))
            state[i:i + dur] = 1
            bid += 1
            bout[i:i + dur] = bid
            i += dur
        else:
            i += int(rng.integers(6, 60))
    return state[:n], bout[:n], hour


def _temperatures(rng, state, hour, s: WearerSettings):
    """The device temperature (what the temperature sensor reads, before its own noise)."""
    night = np.cos(2 * np.pi * (hour - 3.0) / 24.0)
    target = s.skin_c + s.skin_daily_amp_c * night
    target = np.where(state == 0, target - s.active_cooling_c, target)
    amb = s.ambient_c + 1.0 * np.cos(2 * np.pi * (hour - 15.0) / 24.0)
    target = np.where(state == 2, amb, target)
    target = target + np.cumsum(rng.normal(scale=0.02, size=state.shape))  # slow wander
    a = WINDOW_S / (s.device_tau_min * 60.0)
    return lfilter([a], [1.0, -(1.0 - a)], target, zi=[target[0] * (1 - a)])[0]


def simulate_windows(truth: sim.SensorModel, days: float = 7.0, seed: int = 0,
                     settings: WearerSettings | None = None):
    """Window features of a simulated wrist recording read through the simulator's sensor model.

    The deterministic part of ``truth`` (engine.sim.model.apply_deterministic, thermal lag
    included, computed over the whole window series) is applied to each window's true
    orientation; then window-level noise. Returns (WindowFeatures of every window, moving and
    still; boolean mask of the truly still windows).
    """
    s = settings or WearerSettings()
    rng = np.random.default_rng(seed)
    state, bout, hour = _timeline(rng, days, s)
    n = state.shape[0]
    temp = _temperatures(rng, state, hour, s)

    still = state > 0
    nb = int(bout.max()) + 1
    ub = _wrist_orientation(rng, nb)
    table = np.array([0.0, 0.0, 1.0]) * rng.choice([-1.0, 1.0], nb)[:, None] \
        + rng.normal(scale=0.03, size=(nb, 3))
    table /= np.linalg.norm(table, axis=1, keepdims=True)
    is_nonwear_bout = np.zeros(nb, bool)
    is_nonwear_bout[bout[state == 2]] = True
    ub[is_nonwear_bout] = table[is_nonwear_bout]
    u = ub[bout]
    jit = np.where(state[:, None] == 1, rng.normal(scale=0.01, size=(n, 3)), 0.0)  # ~0.5 deg
    u = u + jit
    u /= np.linalg.norm(u, axis=1, keepdims=True)

    t_s = np.arange(n) * WINDOW_S + WINDOW_S / 2
    mean = sim.apply_deterministic(u, truth, temperature_c=temp, time_s=t_s)
    if truth.on("bias_instability"):
        # Gauss-Markov bias wander on the window grid (the simulator's non-deterministic term)
        sig = truth.axis_vector("bias_instability", "mg") / 1000.0
        tau = float(truth.get("bias_instability", "tau_s", 3600.0))
        a = np.exp(-WINDOW_S / tau)
        e = rng.normal(size=(n, 3)) * sig * np.sqrt(1 - a * a)
        e[0] = rng.normal(size=3) * sig
        mean = mean + lfilter([1.0], [1.0, -a], e, axis=0)
    mm = s.micro_motion_mg / 1000.0
    if truth.on("noise"):
        white = truth.axis_vector("noise", "ug_per_rthz") * 1e-6 * np.sqrt(s.rate_hz / 2.0)
    else:
        white = np.full(3, s.noise_mg / 1000.0)
    sd = np.sqrt(white ** 2 + np.where(state[:, None] == 1, (3 * mm) ** 2, 0.0)
                 ) * rng.uniform(0.9, 1.1, size=(n, 3))
    if truth.on("quantisation") and s.lsb_g > 0:
        mean = mean + quantisation_bias(mean, s.lsb_g, sd)
    mean = mean + np.where(state[:, None] == 1, rng.normal(scale=mm, size=(n, 3)),
                           rng.normal(scale=0.2 * mm, size=(n, 3)))
    # moving windows: dynamic acceleration, large SD, mean somewhere near 1 g
    moving = ~still
    k = int(moving.sum())
    mean[moving] = _random_unit(rng, k) * rng.uniform(0.7, 1.3, (k, 1))
    sd[moving] = rng.uniform(0.05, 0.5, size=(k, 3))
    start_ns = (np.arange(n) * int(WINDOW_S * 1e9)).astype(np.int64)
    reading = temp + rng.normal(scale=0.03, size=n)  # the sensor's window-mean temperature
    feats = WindowFeatures.from_arrays(mean, sd, reading, start_ns=start_ns,
                                       n=np.full(n, s.samples_per_window))
    return feats, still
