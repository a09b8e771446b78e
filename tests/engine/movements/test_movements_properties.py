"""Properties of calibration and movement counts implied by Oh, Loeb & Smith 2024 (spec §5.4), on
simulated infant recordings: the error-free sensor shares the noise realisation of the sensor with
errors, and the calibration comes from a simulated six-face session with the same errors."""

from __future__ import annotations

import numpy as np

from stillpoint.engine.calibration.static import static_calibration
from stillpoint.engine.movements.leg import detect_signals
from stillpoint.engine.movements.signals import signals_from_arrays
from stillpoint.engine.sim.infant import make_infant
from stillpoint.engine.sim.sixface import simulate_sixface
from stillpoint.engine.sim.static_errors import StaticErrors

NOISE = [0.002] * 3


def counts(errors, *, seed=31, minutes=12, fs=25, n_postures=None, filt="none", calibrate=True):
    """(error-free count, raw count, calibrated count)."""
    ideal = make_infant(minutes=minutes, fs=fs, seed=seed, n_postures=n_postures,
                        errors=StaticErrors(noise_g=NOISE))
    bad = make_infant(minutes=minutes, fs=fs, seed=seed, n_postures=n_postures, errors=errors)
    t, free, _, gyro = ideal.arrays()
    _, raw, _, _ = bad.arrays()

    def n(acc, correct=None):
        sig = signals_from_arrays(t, acc, gyro, fs, correct)
        return detect_signals(sig, filter=filt)["movements"].shape[0]

    out = [n(free), n(raw)]
    if calibrate:
        session = simulate_sixface(fs=fs, errors=errors, seed=seed + 100)
        cal = static_calibration(session.accel_g, fs, mode="robust")
        out.append(n(raw, cal.apply))
    return out


def test_p1_single_posture_offset_barely_matters():
    e = StaticErrors(offset_g=[0.062, -0.074, 0.030], noise_g=NOISE)
    free, raw, cal = counts(e, n_postures=1)
    assert abs(raw - free) <= 0.03 * free and abs(cal - free) <= 1


def test_p2_several_postures_offset_changes_counts_and_calibration_restores():
    e = StaticErrors(offset_g=[0.062, -0.074, 0.030], gain=[1.002, 0.998, 1.009], noise_g=NOISE)
    free, raw, cal = counts(e, n_postures=6)
    assert abs(raw - free) > 0.05 * free, (free, raw)
    assert abs(cal - free) <= 1, (free, cal)
    zero = StaticErrors(noise_g=NOISE)
    f0, r0 = counts(zero, calibrate=False, n_postures=6)
    assert f0 == r0  # no error, no change


def test_p3_gain_only():
    e = StaticErrors(gain=[0.98, 1 / 0.98, 0.98], noise_g=NOISE)
    free, raw, cal = counts(e, seed=32, n_postures=6)
    assert abs(raw - free) > 0.05 * free and abs(cal - free) <= 1


def test_p4_pure_rotation_leaves_counts_unchanged():
    e = StaticErrors(antisymmetric=[0.01, -0.012, 0.008], noise_g=NOISE)
    free, raw = counts(e, seed=33, calibrate=False)
    assert abs(raw - free) <= 1
    sym = StaticErrors(symmetric=[0.012, 0.012, 0.012], noise_g=NOISE)
    free_s, raw_s = counts(sym, seed=33, calibrate=False)
    assert abs(raw_s - free_s) > abs(raw - free)  # non-orthogonality does change rest norms


def test_p5_two_tap_filter_lowers_counts():
    e = StaticErrors(noise_g=NOISE)
    plain = sum(counts(e, seed=s, fs=20, calibrate=False)[0] for s in (34, 35))
    filtered = sum(counts(e, seed=s, fs=20, calibrate=False, filt="2tap")[0] for s in (34, 35))
    assert filtered <= plain


def test_p7_calibration_reduces_spread_across_sensors():
    rng = np.random.default_rng(36)
    raws, cals = [], []
    for fs in (20, 25, 52):
        e = StaticErrors.draw(rng, offset_max_g=0.12, noise_range_g=(0.001, 0.003))
        _, raw, cal = counts(e, seed=37, fs=fs, minutes=10)
        raws.append(raw)
        cals.append(cal)
    assert np.ptp(cals) < np.ptp(raws), (raws, cals)
