"""`stillpoint demo`: make a recording with known sensor errors, process it, show before/after.

No arguments, no downloads. Simulates a 30-hour AX3 recording (50 Hz) of an adult wrist wearer
(engine/sim: sleep, sitting, standing, walking, nonwear, a skin-coupled device temperature) whose
accelerometer has known offset, gain and temperature errors, then runs `process --mode batch` on
it and prints what the calibration recovered against the truth, and ENMO before/after.
Files go to a temporary directory (or ``--keep DIR``).
"""

from __future__ import annotations

import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

from stillpoint.engine.calibration.estimate import status_applied
from stillpoint.engine.run import RunSettings, process_file
from ._numbers import SEED as SEED_NUMBER, number

from ._runopts import Progress, human_summary

NAME = "demo"
HELP = "simulate a recording with known sensor errors, process it and print before/after"

# The demo device's errors, as simulator effects (engine/sim/model.py): offsets and gains of the
# size van Hees 2014 reports, a temperature drift of up to 1 mg/degC, the AX3's own noise, and
# 1/256 g quantisation (AX3 unpacked, DATAMODE 20).
EFFECTS = {
    "offset": {"x_mg": 35.0, "y_mg": -25.0, "z_mg": 60.0},
    "gain": {"x_pct": 1.5, "y_pct": -1.5, "z_pct": 0.8},
    "temperature_offset": {"x_mg_per_c": 0.8, "y_mg_per_c": -0.5, "z_mg_per_c": 1.0,
                           "reference_c": 25.0},
    "noise": {},  # typical AX3 (ADXL345) noise density, filled in by the simulator
    "clipping": {},
    "quantisation": {"mode": "nearest"},
}
RATE_HZ = 50.0
HOURS = 30.0
SEED = 3  # two daytimes and a night: true mean ENMO 49 mg over the 30 h (seeds 1-8: 22-123 mg; seed 7 runs)


def _sim_args(hours: float, rate: float, seed: int) -> dict:
    return dict(device="ax3", site="wrist", days=hours / 24.0, hz=rate, effects=EFFECTS,
                seed=seed, packed=False)


def make_recording(path: Path, hours: float = HOURS, rate: float = RATE_HZ, seed: int = SEED) -> dict:
    """Simulate an adult wrist wearer with the demo's sensor errors and write it as an AX3 .cwa.

    Returns the truth: the sensor model, and mean ENMO of the uncorrected recording and of the
    same recording corrected with the *true* parameters (what a perfect calibration gives).
    """
    from stillpoint.engine.sim import ggir_equivalent, iter_chunks, simulate_recording

    truth = simulate_recording(path, truth_path=False, labels_path=False,
                               **_sim_args(hours, rate, seed))
    true_cal = ggir_equivalent(truth.sensor_model, 25.0)
    off, sc, to = (np.asarray(true_cal[k]) for k in ("offset", "scale", "tempoffset"))
    enmo_raw = enmo_true = 0.0
    n_total = 0
    for c in iter_chunks(**_sim_args(hours, rate, seed)):  # same seed: the same samples again
        g = c.counts / 256.0  # AX3 unpacked: 256 counts per g (drivers/constants.py)
        enmo_raw += float(np.maximum(np.linalg.norm(g, axis=1) - 1.0, 0.0).sum())
        cal = (g + off) * sc + (c.temperature_c - 25.0)[:, None] * to
        enmo_true += float(np.maximum(np.linalg.norm(cal, axis=1) - 1.0, 0.0).sum())
        n_total += c.n
    return {"samples": n_total, "model": truth.sensor_model,
            "enmo_true_mg": enmo_true / n_total * 1000.0,
            "enmo_uncorrected_mg": enmo_raw / n_total * 1000.0}


def true_correction(model, temperature_ref: float):
    """The GGIR-form parameters that exactly undo the demo's errors at ``temperature_ref``."""
    from stillpoint.engine.sim import ggir_equivalent

    d = ggir_equivalent(model, temperature_ref)
    return d["offset"], d["scale"], d["tempoffset"]


def add_arguments(p) -> None:
    p.add_argument("--keep", type=Path, metavar="DIR", help="keep the recording and outputs in DIR")
    p.add_argument("--hours", type=number(0, 24 * 31, lo_open=True, unit="h"), default=HOURS, help=f"recording length (default {HOURS:g})")
    p.add_argument("--seed", type=SEED_NUMBER, default=SEED, help=f"simulation seed (default {SEED})")


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
        truth = make_recording(rec, hours=args.hours, seed=args.seed)
        t_make = time.perf_counter() - t
        print(f"simulated {rec.name}: adult wrist, AX3 {RATE_HZ:g} Hz, {args.hours:g} h, "
              f"{truth['samples']:,} samples ({rec.stat().st_size / 1e6:.1f} MB) in {t_make:.1f} s")
        e = EFFECTS
        print("  sensor errors: gain " + " ".join(f"{e['gain'][a + '_pct']:+.1f}" for a in "xyz") + " %"
              + " | offset " + " ".join(f"{e['offset'][a + '_mg']:+.0f}" for a in "xyz") + " mg"
              + " | temperature " + " ".join(f"{e['temperature_offset'][a + '_mg_per_c']:+.1f}"
                                             for a in "xyz") + " mg/degC")
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
        if status_applied(c["status"]):
            off, sc, to = true_correction(truth["model"], c["temperature_ref"])
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
        print(f"ENMO mean: uncorrected {truth['enmo_uncorrected_mg']:.2f} mg | calibrated "
              f"{s['enmo_mean_mg']:.2f} mg | with the true parameters {truth['enmo_true_mg']:.2f} mg")
        if args.keep:
            print(f"\nfiles kept in {d} (open demo.mcap in Foxglove; topics /metrics/epoch, "
                  f"/corrected/accel, /calibration)")
        else:
            print("\n(the files above were temporary and are deleted now; `stillpoint demo --keep DIR` "
                  "keeps demo.cwa and demo.mcap)")
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
    return 0
