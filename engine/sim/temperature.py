"""Device temperature: skin-coupled while worn (with a daily cycle and activity coupling),
exponential cooling towards ambient during nonwear.

Computed once per recording on a coarse grid (``TRACK_STEP_S`` = 10 s, one value per label
window; a week is 60k values) and interpolated to sample times. The model is a first-order
approach to a target temperature:

    worn:    target = skin(site, time of day, sleep) + activity offset
                      - coupling(site) * (skin - ambient);   tau = tau_worn_s
    nonwear: target = ambient (drawer: ambient - 0.5 degC); tau = tau_nonwear_s

plus a slow random fluctuation (Gauss-Markov, SD ``fluct_sd_c``). Distal (wrist, ankle) skin
warms during sleep (vasodilation); proximal sites (hip, thigh) under clothing are warmer and
steadier. Defaults give a wrist device at ~29-34 degC by day and night and ~21-23 degC off-body.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from .model import _linear_recursion
from .wearer import SITES, A, Schedule

TRACK_STEP_S = 10.0


@dataclass
class TemperatureParams:
    """Device temperature model parameters (degC, seconds)."""

    ambient_c: float = 22.0  # indoor air, mean
    ambient_daily_amp_c: float = 1.0  # +- daily swing, peak at 16:00
    skin_day_c: dict = field(default_factory=lambda: {"wrist": 32.0, "hip": 33.8, "thigh": 32.8,
                                                      "ankle": 30.5})
    skin_sleep_c: dict = field(default_factory=lambda: {"wrist": 34.8, "hip": 34.8, "thigh": 34.0,
                                                        "ankle": 33.5})
    coupling: dict = field(default_factory=lambda: {"wrist": 0.18, "hip": 0.06, "thigh": 0.08,
                                                    "ankle": 0.15})  # device -> ambient share
    walking_c: float = 0.3  # activity coupling (muscle heat; wrist: offset by airflow)
    running_c: float = 1.2
    running_wrist_c: float = -0.8  # arm swing airflow cools a wrist device
    tau_worn_s: float = 480.0
    tau_nonwear_s: float = 1200.0
    fluct_sd_c: float = 0.3
    fluct_tau_s: float = 1800.0
    initial_c: float = 24.0  # device temperature at the start (out of the box)

    def to_dict(self) -> dict:
        return asdict(self)


def temperature_track(schedule: Schedule, site: str, params: TemperatureParams, seed: int,
                      duration_s: float):
    """(t_grid, T_grid): device temperature (degC) every TRACK_STEP_S from 0 to past duration."""
    p = params
    n = int(np.ceil(duration_s / TRACK_STEP_S)) + 2
    t = np.arange(n) * TRACK_STEP_S
    seg = schedule.segment_at(t + 0.5 * TRACK_STEP_S)
    act = schedule.activity[seg]
    hour = (schedule.start_hour + t / 3600.0) % 24.0
    ambient = p.ambient_c + p.ambient_daily_amp_c * np.cos(2 * np.pi * (hour - 16.0) / 24.0)
    asleep = (act == A["sleep"]) | (act == A["lying"])
    skin = np.where(asleep, p.skin_sleep_c[site], p.skin_day_c[site])
    target = skin - p.coupling[site] * (skin - ambient)
    target = target + np.where(act == A["walking"], p.walking_c, 0.0)
    run = p.running_wrist_c if site == "wrist" else p.running_c
    target = target + np.where(act == A["running"], run, 0.0)
    off = (act == A["nonwear_table"]) | (act == A["nonwear_drawer"])
    target = np.where(off, ambient - 0.5 * (act == A["nonwear_drawer"]), target)
    tau = np.where(off, p.tau_nonwear_s, p.tau_worn_s)
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 20, SITES.index(site)]))
    # slow fluctuation (OU), worn only
    a_f = np.exp(-TRACK_STEP_S / p.fluct_tau_s)
    e = rng.normal(0.0, p.fluct_sd_c * np.sqrt(1 - a_f * a_f), n)
    fl = np.empty(n)
    fl[0] = 0.0
    _linear_recursion(np.full(n - 1, a_f), e[1:], 0.0, fl[1:])
    target = target + np.where(off, 0.0, fl)
    # first-order approach: T[i+1] = a T[i] + (1 - a) target[i]
    a = np.exp(-TRACK_STEP_S / tau[:-1])
    T = np.empty(n)
    T[0] = p.initial_c
    _linear_recursion(a, (1.0 - a) * target[:-1], p.initial_c, T[1:])
    return t, T
