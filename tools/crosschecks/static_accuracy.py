"""Accuracy of the six-orientation static calibration and of calibrated infant movement counts, on
simulated data (engine.sim.sixface / engine.sim.infant), with and without cross-axis coupling.

1. Six-face sessions with Table-2-like errors (offsets within ±0.2 g, gains 0.99-1.015), sigma =
   3 mg, 1-3 s hand turns with jitter, handling before and after: max |offset error| (goal <= 1 mg)
   and max |gain error| (goal <= 0.1 %) per mode, for
   * 10-s holds, no coupling;
   * hand-timed holds of 7-12 s (unequal), no coupling;
   * the same with symmetric cross-axis coupling of 1-2 % on every axis pair (random signs);
   * the same on a table tilted by 1 degree (the device at a random yaw per hold);
   * brisk (constant-speed) turns instead of a slow approach to each face, 10-s holds.
   Also: max |coupling error| (estimated vs true off-diagonal of S, mg per g), the full matrix's
   offset error, and a row "robust, pooled" = the robust windows with the paper's pooled
   non-gravity offset rule (what robust mode used before it took the face-pair midpoints).
2. Infant recordings (25 Hz, 6 postures) seen by a sensor with Table-2-like errors and by an
   error-free sensor with the same noise, without and with 1-2 % coupling: movement-count error
   before and after calibration (from a simulated session with the same errors and 7-12 s holds:
   robust offset and gain, robust full matrix, reference).

    python tools/crosschecks/static_accuracy.py [--sessions 20] [--recordings 10] [--minutes 20]
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
HOLDS = (7.0, 12.0)  # hand-timed holds: "count to ten"


def draw(rng, coupling: float, *, offset_max_g: float = 0.2, noise_g: float = 0.003) -> StaticErrors:
    """Table-2-like errors; ``coupling``: symmetric cross-axis terms of coupling/2..coupling on
    every axis pair, random signs (0: none)."""
    e = StaticErrors.draw(rng, offset_max_g=offset_max_g, noise_range_g=(noise_g, noise_g))
    if coupling:
        e.symmetric = list(rng.choice([-1.0, 1.0], 3) * rng.uniform(coupling / 2, coupling, 3))
    return e


def off_diagonal(m) -> np.ndarray:
    m = np.asarray(m, np.float64)
    return m - np.diag(np.diag(m))


def sessions(n: int, fs: float, *, coupling: float = 0.0, holds=10.0, tilt: float = 0.0,
             profile: str = "smooth") -> None:
    hold_txt = f"{holds:g} s holds" if np.isscalar(holds) else f"{holds[0]:g}-{holds[1]:g} s holds"
    print(f"six-face sessions: {n} per mode, {fs:g} Hz, sigma 3 mg, {hold_txt}, 1-3 s {profile} "
          f"turns with jitter, " + (f"symmetric coupling {coupling * 50:g}-{coupling * 100:g} %"
                                    if coupling else "no coupling")
          + (f", table tilted {tilt:g} deg" if tilt else ""))
    print(f"  {'mode':<14} {'max |offset err| mg':>19} {'median mg':>10} {'max |gain err| %':>17} "
          f"{'failed':>7}  {'coupling err mg/g':>17} {'matrix offset err mg':>20}")
    for mode in MODES + ("robust, pooled",):
        off, gain, cpl, moff, failed = [], [], [], [], 0
        for seed in range(n):
            rng = np.random.default_rng((seed, 1))
            e = draw(rng, coupling)
            hs = holds if np.isscalar(holds) else rng.uniform(*holds, 6)
            s = simulate_sixface(fs=fs, errors=e, seed=seed, hold_s=hs, turn_profile=profile,
                                 table_tilt_deg=tilt)
            try:
                c = static_calibration(s.accel_g, fs, mode=mode.split(",")[0], full_matrix=True)
            except StaticCalibrationError:
                failed += 1
                continue
            o = c.diagnostics["non_gravity_offset_g"] if mode.endswith("pooled") else c.offset_g
            off.append(np.abs(np.asarray(o) - e.offset_g).max() * 1000)
            gain.append(np.abs(np.asarray(c.gain) / np.asarray(e.gain) - 1).max() * 100)
            cpl.append(np.abs(off_diagonal(c.cross_axis_g) - off_diagonal(e.matrix)).max() * 1000)
            moff.append(np.abs(np.asarray(c.matrix_offset_g) - e.offset_g).max() * 1000)
        print(f"  {mode:<14} {max(off):19.3f} {np.median(off):10.3f} {max(gain):17.4f} {failed:7d}  "
              f"{max(cpl):17.2f} {max(moff):20.3f}")


def infants(n: int, minutes: float, fs: float, coupling: float) -> None:
    print(f"infant recordings: {n} x {minutes:g} min at {fs:g} Hz, 6 postures, Table-2-like errors "
          "(offsets within ±0.1 g, gains 0.99-1.015, sigma 2 mg"
          + (f", symmetric coupling {coupling * 50:g}-{coupling * 100:g} %" if coupling else
             ", no coupling")
          + "); count error vs the error-free sensor")
    rows = []
    for seed in range(n):
        rng = np.random.default_rng((seed, 2))
        e = draw(rng, coupling, offset_max_g=0.1, noise_g=0.002)
        ideal = make_infant(minutes=minutes, fs=fs, seed=seed, n_postures=6,
                            errors=StaticErrors(noise_g=e.noise_g))
        bad = make_infant(minutes=minutes, fs=fs, seed=seed, n_postures=6, errors=e)
        t, free, _, gyro = ideal.arrays()
        _, raw, _, _ = bad.arrays()
        session = simulate_sixface(fs=fs, errors=e, seed=seed + 1000, hold_s=rng.uniform(*HOLDS, 6))

        def count(acc, correct=None):
            return detect_signals(signals_from_arrays(t, acc, gyro, fs, correct))["movements"].shape[0]

        row = [bad.truth()["kick_count"], count(free), count(raw)]
        rob = static_calibration(session.accel_g, fs, mode="robust", full_matrix=True)
        row.append(count(raw, lambda g: rob.apply(g, full_matrix=False)))
        row.append(count(raw, lambda g: rob.apply(g, full_matrix=True)))
        ref = static_calibration(session.accel_g, fs, mode="reference")
        row.append(count(raw, ref.apply))
        rows.append(row)
    r = np.asarray(rows, float)
    rel = lambda k: 100 * (r[:, k] - r[:, 1]) / r[:, 1]  # noqa: E731
    print(f"  simulated kicks {r[:, 0].sum():.0f}, error-free detector count {r[:, 1].sum():.0f} "
          f"({100 * r[:, 1].sum() / r[:, 0].sum():.1f} % of kicks)")
    for k, name in ((2, "uncalibrated"), (3, "robust, offset + gain"), (4, "robust, full matrix"),
                    (5, "reference")):
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
    sessions(a.sessions, 25.0)
    sessions(a.sessions, 25.0, holds=HOLDS)
    sessions(a.sessions, 25.0, holds=HOLDS, coupling=0.02)
    sessions(a.sessions, 25.0, holds=HOLDS, coupling=0.02, tilt=1.0)
    sessions(a.sessions, 25.0, profile="linear")
    infants(a.recordings, a.minutes, 25.0, 0.0)
    infants(a.recordings, a.minutes, 25.0, 0.02)
    print(f"done in {time.perf_counter() - t0:.1f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
