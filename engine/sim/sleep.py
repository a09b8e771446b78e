"""Simulated sleep at the 5 s epoch level, with its truth: per night an onset, a wake-up, a number
of awakenings (minutes awake and moving inside the night), optionally a daysleeper (asleep from
the early morning into the afternoon) and nonwear (device off, still, flagged) inside the night.

``sleep_scenario(spec)`` -> ``SleepSeries``: epoch start times (UTC ns), anglez (deg), ENMO (mg),
the nonwear flag and the truth per night. Awake: the arm moves (anglez a bounded random walk
an AR(1) walk with steps of about 15 deg per epoch, ENMO around 40 mg), with quiet evening stretches (sitting:
steps of 2-3 deg). Asleep: a held posture (small breathing noise) changed by a turn every
``posture_min`` minutes on average. Everything is drawn from one ``numpy.random.default_rng(seed)``
so a scenario is the same numbers wherever it is built (the GGIR agreement fixtures in
tests/data/ggir_sleep/ are built from these series). Values are rounded to 0.01 deg so the series
written to CSV for R are the same doubles.

This is the epoch-level companion of the raw wearer model (engine/sim/wearer.py, which also
sleeps): it feeds the sleep operators directly, with a known onset and wake, in milliseconds.
"""

from __future__ import annotations

import datetime as _dt
from dataclasses import dataclass, field

import numpy as np

from ..timezones import Zone, parse_zone

EPOCH_S = 5.0


@dataclass
class SleepSpec:
    start_local: str = "2026-03-25T10:00:00"  # local start of the recording
    timezone: str = "Europe/London"
    days: float = 7.0
    seed: int = 1
    onset_h: float = 23.0  # mean onset (local hours; > 24 means after midnight)
    wake_h: float = 7.0  # mean wake (local hours, next morning)
    sd_h: float = 0.5
    awakenings: float = 2.0  # mean awakenings per night (Poisson)
    awakening_min: tuple = (3.0, 15.0)
    posture_min: float = 40.0
    daysleeper_nights: tuple = ()  # night numbers (0 = the first evening) slept 05:00-14:00
    nonwear_nights: tuple = ()  # night numbers with 2 h of nonwear starting 2 h after onset
    quiet_evening_h: float = 1.5  # low-movement sitting before onset
    # waking activity (off by default; drawn from a second stream seeded from ``seed`` so the
    # rest of a scenario is the same numbers with it on or off): per day, Poisson-many stretches
    # of sitting (ENMO ~ 12 mg), light activity (~ 70 mg), moderate to vigorous activity
    # (~ 180 mg, a fifth of its epochs light: the bout rule's 80 %) and runs (~ 500 mg), 2-40 min
    # each
    active_per_day: float = 0.0
    nonwear_days: tuple = ()  # day numbers (0 = the first) with 3 h of nonwear from 13:00 local


@dataclass
class SleepSeries:
    spec: SleepSpec
    zone: Zone
    t_ns: np.ndarray
    anglez: np.ndarray
    enmo: np.ndarray
    nonwear: np.ndarray
    truth: list = field(default_factory=list)  # dicts: night, onset_ns, wake_ns, awakenings


def _local_to_utc_ns(zone: Zone, local: _dt.datetime) -> int:
    ln = int((local - _dt.datetime(1970, 1, 1)).total_seconds()) * 10**9
    guess = ln - int(zone.offsets_s(np.array([ln]))[0]) * 10**9
    return ln - int(zone.offsets_s(np.array([guess]))[0]) * 10**9


