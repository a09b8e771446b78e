"""The numbers of Oh, Loeb & Smith 2024 (Tables 2 and 3) as a read-only fixture: the relations the
paper states between them, and the six-face estimate applied to each simulated Table-2 sensor."""

from __future__ import annotations

import numpy as np
import pytest

from stillpoint.engine.calibration.static import static_calibration
from stillpoint.engine.sim.sixface import simulate_sixface
from stillpoint.engine.sim.static_errors import StaticErrors

# Table 2: per unit (Opal 1-3, Ax6 1-3, Movesense 1-3), rows x, y, z; offset/misalignment/noise in g
OFFSET = np.array([[0.018, 0.013, 0.013, 0.062, 0.030, 0.065, -0.002, -0.017, 0.084],
                   [-0.010, -0.023, 0.013, -0.074, -0.067, -0.084, -0.029, -0.083, -0.185],
                   [-0.012, -0.004, 0.027, 0.030, 0.018, -0.007, 0.114, 0.063, 0.144]])
MISALIGN = np.array([[0.016, 0.008, 0.009, 0.011, 0.009, 0.009, 0.005, 0.008, 0.005],
                     [0.006, 0.006, 0.000, 0.016, 0.005, 0.001, 0.004, 0.021, 0.004],
                     [0.006, 0.023, 0.014, 0.011, 0.012, 0.004, 0.004, 0.001, 0.017]])
GAIN = np.array([[0.999, 0.999, 0.999, 1.002, 0.998, 0.998, 1.009, 0.997, 1.008],
                 [0.999, 0.999, 0.999, 0.998, 0.994, 0.993, 1.001, 1.003, 1.004],
                 [1.000, 1.000, 0.999, 1.009, 1.011, 1.013, 1.002, 1.005, 1.009]])
NOISE = np.array([[0.002, 0.002, 0.002, 0.003, 0.005, 0.009, 0.004, 0.005, 0.004],
                  [0.002, 0.002, 0.003, 0.001, 0.001, 0.002, 0.004, 0.004, 0.008],
                  [0.002, 0.001, 0.002, 0.002, 0.002, 0.002, 0.004, 0.004, 0.004]])
COUNTS = {"opal": (269, 269, 195), "ax6": (185, 196, 175), "movesense": (231, 230, 213)}  # Raw, C, C+F
MODELS = {"opal": slice(0, 3), "ax6": slice(3, 6), "movesense": slice(6, 9)}


def test_relations_stated_in_the_paper():
    for a in (OFFSET, MISALIGN, GAIN, NOISE):
        a.setflags(write=False)
    assert np.round(GAIN[:, MODELS["opal"]].mean(axis=1), 3).tolist() == [0.999, 0.999, 1.000]
    assert NOISE[:, MODELS["opal"]].max() <= 0.003 and NOISE.max() <= 0.009  # "<" is really "<="
    assert np.abs(OFFSET).max() == pytest.approx(0.185) and (np.abs(OFFSET) > 0.1).sum() == 3
    assert all(np.abs(OFFSET[:, MODELS["movesense"]]).max() >= np.abs(OFFSET[:, s]).max()
               for s in MODELS.values())
    assert (MISALIGN >= 0.02).sum() == 2 and np.abs(GAIN - 1).max() == pytest.approx(0.013)
    raw = [c[0] for c in COUNTS.values()]
    assert (min(raw), max(raw)) == (185, 269)
    spread = [max(c[k] for c in COUNTS.values()) - min(c[k] for c in COUNTS.values()) for k in range(3)]
    assert spread == [84, 73, 38]
    # Fig. 2: the Ax6 unit-1 Y offset and misalignment are Table 2's
    assert OFFSET[1, 3] == -0.074 and MISALIGN[1, 3] == 0.016


@pytest.mark.parametrize("unit", range(9))
def test_six_face_estimate_recovers_each_table2_sensor(unit):
    e = StaticErrors(offset_g=OFFSET[:, unit].tolist(), gain=GAIN[:, unit].tolist(),
                     noise_g=(NOISE[:, unit] / 2).tolist())
    s = simulate_sixface(fs=25, errors=e, seed=50 + unit)
    cal = static_calibration(s.accel_g, 25, mode="robust")
    assert np.abs(np.asarray(cal.offset_g) - OFFSET[:, unit]).max() < 0.0005
    assert np.abs(np.asarray(cal.gain) - GAIN[:, unit]).max() < 0.0005
    assert np.abs(np.asarray(cal.noise_g) - NOISE[:, unit]).max() < 0.0015
