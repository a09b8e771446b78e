"""A fast synthetic AX3 recording for engine tests: still postures in random orientations every
few minutes (so the sphere is covered within an hour), walking bouts, a night of sleep and a
day/night temperature cycle, with known offset, gain and temperature errors.

The demo and the realism checks use the simulator (engine/sim); the engine tests use this
generator because it covers the 1 g sphere within 1-4 hours, which a realistic wearer does not.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

# The demo device's errors (sensor form: measured = true * gain + bias + (T - T_REF) * temp_coef)
GAIN = np.array([1.015, 0.985, 1.008])
BIAS_G = np.array([0.035, -0.025, 0.060])
TEMP_COEF_G_PER_C = np.array([0.0008, -0.0005, 0.0010])
T_REF_C = 25.0
NOISE_G = 0.004

# the simulator's ``effects`` of a device with sensor errors of tens of mg (offsets) and percent
# (gains): uncorrected, a day's ENMO is off by far more than 3 %
SENSOR_ERRORS = {"offset": {"x_mg": 60.0, "y_mg": -45.0, "z_mg": 70.0},
                 "gain": {"x_pct": 1.5, "y_pct": -1.2, "z_pct": 2.0}, "noise": {}}

RATE_HZ = 50.0
HOURS = 30.0


def true_correction(temperature_ref: float):
    """The GGIR-form parameters that undo the demo's errors (for a given reference temperature):
    cal = (raw + offset) * scale + (T - Tref) * tempoffset."""
    scale = 1.0 / GAIN
    # raw = true*gain + bias + (T - T_REF)*c  ->  true = (raw - bias - (T - T_REF)*c) / gain
    # with T - T_REF = (T - Tref) + (Tref - T_REF):
    offset = -(BIAS_G + (temperature_ref - T_REF_C) * TEMP_COEF_G_PER_C)
    tempoffset = -TEMP_COEF_G_PER_C / GAIN
    return offset, scale, tempoffset


def _schedule(rng, hours):
    """(kind, seconds, orientation) bouts: still postures, walking, and a night of sleep."""
    bouts, t, total = [], 0.0, hours * 3600
    while t < total:
        hour = (t / 3600 + 8) % 24  # the recording starts at 08:00
        if hour >= 23 or hour < 7:
            kind, dur = "sleep", rng.uniform(20, 60) * 60
        else:
            kind = rng.choice(["still", "walk", "still", "fidget"])
            dur = rng.uniform(1, 15) * 60
        v = rng.normal(size=3)
        v /= np.linalg.norm(v)
        bouts.append((kind, min(dur, total - t), v))
        t += dur
    return bouts


def make_recording(path: Path, hours: float = HOURS, rate: float = RATE_HZ, seed: int = 7) -> dict:
    """Write the demo .cwa; return truth: ENMO of a perfect sensor (same motion and noise, no
    offset/gain/temperature errors) and of the uncorrected recording."""
    from stillpoint.drivers.cwa import CwaWriter
    rng = np.random.default_rng(seed)
    t0 = 1_700_000_000 * 10**9  # 2023-11-14 22:13:20 UTC
    step = int(round(1e9 / rate))
    enmo_true = enmo_raw = 0.0
    n_total = 0
    with CwaWriter(path, device_type="AX3", device_id=4242, session_id=1, rate_hz=rate, range_g=8,
                   packed=False) as w:
        i0 = 0
        for kind, dur, v in _schedule(rng, hours):
            n = int(dur * rate)
            if n <= 0:
                continue
            i = np.arange(i0, i0 + n)
            ts = i / rate
            g = np.tile(v, (n, 1))
            if kind == "walk":
                g = g + 0.35 * np.sin(2 * np.pi * 1.9 * ts)[:, None] * np.array([0.3, 0.9, 0.3])
                g += rng.normal(0, 0.08, size=g.shape)
            elif kind == "fidget":
                g = g + rng.normal(0, 0.05, size=g.shape)
            temp = 29.0 + 4.0 * np.sin(2 * np.pi * ts / 86400.0) + (kind == "sleep") * 1.5
            ideal = g + rng.normal(0, NOISE_G, size=g.shape)  # a perfect sensor: noise only
            meas = ideal * GAIN + BIAS_G + (temp - T_REF_C)[:, None] * TEMP_COEF_G_PER_C
            counts = np.clip(np.round(meas * 256), -32768, 32767).astype(np.int16)
            code = np.round((temp + 50.0) * 256 / 75).astype(np.int32)
            w.write(t0 + i * step, counts, temperature_raw=code)
            enmo_true += float(np.maximum(np.linalg.norm(np.round(ideal * 256) / 256, axis=1) - 1,
                                          0).sum())
            enmo_raw += float(np.maximum(np.linalg.norm(counts / 256.0, axis=1) - 1, 0).sum())
            n_total += n
            i0 += n
    return {"samples": n_total, "enmo_true_mg": enmo_true / n_total * 1000,
            "enmo_uncorrected_mg": enmo_raw / n_total * 1000}
