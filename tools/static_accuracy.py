"""Accuracy of the six-orientation static calibration and of calibrated infant movement counts, on
simulated data (engine.sim.sixface / engine.sim.infant).

1. Six-face sessions with Table-2-like errors (offsets within ±0.2 g, gains 0.99-1.015), sigma =
   3 mg, 10-s holds, 1-3 s hand turns with jitter, handling before and after: max |offset error|
   (goal <= 1 mg) and max |gain error| (goal <= 0.1 %) per mode; also with 0.025 cross-axis terms
   and with brisk (constant-speed) turns instead of a slow approach to each face.
2. Infant recordings (25 Hz, several postures) seen by a sensor with Table-2-like errors and by an
   error-free sensor with the same noise: movement-count error before and after calibration
   (calibration from a simulated session with the same errors, robust and reference modes).

    python tools/static_accuracy.py [--sessions 20] [--recordings 10] [--minutes 20]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from stillpoint.engine.calibration.static import StaticCalibrationError, static_calibration
from stillpoint.engine.movements.leg import detect_signals
from stillpoint.engine.movements.signals import signals_from_arrays
from stillpoint.engine.sim.infant import make_infant
from stillpoint.engine.sim.sixface import simulate_sixface
from stillpoint.engine.sim.static_errors import StaticErrors

MODES = ("reference", "paper", "robust")


def sessions(n: int, fs: float, cross: float, profile: str = "smooth") -> None:
    print(f"six-face sessions: {n} per mode, {fs:g} Hz, sigma 3 mg, 10 s holds, 1-3 s {profile} "
          f"turns with jitter, cross-axis terms up to {cross:g}")
    print(f"  {'mode':<10} {'max |offset err| mg':>20} {'median mg':>10} {'max |gain err| %':>17} "
          f"{'failed':>7}")
    for mode in MODES:
        off, gain, failed = [], [], 0
        for seed in range(n):
            e = StaticErrors.draw(np.random.default_rng((seed, 1)), cross_max=cross,
                                  noise_range_g=(0.003, 0.003))
            s = simulate_sixface(fs=fs, errors=e, seed=seed, hold_s=10.0, turn_profile=profile)
            try:
                c = static_calibration(s.accel_g, fs, mode=mode)
            except StaticCalibrationError:
                failed += 1
                continue
            off.append(np.abs(np.asarray(c.offset_g) - e.offset_g).max() * 1000)
            gain.append(np.abs(np.asarray(c.gain) / np.asarray(e.gain) - 1).max() * 100)
        print(f"  {mode:<10} {max(off):20.3f} {np.median(off):10.3f} {max(gain):17.4f} {failed:7d}")


def infants(n: int, minutes: float, fs: float) -> None:
    print(f"infant recordings: {n} x {minutes:g} min at {fs:g} Hz, 6 postures, Table-2-like errors "
          "(offsets within ±0.1 g, gains 0.99-1.015, sigma 2 mg); count error vs the error-free sensor")
    rows = []
    for seed in range(n):
        rng = np.random.default_rng((seed, 2))
        e = StaticErrors.draw(rng, offset_max_g=0.1, noise_range_g=(0.002, 0.002))
        ideal = make_infant(minutes=minutes, fs=fs, seed=seed, n_postures=6,
                            errors=StaticErrors(noise_g=e.noise_g))
        bad = make_infant(minutes=minutes, fs=fs, seed=seed, n_postures=6, errors=e)
        t, free, _, gyro = ideal.arrays()
        _, raw, _, _ = bad.arrays()
        session = simulate_sixface(fs=fs, errors=e, seed=seed + 1000)

        def count(acc, correct=None):
            return detect_signals(signals_from_arrays(t, acc, gyro, fs, correct))["movements"].shape[0]

        c_free, c_raw = count(free), count(raw)
        row = [bad.truth()["kick_count"], c_free, c_raw]
        for mode in ("robust", "reference"):
            cal = static_calibration(session.accel_g, fs, mode=mode)
            row.append(count(raw, cal.apply))
        rows.append(row)
    r = np.asarray(rows, float)
    rel = lambda k: 100 * (r[:, k] - r[:, 1]) / r[:, 1]  # noqa: E731
    print(f"  simulated kicks {r[:, 0].sum():.0f}, error-free detector count {r[:, 1].sum():.0f} "
          f"({100 * r[:, 1].sum() / r[:, 0].sum():.1f} % of kicks)")
    for k, name in ((2, "uncalibrated"), (3, "calibrated (robust)"), (4, "calibrated (reference)")):
        print(f"  {name:<24} mean |count error| {np.mean(np.abs(rel(k))):6.2f} %   max "
              f"{np.max(np.abs(rel(k))):6.2f} %   recordings with exactly the error-free count "
              f"{int(np.sum(r[:, k] == r[:, 1]))}/{len(r)}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sessions", type=int, default=20)
    ap.add_argument("--recordings", type=int, default=10)
    ap.add_argument("--minutes", type=float, default=20.0)
    a = ap.parse_args(argv)
    t0 = time.perf_counter()
    sessions(a.sessions, 25.0, 0.0)
    sessions(a.sessions, 25.0, 0.025)
    sessions(a.sessions, 25.0, 0.0, "linear")
    infants(a.recordings, a.minutes, 25.0)
    print(f"done in {time.perf_counter() - t0:.1f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
