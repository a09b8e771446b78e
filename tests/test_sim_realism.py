"""Realism checks on a CI-sized simulated day (adult wrist, AX3 unpacked, 25 Hz): still windows
at the noise floor, a plausible share of low-SD windows (mostly at night), ENMO before/after a
true calibration moving as in van Hees 2014 Table 4, the walking step frequency, temperature."""

import numpy as np
import pytest

from stillpoint.engine.sim.model import ggir_equivalent
from stillpoint.engine.sim.record import build_model, make_devices
from stillpoint.engine.sim.sensor import noise_sd_g

HZ = 25.0


@pytest.fixture(scope="module")
def day():
    """One simulated day with offsets/gains of the size van Hees 2014 reports, window stats."""
    model = (build_model("default")
             .with_effect("offset", x_mg=35.0, y_mg=-40.0, z_mg=75.0)
             .with_effect("gain", x_pct=1.2, y_pct=-0.8, z_pct=1.5))
    [sim] = make_devices(sites=["wrist"], devices=["ax3"], days=1, hz=HZ, seed=11, effects=model,
                         packed=False)
    true_model = sim.model.without("bias_instability", "noise", "clipping", "quantisation",
                                   "rate_error", "clock")
    g = ggir_equivalent(true_model, 25.0)
    nw = int(np.ceil(sim.duration_s / 10))
    s1, s2, cnt = np.zeros((nw, 3)), np.zeros((nw, 3)), np.zeros(nw)
    ne = int(np.ceil(sim.duration_s / 5))
    enmo_u, enmo_c, ecnt = np.zeros(ne), np.zeros(ne), np.zeros(ne)
    walk_signal = []
    for c in sim.chunks():
        a = sim.spec.to_g(c.counts)
        w = (c.true_s // 10).astype(int)
        cnt += np.bincount(w, minlength=nw)
        for j in range(3):
            s1[:, j] += np.bincount(w, a[:, j], nw)
            s2[:, j] += np.bincount(w, a[:, j] ** 2, nw)
        cal = (a + g["offset"]) * g["scale"] + (c.temperature_c - 25.0)[:, None] * np.array(g["tempoffset"])
        e = (c.true_s // 5).astype(int)
        ecnt += np.bincount(e, minlength=ne)
        enmo_u += np.bincount(e, np.maximum(np.linalg.norm(a, axis=1) - 1, 0), ne)
        enmo_c += np.bincount(e, np.maximum(np.linalg.norm(cal, axis=1) - 1, 0), ne)
        walk_signal.append((c.true_s, np.linalg.norm(a, axis=1)))
    mean = s1 / cnt[:, None]
    sd = np.sqrt(np.maximum(s2 / cnt[:, None] - mean ** 2, 0) * (cnt / (cnt - 1))[:, None])
    labels = sim.labels(np.zeros((nw, 3)), np.zeros((nw, 3)), cnt.astype(np.int64))
    ok = ecnt > 0
    return dict(sim=sim, sd=sd, labels=labels, enmo_u=enmo_u[ok] / ecnt[ok],
                enmo_c=enmo_c[ok] / ecnt[ok], walk=walk_signal)


def test_still_windows_sit_at_the_noise_floor(day):
    sim, sd, lab = day["sim"], day["sd"], day["labels"]
    still = lab["still"] == 1
    q = sim.spec.lsb_g  # quantisation adds q^2 / 12 to the variance
    floor = np.sqrt(noise_sd_g(sim.model, HZ) ** 2 + q ** 2 / 12 + (0.3e-3) ** 2)
    med = np.median(sd[still], axis=0)
    assert np.all(np.abs(med / floor - 1) < 0.2), (med, floor)
    assert np.all(np.percentile(sd[still], 99, axis=0) < 0.013)  # every still window passes 13 mg


def test_low_sd_share_is_plausible_and_mostly_at_night(day):
    sd, lab, sim = day["sd"], day["labels"], day["sim"]
    low = (sd < 0.013).all(axis=1)
    share = low.mean()
    assert 1 / 3 <= share <= 1 / 2, share
    hour = (sim.schedule.start_hour + lab["true_start_s"] / 3600) % 24
    night = (hour >= 23) | (hour < 7)
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
    lab, sim = day["labels"], day["sim"]
    t = np.concatenate([w[0] for w in day["walk"]])
    n = np.concatenate([w[1] for w in day["walk"]])
    walking = lab["activity"] == 6
    # the longest run of walking windows
    idx = np.nonzero(walking)[0]
    runs = np.split(idx, np.nonzero(np.diff(idx) > 1)[0] + 1)
    run = max(runs, key=len)
    assert len(run) >= 6
    sel = (t >= (run[0] + 1) * 10) & (t < run[-1] * 10)
    x = n[sel] - n[sel].mean()
    spec = np.abs(np.fft.rfft(x * np.hanning(x.size))) ** 2
    f = np.fft.rfftfreq(x.size, 1 / HZ)
    band = (f > 0.5) & (f < 6)
    peak = f[band][np.argmax(spec[band])]
    seg = sim.schedule.segment_at(np.array([(run[0] + 1) * 10.0]))[0]
    assert 1.6 <= peak <= 2.2
    assert abs(peak - sim.schedule.step_hz[seg]) < 0.1


def test_temperature_range_is_plausible_for_the_wrist(day):
    lab = day["labels"]
    worn = lab["activity"] > 1
    lo, hi = np.percentile(lab["temperature_c"][worn], [5, 95])
    assert 25 <= lo < hi <= 36
    assert hi - lo > 1.5  # a daily cycle, not a constant