def sleep_scenario(spec: SleepSpec) -> SleepSeries:
    zone = parse_zone(spec.timezone)
    rng = np.random.default_rng(spec.seed)
    start_local = _dt.datetime.fromisoformat(spec.start_local)
    t0 = _local_to_utc_ns(zone, start_local)
    ep = int(EPOCH_S * 1e9)
    n = int(round(spec.days * 86400 / EPOCH_S))
    t = t0 + np.arange(n, dtype=np.int64) * ep
    state = np.zeros(n, np.int8)  # 0 awake, 1 asleep, 2 quiet, 3 nonwear
    truth = []
    day0 = start_local.date()
    for k in range(int(np.ceil(spec.days)) + 1):
        d = day0 + _dt.timedelta(days=k)
        if k in spec.daysleeper_nights:
            on_h, wk_h = 29.0 + rng.normal(0, 0.3), 38.0 + rng.normal(0, 0.3)
        else:
            on_h = spec.onset_h + rng.normal(0, spec.sd_h)
            wk_h = 24 + spec.wake_h + rng.normal(0, spec.sd_h)
        base = _dt.datetime.combine(d, _dt.time())
        on = _local_to_utc_ns(zone, base + _dt.timedelta(hours=float(on_h)))
        wk = _local_to_utc_ns(zone, base + _dt.timedelta(hours=float(wk_h)))
        i0, i1 = (on - t0) // ep, (wk - t0) // ep
        q0 = i0 - int(spec.quiet_evening_h * 720)
        if i1 <= 0 or i0 >= n:
            continue
        state[max(q0, 0):max(i0, 0)] = 2
        state[max(i0, 0):min(i1, n)] = 1
        m = int(rng.poisson(spec.awakenings))
        wakes = []
        for _ in range(m):
            dur = int(rng.uniform(*spec.awakening_min) * 12)
            a = int(rng.integers(i0 + 360, max(i1 - 360 - dur, i0 + 361)))
            wakes.append((a, a + dur))
            state[max(a, 0):min(a + dur, n)] = 0
        if k in spec.nonwear_nights:
            a = i0 + 2 * 720
            state[max(a, 0):min(a + 2 * 720, n)] = 3
        if i0 >= 0 and i1 <= n:
            truth.append({"night": d.isoformat(), "onset_ns": int(t0 + i0 * ep),
                          "wake_ns": int(t0 + i1 * ep), "awakenings": m,
                          "daysleeper": k in spec.daysleeper_nights,
                          "nonwear": k in spec.nonwear_nights})
    # anglez per state, vectorised: steps drawn for every epoch, used per state
    step_awake = rng.normal(0, 15, n)
    step_quiet = rng.normal(0, 2.5, n)
    turn = rng.random(n) < 1.0 / (spec.posture_min * 12)
    turn_to = rng.uniform(-80, 80, n)
    breath = rng.normal(0, 0.03, n)
    a = np.empty(n)
    # piecewise: asleep/nonwear hold a level that changes at turns (nonwear: one level)
    level_id = np.cumsum(turn | (np.diff(np.concatenate([[-1], state])) != 0))
    level = turn_to[np.flatnonzero(np.diff(np.concatenate([[0], level_id])))][level_id - 1]
    from scipy.signal import lfilter
    walk = lfilter([1.0], [1.0, -0.9], np.where(state == 0, step_awake,
                                                np.where(state == 2, step_quiet, 0.0)))
    walk = np.clip(walk, -89.0, 89.0)  # the arm's angle, pulled back towards level
    a[:] = walk
    a[state == 1] = (level + breath)[state == 1]
    a[state == 3] = level[state == 3]
    enmo = np.where(state == 0, np.abs(rng.normal(40, 20, n)), np.where(state == 2, 5.0, 0.5))
    if spec.active_per_day or spec.nonwear_days:
        enmo, worn_off = _waking_activity(spec, zone, t0, n, state, enmo, day0)
        a[worn_off] = 10.0  # on a table: still
        state = np.where(worn_off, 3, state)
    return SleepSeries(spec, zone, t, np.round(a, 2), np.round(enmo, 2), state == 3, truth)


def _waking_activity(spec: SleepSpec, zone: Zone, t0: int, n: int, state, enmo, day0):
    """Activity stretches and daytime nonwear in the awake epochs (``active_per_day``,
    ``nonwear_days``): the new ENMO and the epochs taken off."""
    rng = np.random.default_rng([int(spec.seed), 1])
    ep = int(EPOCH_S * 1e9)
    enmo = enmo.copy()
    off = np.zeros(n, bool)
    for k in range(int(np.ceil(spec.days)) + 1):
        base = _dt.datetime.combine(day0 + _dt.timedelta(days=k), _dt.time())
        for _ in range(int(rng.poisson(spec.active_per_day))):
            kind = int(rng.integers(0, 4))  # light, MVPA, run, sitting
            start = _local_to_utc_ns(zone, base + _dt.timedelta(hours=float(rng.uniform(8, 21))))
            i0 = (start - t0) // ep
            i1 = min(n, i0 + int(rng.uniform(2, 40) * 12))
            if i0 < 0 or i0 >= n:
                continue
            sel = np.arange(i0, i1)
            sel = sel[state[sel] == 0]
            m = sel.shape[0]
            if kind == 0:
                enmo[sel] = np.abs(rng.normal(70, 15, m))
            elif kind == 1:
                enmo[sel] = np.where(rng.random(m) < 0.2, np.abs(rng.normal(60, 15, m)),
                                     np.abs(rng.normal(180, 60, m)))
            elif kind == 2:
                enmo[sel] = np.abs(rng.normal(500, 120, m))
            else:
                enmo[sel] = np.abs(rng.normal(12, 6, m))
        if k in spec.nonwear_days:
            start = _local_to_utc_ns(zone, base + _dt.timedelta(hours=13.0))
            i0 = max(0, (start - t0) // ep)
            i1 = min(n, i0 + 3 * 720)
            sel = np.arange(i0, i1)
            sel = sel[state[sel] == 0]
            off[sel] = True
            enmo[sel] = 0.5
    return enmo, off
