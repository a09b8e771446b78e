"""Device resolution, clipping and quantisation; noise level; GENEActiv calibration mapping."""

import numpy as np
import pytest

from stillpoint.engine.sim.model import SensorModel
from stillpoint.engine.sim.sensor import DeviceSpec, measure, noise_sd_g, standard_normals


def test_ax3_packed_resolution_and_clipping():
    spec = DeviceSpec.make("ax3", range_g=8)
    assert spec.step_counts == 4 and spec.lsb_g[0] == pytest.approx(4 / 256)
    a = np.array([[0.0, 1.0, -1.0], [7.99, -8.5, 0.01], [0.0078, 0.0079, -0.0079]])
    c = spec.to_counts(a)
    assert np.all(c % 4 == 0)
    assert c[0].tolist() == [0, 256, -256]
    assert c[1].tolist() == [511 * 4, -512 * 4, 4]  # saturates at the 10-bit range, like the firmware
    assert c[2].tolist() == [0, 4, -4]  # nearest multiple of 1/64 g
    f = spec.to_counts(a, mode="floor")
    assert f[2].tolist() == [0, 0, -4]  # arithmetic shift rounds down
    with pytest.raises(ValueError):
        spec.to_counts(a, clip=False)


@pytest.mark.parametrize("kind, rng, cpg", [("ax3", 2, 256.0), ("ax6", 16, 2048.0), ("ax6", 4, 8192.0)])
def test_unpacked_resolutions(kind, rng, cpg):
    spec = DeviceSpec.make(kind, range_g=rng, packed=False)
    assert spec.counts_per_g[0] == cpg and spec.step_counts == 1
    x = np.array([[0.5, -0.25, 1.0]])
    assert np.allclose(spec.to_g(spec.to_counts(x)), x, atol=0.5 / cpg)


def test_geneactiv_counts_invert_the_header_calibration():
    spec = DeviceSpec.make("geneactiv", gains=(25875, 25734, 25538), offsets=(439, -662, -3056))
    x = np.random.default_rng(0).uniform(-7, 7, (1000, 3))
    c = spec.to_counts(x)
    assert c.min() >= -2048 and c.max() <= 2047
    g = (c * 100.0 - np.array([439, -662, -3056])) / np.array([25875, 25734, 25538])  # the readers' formula
    assert np.all(np.abs(g - x) <= 0.5 * 100 / np.array([25875, 25734, 25538]) + 1e-12)


def test_noise_level_and_normals():
    r = np.random.default_rng(1)
    z = standard_normals(r, (200000, 3))
    assert z.dtype == np.float32
    assert abs(z.mean()) < 0.01 and abs(z.std() - 1) < 0.01
    assert abs(np.mean(z ** 4) - 3) < 0.1  # Gaussian kurtosis
    m = SensorModel({"noise": {"x_ug_per_rthz": 400, "y_ug_per_rthz": 400, "z_ug_per_rthz": 550}})
    sd = noise_sd_g(m, 100.0)
    assert sd[0] == pytest.approx(400e-6 * np.sqrt(50))
    spec = DeviceSpec.make("ax6", range_g=2)
    f = np.tile([0.0, 0.0, 1.0], (100000, 1)).astype(np.float32)
    meas, counts = measure(f, m, spec, temperature_c=None, time_s=None, accel_temperature_c=None,
                           bias_g=None, rng=np.random.default_rng(2), rate_hz=100.0)
    assert np.allclose(spec.to_g(counts).std(axis=0), sd, rtol=0.03)
    assert counts.dtype == np.int32
