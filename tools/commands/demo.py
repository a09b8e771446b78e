"""`stillpoint demo`: make a recording with known sensor errors, process it, show before/after.

No arguments, no downloads. Writes a 30-hour AX3 recording (50 Hz) of a simulated wearer (still
postures in many orientations, walking bouts, a night of sleep, a day/night temperature cycle)
whose accelerometer has known offset, gain and temperature errors, then runs `process --mode
batch` on it and prints what the calibration recovered against the truth, and ENMO before/after.
Files go to a temporary directory (or ``--keep DIR``).
"""

from __future__ import annotations

import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

from stillpoint.engine.run import RunSettings, process_file

from ._runopts import Progress, human_summary

NAME = "demo"
HELP = "simulate a recording with known sensor errors, process it and print before/after"

# The demo device's errors (sensor form: measured = true * gain + bias + (T - T_REF) * temp_coef)
GAIN = np.array([1.015, 0.985, 1.008])
BIAS_G = np.array([0.035, -0.025, 0.060])
TEMP_COEF_G_PER_C = np.array([0.0008, -0.0005, 0.0010])
T_REF_C = 25.0
NOISE_G = 0.004
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


def add_arguments(p) -> None:
    p.add_argument("--keep", type=Path, metavar="DIR", help="keep the recording and outputs in DIR")
    p.add_argument("--hours", type=float, default=HOURS, help=f"recording length (default {HOURS:g})")


def run(args) -> int:
    tmp = None
    if args.keep:
        d = args.keep
        d.mkdir(parents=True, exist_ok=True)
    else:
        d = Path(tempfile.mkdtemp(prefix="stillpoint-demo-"))
        tmp = d
    try:
        t = time.perf_counter()
        rec = d / "demo.cwa"
        truth = make_recording(rec, hours=args.hours)
        t_make = time.perf_counter() - t
        print(f"made {rec.name}: AX3 {RATE_HZ:g} Hz, {args.hours:g} h, {truth['samples']:,} samples "
              f"({rec.stat().st_size / 1e6:.1f} MB) in {t_make:.1f} s")
        print("  sensor errors: gain " + " ".join(f"{x:.3f}" for x in GAIN)
              + " | bias " + " ".join(f"{x * 1000:+.0f}" for x in BIAS_G) + " mg"
              + " | temperature " + " ".join(f"{x * 1000:+.1f}" for x in TEMP_COEF_G_PER_C) + " mg/degC")
        progress = Progress()
        t = time.perf_counter()
        try:
            s = process_file(rec, d / "demo.mcap", RunSettings(mode="batch"), progress=progress)
        finally:
            progress.done()
        t_proc = time.perf_counter() - t
        print(f"\nstillpoint process --mode batch demo.cwa  ({t_proc:.1f} s)\n")
        print(human_summary(s))
        c = s["calibration"]
        if c["status"] in ("ok", "high_error"):
            off, sc, to = true_correction(c["temperature_ref"])
            print("\n                 x          y          z")
            print("offset  true  " + " ".join(f"{x:+.5f}  " for x in off))
            print("        fit   " + " ".join(f"{x:+.5f}  " for x in c["offset"]))
            print("scale   true  " + " ".join(f"{x:.5f}   " for x in sc))
            print("        fit   " + " ".join(f"{x:.5f}   " for x in c["scale"]))
            print("tempoff true  " + " ".join(f"{x:+.6f} " for x in to))
            print("        fit   " + " ".join(f"{x:+.6f} " for x in c["tempoffset"]))
        if c["error_before_mg"] is not None and c["error_after_mg"] is not None:
            print(f"\ncalibration error: {c['error_before_mg']:.1f} mg before -> "
                  f"{c['error_after_mg']:.1f} mg after")
        else:
            print(f"\ncalibration not applied: {c['status']}")
        print(f"ENMO mean: perfect sensor {truth['enmo_true_mg']:.2f} mg | uncorrected "
              f"{truth['enmo_uncorrected_mg']:.2f} mg | calibrated {s['enmo_mean_mg']:.2f} mg")
        if args.keep:
            print(f"\nfiles kept in {d} (open demo.mcap in Foxglove; topics /metrics/epoch, "
                  f"/corrected/accel, /calibration)")
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
    return 0
