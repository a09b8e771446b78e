"""Realism checks on a CI-sized simulated day (adult wrist, AX3 unpacked, 25 Hz): still windows
at the noise floor plus the worn micro-motion, a plausible share of low-SD windows (mostly at night), ENMO before/after a
true calibration moving as in van Hees 2014 Table 4, the walking step frequency, temperature."""

import numpy as np
import pytest

from stillpoint.engine.sim.realism import night_mask, realism_stats, van_hees_wrist
from stillpoint.engine.sim.sensor import noise_sd_g

HZ = 25.0


@pytest.fixture(scope="module")
def day():
    """One simulated day with offsets/gains of the size van Hees 2014 reports, window stats."""
    st = realism_stats(van_hees_wrist(days=1, hz=HZ, seed=11), HZ)
    return dict(sim=st.sim, sd=st.window_sd, labels=st.labels, enmo_u=st.enmo_uncal,
                enmo_c=st.enmo_cal, walking_peaks=st.walking_peaks, stats=st)


def test_still_windows_sit_at_the_noise_floor(day):
    sim, sd, lab = day["sim"], day["sd"], day["labels"]
    still = lab["still"] == 1
    q = sim.spec.lsb_g  # quantisation adds q^2 / 12 to the variance
    sw = sim.still_windows()  # the closed-form micro-motion RMS of each still window
    assert set(sw["window"]) <= set(np.nonzero(still)[0])
    floor = np.sqrt(noise_sd_g(sim.model, HZ) ** 2 + q ** 2 / 12 + (0.3e-3) ** 2 + sw["micro_sd"] ** 2)
    ratio = np.median(sd[sw["window"]] / floor, axis=0)
    assert np.all(np.abs(ratio - 1) < 0.2), ratio
    # the worn micro-motion leaves most still windows under the 13 mg criterion
    assert np.mean(np.all(sd[still] < 0.013, axis=1)) > 0.75


def test_low_sd_share_is_plausible_and_mostly_at_night(day):
    sd = day["sd"]
    low = (sd < 0.013).all(axis=1)
    share = low.mean()
    assert 1 / 3 <= share <= 1 / 2, share
    night = night_mask(day["stats"])
    assert (low & night).sum() / low.sum() > 0.5
    assert low[night].mean() > 2 * low[~night].mean()


def test_enmo_falls_after_true_calibration_low_percentiles_most(day):
    u, c = day["enmo_u"], day["enmo_c"]
    assert c.mean() < u.mean()
    pu = np.percentile(u, [25, 50, 75, 95])
    pc = np.percentile(c, [25, 50, 75, 95])
    rel = (pu - pc) / np.maximum(pu, 1e-9)
    assert pc[1] < pu[1] and pc[2] < pu[2]
    assert rel[1] > rel[3] and rel[2] > rel[3]  # low percentiles fall most
    assert abs(pc[3] - pu[3]) / pu[3] < 0.1  # high percentiles barely move


def test_walking_step_frequency_is_a_spectral_peak(day):
    pk = day["walking_peaks"]  # per walking bout >= 60 s: peak Hz, true step Hz, seconds
    assert len(pk) >= 1
    peak, step_hz, _ = pk[np.argmax(pk[:, 2])]  # the longest bout
    assert 1.6 <= peak <= 2.2
    assert abs(peak - step_hz) < 0.1


def test_temperature_range_is_plausible_for_the_wrist(day):
    lab = day["labels"]
    worn = lab["activity"] > 1
    lo, hi = np.percentile(lab["temperature_c"][worn], [5, 95])
    assert 25 <= lo < hi <= 36
    assert hi - lo > 1.5  # a daily cycle, not a constant
