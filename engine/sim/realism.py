"""Realism statistics of a simulated recording, in one streaming pass over its chunks.

Used by the realism tests (tests/engine/sim/test_sim_realism.py) and the benchmark's ``--realism`` table
(tools/benchmarks/bench_simulate.py): 10 s window means and SDs of what the device stored, the same windows
after the true GGIR-form correction, 5 s epoch ENMO before and after it, and the spectral peak of
every walking bout of at least 60 s against its true step frequency.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .model import ggir_equivalent
from .record import build_model, make_devices
from .sensor import noise_sd_g

WALKING = 6  # the schedule's activity code for walking (engine/sim/wearer.py)
NOT_IN_TRUE_MODEL = ("bias_instability", "noise", "clipping", "quantisation", "rate_error", "clock")


def van_hees_wrist(days: float, hz: float, seed: int):
    """An adult wrist AX3 (unpacked) with offsets and gains of the size van Hees 2014 reports."""
    model = (build_model("default").with_effect("offset", x_mg=35.0, y_mg=-40.0, z_mg=75.0)
             .with_effect("gain", x_pct=1.2, y_pct=-0.8, z_pct=1.5))
    [sim] = make_devices(sites=["wrist"], devices=["ax3"], days=days, hz=hz, seed=seed,
                         effects=model, packed=False)
    return sim


@dataclass
class RealismStats:
    sim: object
    window_mean: np.ndarray  # (nw, 3) g, as stored
    window_sd: np.ndarray  # (nw, 3) g, sample SD
    window_cal_mean: np.ndarray  # (nw, 3) g, after the true correction
    window_n: np.ndarray  # (nw,)
    labels: dict  # the simulator's per-window truth labels
    enmo_uncal: np.ndarray  # per 5 s epoch (epochs with data), g
    enmo_cal: np.ndarray
    walking_peaks: np.ndarray  # (k, 3): spectral peak Hz, true step Hz, bout seconds used


def realism_stats(sim, hz: float) -> RealismStats:
    """One pass over ``sim``'s chunks (``hz``: its nominal rate)."""
    g = ggir_equivalent(sim.model.without(*NOT_IN_TRUE_MODEL), 25.0)
    off, sc, to = (np.asarray(g[k]) for k in ("offset", "scale", "tempoffset"))
    nw, ne = int(np.ceil(sim.duration_s / 10)), int(np.ceil(sim.duration_s / 5))
    s1, s2, c1, cnt = np.zeros((nw, 3)), np.zeros((nw, 3)), np.zeros((nw, 3)), np.zeros(nw)
    eu, ec, en = np.zeros(ne), np.zeros(ne), np.zeros(ne)
    peaks = []
    sch = sim.schedule
    for c in sim.chunks():
        a = sim.spec.to_g(c.counts)
        cal = (a + off) * sc + (c.temperature_c - 25.0)[:, None] * to
        w = (c.true_s // 10).astype(int)
        cnt += np.bincount(w, minlength=nw)
        for j in range(3):
            s1[:, j] += np.bincount(w, a[:, j], nw)
            s2[:, j] += np.bincount(w, a[:, j] ** 2, nw)
            c1[:, j] += np.bincount(w, cal[:, j], nw)
        e = (c.true_s // 5).astype(int)
        en += np.bincount(e, minlength=ne)
        eu += np.bincount(e, np.maximum(np.linalg.norm(a, axis=1) - 1, 0), ne)
        ec += np.bincount(e, np.maximum(np.linalg.norm(cal, axis=1) - 1, 0), ne)
        seg = sch.segment_at(c.true_s)
        for i in np.unique(seg[sch.activity[seg] == WALKING]):  # walking bouts in this chunk
            m = (seg == i) & (c.true_s > sch.start[i] + 5) & (c.true_s < sch.end[i] - 5)
            if m.sum() >= 60 * hz:
                x = np.linalg.norm(a[m], axis=1)
                x = x - x.mean()
                spec = np.abs(np.fft.rfft(x * np.hanning(x.size))) ** 2
                f = np.fft.rfftfreq(x.size, 1 / hz)
                band = (f > 0.5) & (f < 6)
                peaks.append((float(f[band][np.argmax(spec[band])]), float(sch.step_hz[i]),
                              m.sum() / hz))
    mean = s1 / cnt[:, None]
    sd = np.sqrt(np.maximum(s2 / cnt[:, None] - mean ** 2, 0) * (cnt / (cnt - 1))[:, None])
    ok = en > 0
    return RealismStats(
        sim=sim, window_mean=mean, window_sd=sd, window_cal_mean=c1 / cnt[:, None], window_n=cnt,
        labels=sim.labels(np.zeros((nw, 3)), np.zeros((nw, 3)), cnt.astype(np.int64)),
        enmo_uncal=eu[ok] / en[ok], enmo_cal=ec[ok] / en[ok],
        walking_peaks=np.array(peaks) if peaks else np.zeros((0, 3)))


def night_mask(stats: RealismStats) -> np.ndarray:
    """Windows between 23:00 and 07:00 wearer time."""
    hour = (stats.sim.schedule.start_hour + stats.labels["true_start_s"] / 3600) % 24
    return (hour >= 23) | (hour < 7)


def realism_summary(stats: RealismStats, hz: float) -> dict:
    """The figures docs/simulate.md quotes (tools/benchmarks/bench_simulate.py --realism)."""
    sd, lab, pk = stats.window_sd, stats.labels, stats.walking_peaks
    low = (sd < 0.013).all(axis=1)
    still = lab["still"] == 1
    floor = np.sqrt(noise_sd_g(stats.sim.model, hz) ** 2 + stats.sim.spec.lsb_g ** 2 / 12)
    err_u = np.abs(np.linalg.norm(stats.window_mean[low], axis=1) - 1)  # GGIR's calibration error
    err_c = np.abs(np.linalg.norm(stats.window_cal_mean[low], axis=1) - 1)  # on the low-SD windows
    u, cc = stats.enmo_uncal, stats.enmo_cal
    worn = lab["activity"] > 1
    r = lambda x, k=1: round(float(x), k)  # noqa: E731
    return {
        "low_sd_window_share": r(low.mean(), 3),
        "low_sd_share_at_night_23_07": r((low & night_mask(stats)).sum() / max(low.sum(), 1), 3),
        "still_sd_median_mg": [r(x * 1000, 2) for x in np.median(sd[still], axis=0)],
        "noise_floor_mg": [r(x * 1000, 2) for x in floor],
        "calibration_error_mg_uncal_cal": [r(err_u.mean() * 1000), r(err_c.mean() * 1000, 2)],
        "enmo_mean_mg_uncal_cal": [r(u.mean() * 1000), r(cc.mean() * 1000)],
        "enmo_p25_p50_p75_p95_uncal": [r(x * 1000) for x in np.percentile(u, [25, 50, 75, 95])],
        "enmo_p25_p50_p75_p95_cal": [r(x * 1000) for x in np.percentile(cc, [25, 50, 75, 95])],
        "walking_bouts_ge_60s": int(pk.shape[0]),
        "walking_step_hz_min_max": [r(pk[:, 1].min(), 2), r(pk[:, 1].max(), 2)] if pk.size else None,
        # share of walking bouts whose vector-magnitude spectrum peaks at their step frequency
        # (+-0.1 Hz); the others peak at the stride frequency (half of it)
        "walking_peak_at_step_hz_share": r(np.mean(np.abs(pk[:, 0] - pk[:, 1]) < 0.1), 3) if pk.size else None,
        "walking_peak_in_1p6_2p2_hz_share": r(np.mean((pk[:, 0] >= 1.6) & (pk[:, 0] <= 2.2)), 3) if pk.size else None,
        "worn_temperature_c_p5_p95": [r(x) for x in np.percentile(lab["temperature_c"][worn], [5, 95])],
    }
