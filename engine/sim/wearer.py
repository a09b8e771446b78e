"""The wearer: a multi-day free-living schedule (sleep with posture changes, lying, sitting,
standing, walking, running, nonwear on a table or in a drawer) and the true specific force (and
angular rate) it produces at a body site (wrist, hip, thigh, ankle), in the device frame.

Two layers:

* ``make_schedule(params, duration_s, seed)`` -> ``Schedule``: the body-level plan, shared by
  every device on the body: segments (start, end, activity, posture, motion kind, transition
  length) and, for walking/running, the step (heel-strike) times. Small (a few thousand segments
  and ~10^5 step times a week); built once.
* ``SiteModel(schedule, site, seed)``: per-site rendering. ``render(t)`` evaluates, for true
  times t (s since the start, increasing), the specific force in the device frame (g) and the
  angular rate (deg/s). Orientations are drawn per segment from the site's own random stream;
  motion is a deterministic function of time, so two devices sampled at different instants see
  the same movement (same heel strikes), and the result does not depend on how t is chunked.

Frames: world X forward, Y left, Z up; the accelerometer reads the specific force
f = a - g_vec = a + (0, 0, 1) g, rotated into the device frame: f_dev = R^T f_world where the
columns of R are the device axes in world coordinates. Each segment's orientation is
R(t) = Rot(axis, angle(t)) @ R_ref: during the segment's opening transition R_ref is the previous
segment's final orientation and the rotation carries it to the segment's base orientation;
afterwards R_ref is the base orientation and angle(t) is the segment's oscillation (fidgeting,
arm swing, leg swing, pelvic rotation). A worn device at rest is never perfectly still: its
"still" segments carry a micro-motion (``micromotion``: breathing, pulse and tremor sinusoids of
linear acceleration along random directions, zero mean), which also dithers the stored counts'
quantisation as on a real wrist; nonwear segments are still.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Optional

import numpy as np

G = 9.80665  # m/s^2 per g

ACTIVITIES = ("nonwear_table", "nonwear_drawer", "sleep", "lying", "sitting", "standing",
              "walking", "running")
POSTURES = ("none", "supine", "prone", "left_side", "right_side", "sitting", "upright")
MOTIONS = ("still", "fidget", "gait")
SITES = ("wrist", "hip", "thigh", "ankle")
A = {n: i for i, n in enumerate(ACTIVITIES)}
P = {n: i for i, n in enumerate(POSTURES)}
M = {n: i for i, n in enumerate(MOTIONS)}


# Where the default wearer's intensity and wear figures come from (one place):
# * Doherty A et al. 2017, "Large scale population assessment of physical activity using wrist
#   worn accelerometers: the UK Biobank study", PLoS ONE 12(2):e0169649, Table 1: mean
#   acceleration vector magnitude (ENMO, mg) 31.2/31.1 (women/men, 45-54 y), 29.1/28.8
#   (55-64 y), 26.6/25.6 (65-74 y); wear time per 7-day wear median 164.9-166.8 h (IQR from
#   149.5-160.8 h to 167.0-168.0 h), i.e. a median of ~1-3 h of nonwear per week, 7-18 h
#   at the lower quartile. The default wearer (a week, seeds 1-4): mean ENMO 28-46 mg (the
#   upper seeds run twice a week), nonwear (showers, a drawer, off-wrist on a table) 6-11 h.
# * Hildebrand M et al. 2014, "Age group comparability of raw accelerometer output from wrist-
#   and hip-worn monitors", Med Sci Sports Exerc 46(9):1816-24, Table 3 (non-dominant wrist,
#   adults): MVPA from 100.6 mg (ActiGraph) / 93.2 mg (GENEActiv), vigorous from 428.8 mg;
#   Hildebrand M et al. 2017, Scand J Med Sci Sports 27(12):1814-23: sedentary below 44.8 mg.
#   Free-living wrist data spend time at every intensity between these: light activity
#   (40-100 mg: chores, cooking, slow walking) is as common as MVPA (a week of the default
#   wearer, 5 s epochs: 100-150 min/day at 40-100 mg, 80-100 min/day at 100-400 mg), not ~1 min/day.
REALISM_SOURCES = ("Doherty et al. 2017 PLoS ONE 12(2):e0169649 Table 1",
                   "Hildebrand et al. 2014 Med Sci Sports Exerc 46(9):1816-24 Table 3",
                   "Hildebrand et al. 2017 Scand J Med Sci Sports 27(12):1814-23")


@dataclass
class WearerParams:
    """Behaviour of the simulated adult (defaults: a typical adult wearing the device on the
    wrist; times of day in hours, local time = UTC of the recording's start)."""

    wake_h: float = 7.0  # mean wake-up time
    wake_sd_h: float = 0.6
    sleep_h: float = 23.0  # mean sleep onset
    sleep_sd_h: float = 0.6
    sleep_posture_min: float = 35.0  # mean time between posture changes in bed (min)
    sleep_twitch_per_h: float = 4.0  # brief movements in bed (5-20 s) per hour
    sit_share: float = 0.52  # shares of the awake bouts (by count): sitting, standing, lying
    stand_share: float = 0.18  # awake; the remainder (0.28 by default) are short walks
    lying_share: float = 0.02
    sit_bout_min: float = 20.0  # median bout durations (min), lognormal
    stand_bout_min: float = 4.0
    walk_bout_min: float = 3.0
    lying_bout_min: float = 15.0
    long_walk_per_day: float = 1.5  # 15-45 min walks per day (on average)
    still_share_sitting: float = 0.15  # share of sitting time with the wrist truly still
    still_share_standing: float = 0.1
    still_bout_s: float = 90.0  # median still piece while sitting or standing (s), lognormal
    walk_step_hz: float = 1.85  # walking step (heel-strike) frequency, mean; range 1.6-2.2 Hz
    walk_step_hz_sd: float = 0.12
    run_step_hz: float = 2.75  # running 2.5-3.0 Hz
    run_step_hz_sd: float = 0.12
    step_cv: float = 0.025  # step-to-step variability of the interval
    runs_per_week: float = 2.0  # 20-45 min runs
    shower_per_day: float = 1.0  # device off on a table, 15-30 min (morning)
    drawer_per_day: float = 0.15  # device off in a drawer, 1-4 h
    first_hour_nonwear: bool = False  # start with the device on a table for 1 h (set-up)
    # RMS (mg) of the micro-motion of a worn device at rest (breathing, pulse, physiological
    # tremor), drawn per still segment (lognormal around it); 0 = a perfectly still body. 6 mg
    # gives worn still-window SDs (median 6-8 mg on packed +-8 g AX3 at 100 Hz) like those of
    # the real wrist recordings in shared/data/real (tools/crosschecks/still_window_sd.py).
    still_micromotion_mg: float = 6.0
    # Free-living intensity and wear (figures and sources: ``REALISM_SOURCES`` below).
    light_share_standing: float = 0.6  # share of standing fidget segments that are light
    light_share_sitting: float = 0.2  # activity (chores, cooking, tidying: 40-100 mg at the wrist)
    light_vigour: float = 9.0  # median motion multiplier of a light-activity segment (lognormal)
    stroll_share: float = 0.45  # share of walking bouts at a slow stroll (arm swing and trunk
    stroll_vigour: float = 0.5  # acceleration times this: 50-100 mg at the wrist)
    offwrist_per_week: float = 1.5  # episodes with the device off the wrist, flat on a table,
    offwrist_min_h: float = 1.0  # 1-3 h, in the day (detectable nonwear: >= 60 min still)
    offwrist_max_h: float = 3.0

    def to_dict(self) -> dict:
        return asdict(self)


# The simulator's named wearers (``stillpoint simulate --wearer NAME``): the parameters each
# changes from ``WearerParams``'s defaults.
# * "default": the typical adult above.
# * "still": a sedentary older participant with long still periods, the hard case for a
#   calibration that refits as data arrive (many still windows a day, in few orientations): long
#   nights (21:30-07:30) with rare posture changes and twitches, most of the day sitting in long
#   bouts with the wrist resting for minutes at a time, short slow walks and no runs, and the
#   device off the wrist often and for long (on a table for 2-6 h about five times a week, in a
#   drawer a few hours about twice a week). Older adults are the most sedentary group of
#   accelerometer surveys (Matthews CE et al. 2008, "Amount of time spent in sedentary behaviors
#   in the United States, 2003-2004", Am J Epidemiol 167(7):875-81, Table 2: ~9 h/day at ages
#   60-85) and have the lowest mean ENMO (Doherty 2017, Table 1, ages 65-74: 25.6-26.6 mg); this
#   wearer goes further on purpose, as a stress case rather than a population's average (a week,
#   seeds 1-4: 20.5-21.1 h/day in still segments, worn or not, against 11.0-12.4 h for the
#   default wearer; 9.6-10.1 h/day asleep; 12-22 h/week off the wrist; worn wrist ENMO ~6 mg
#   over two days at seed 3, against ~40 mg).
# * "shift": a night-shift worker who sleeps by day, from about 05:00 to 14:00 local time, and is
#   awake (and otherwise the default wearer) from the afternoon through the night: the case for
#   sleep detection and day segmentation that must not assume night-time sleep (GGIR's
#   "daysleeper" nights, part 5's wake-to-wake windows starting in the afternoon).
WEARERS = {
    "default": {},
    "still": dict(wake_h=7.5, sleep_h=21.5, sleep_posture_min=75.0, sleep_twitch_per_h=1.0,
                  sit_share=0.6, stand_share=0.15, lying_share=0.07, sit_bout_min=45.0,
                  stand_bout_min=3.0, walk_bout_min=2.0, lying_bout_min=45.0,
                  long_walk_per_day=0.6, runs_per_week=0.0, still_share_sitting=0.4,
                  still_share_standing=0.15, still_bout_s=300.0, drawer_per_day=0.3,
                  stroll_share=0.8, offwrist_per_week=5.0, offwrist_min_h=2.0,
                  offwrist_max_h=6.0),
    "shift": dict(wake_h=14.0, sleep_h=29.0),
}


def wearer_params(name: str = "default") -> WearerParams:
    """The named wearer's parameters (``WEARERS``); ValueError naming the choices otherwise."""
    if name not in WEARERS:
        raise ValueError(f"unknown wearer {name!r}: one of {', '.join(WEARERS)}")
    return WearerParams(**WEARERS[name])


@dataclass
class Schedule:
    """Body-level segments (arrays of equal length) and step times."""

    start: np.ndarray  # (k,) s since the start of the recording
    end: np.ndarray
    activity: np.ndarray  # (k,) int8 index into ACTIVITIES
    posture: np.ndarray  # (k,) int8 index into POSTURES
    motion: np.ndarray  # (k,) int8 index into MOTIONS
    trans_s: np.ndarray  # (k,) opening transition length (s), 0 = no transition
    step_hz: np.ndarray  # (k,) step frequency of gait segments (0 otherwise)
    group: np.ndarray  # (k,) orientation group: segments of one group share a base orientation
    steps: np.ndarray  # (m,) sorted heel-strike times (s), all gait segments
    start_hour: float  # time of day (h) at t = 0
    duration_s: float
    params: WearerParams = field(default_factory=WearerParams)
    # (k,) multiplier of each segment's motion amplitudes (fidget and gait); None = all ones
    vigour: Optional[np.ndarray] = None

    def __len__(self) -> int:
        return int(self.start.shape[0])

    def segment_at(self, t) -> np.ndarray:
        return np.clip(np.searchsorted(self.start, t, side="right") - 1, 0, len(self) - 1)


# ----------------------------------------------------------------------------- the schedule
def make_schedule(params: WearerParams, duration_s: float, seed: int,
                  start_hour: float = 10.0) -> Schedule:
    """The body-level plan for ``duration_s`` seconds starting at ``start_hour`` (local)."""
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0]))
    p = params
    bouts: list[tuple[float, float, str]] = []  # (start, end, activity), contiguous
    t = 0.0
    end_all = duration_s + 60.0
    if p.first_hour_nonwear:
        bouts.append((0.0, 3600.0, "nonwear_table"))
        t = 3600.0
    day0 = -start_hour * 3600.0  # midnight before the start
    d = 0
    while t < end_all:
        midnight = day0 + d * 86400.0
        wake = midnight + 3600.0 * (p.wake_h + rng.normal(0, p.wake_sd_h))
        sleep = midnight + 3600.0 * (p.sleep_h + rng.normal(0, p.sleep_sd_h))
        if t < wake:  # asleep until wake (the first night is cut at t = 0)
            bouts.append((t, wake, "sleep"))
            t = wake
        if t < sleep:
            t = _awake_day(bouts, rng, p, t, sleep, wake)
        d += 1
        # the night continues into the next day's wake; handled by the loop above
        if t >= end_all:
            break
    bouts = [(s, min(e, end_all), a) for s, e, a in bouts if s < end_all and e > s]

    # ---- split bouts into segments with motion kinds and postures
    seg = {k: [] for k in ("start", "end", "activity", "posture", "motion", "trans", "hz", "group")}
    steps: list[np.ndarray] = []
    group = [0]

    def add(s, e, act, post, mot, trans, hz=0.0, new_group=True):
        if e - s <= 0.05:
            return
        if new_group:
            group[0] += 1
        seg["group"].append(group[0])
        seg["start"].append(s)
        seg["end"].append(e)
        seg["activity"].append(A[act])
        seg["posture"].append(P[post])
        seg["motion"].append(M[mot])
        seg["trans"].append(min(trans, 0.4 * (e - s)))
        seg["hz"].append(hz)

    prev_act = None
    for s, e, act in bouts:
        big = act != prev_act  # posture change between bouts: longer transition
        prev_act = act
        if act in ("nonwear_table", "nonwear_drawer"):
            add(s, e, act, "none", "still", 3.0)
        elif act in ("sleep", "lying"):
            t = s
            while t < e:
                dur = rng.exponential(p.sleep_posture_min * 60.0) + 120.0
                u = min(e, t + dur)
                post = ("supine", "prone", "left_side", "right_side")[
                    rng.choice(4, p=(0.4, 0.1, 0.25, 0.25))]
                tw = min(u - t, rng.uniform(8.0, 25.0))  # turning over into the new posture
                add(t, t + tw, act, post, "fidget", 4.0 if big else 2.0)
                big = False
                # brief twitches within the posture: still pieces separated by short fidgets,
                # all sharing the posture's orientation (same group)
                v = t + tw
                while v < u:
                    gap = rng.exponential(3600.0 / max(p.sleep_twitch_per_h, 1e-6))
                    w = min(u, v + gap)
                    add(v, w, act, post, "still", 0.5, new_group=False)
                    if w < u:
                        tl = min(u, w + rng.uniform(3.0, 15.0))
                        add(w, tl, act, post, "fidget", 0.5, new_group=False)
                        w = tl
                    v = w
                t = u
        elif act in ("sitting", "standing"):
            post = "sitting" if act == "sitting" else "upright"
            still_share = p.still_share_sitting if act == "sitting" else p.still_share_standing
            t = s
            first = True
            while t < e:
                if rng.random() < still_share:
                    dur = rng.lognormal(np.log(p.still_bout_s), 0.9)
                    mot = "still"
                else:
                    dur = rng.lognormal(np.log(60.0), 0.9)
                    mot = "fidget"
                u = min(e, t + dur)
                add(t, u, act, post, mot, (3.0 if big else 1.5) if first else rng.uniform(0.8, 2.0))
                t = u
                first = False
        else:  # walking / running
            if act == "walking":
                hz = float(np.clip(rng.normal(p.walk_step_hz, p.walk_step_hz_sd), 1.6, 2.2))
            else:
                hz = float(np.clip(rng.normal(p.run_step_hz, p.run_step_hz_sd), 2.5, 3.0))
            add(s, e, act, "upright", "gait", 1.5, hz)
            n = int((e - s) * hz) + 3
            iv = rng.normal(1.0 / hz, p.step_cv / hz, n).clip(0.5 / hz, 2.0 / hz)
            st = s - rng.uniform(0.0, 1.0 / hz) + np.cumsum(iv) - iv[0]
            steps.append(st[st < e + 2.0 / hz])
    steps_arr = np.sort(np.concatenate(steps)) if steps else np.zeros(0)
    sch = Schedule(start=np.asarray(seg["start"]), end=np.asarray(seg["end"]),
                   activity=np.asarray(seg["activity"], np.int8),
                   posture=np.asarray(seg["posture"], np.int8),
                   motion=np.asarray(seg["motion"], np.int8),
                   trans_s=np.asarray(seg["trans"]), step_hz=np.asarray(seg["hz"]),
                   group=np.asarray(seg["group"], np.int64),
                   steps=steps_arr, start_hour=float(start_hour), duration_s=float(duration_s),
                   params=params)
    # intensity and off-wrist episodes from streams of their own: the behaviour above is drawn
    # exactly as without them
    sch = _with_offwrist(sch, np.random.default_rng(np.random.SeedSequence([int(seed), 2])))
    sch.vigour = _vigour(sch, np.random.default_rng(np.random.SeedSequence([int(seed), 1])))
    return sch


def nonwear_summary(sch: Schedule) -> dict:
    """How much nonwear the schedule holds (for the truth JSON): total hours, the episodes
    (contiguous nonwear segments: start/end s since the start, kind) and the hours in episodes
    of at least 60 min (what a 60-min nonwear rule such as GGIR's can find)."""
    off = np.isin(sch.activity, [A["nonwear_table"], A["nonwear_drawer"]])
    s = np.clip(sch.start, 0.0, sch.duration_s)
    e = np.clip(sch.end, 0.0, sch.duration_s)
    eps = []
    for i in np.flatnonzero(off):
        kind = ACTIVITIES[sch.activity[i]]
        if eps and abs(eps[-1][1] - s[i]) < 1e-6 and eps[-1][2] == kind:
            eps[-1][1] = float(e[i])
        elif e[i] > s[i]:
            eps.append([float(s[i]), float(e[i]), kind])
    hours = sum(b - a for a, b, _ in eps) / 3600.0
    long_h = sum(b - a for a, b, _ in eps if b - a >= 3600.0) / 3600.0
    return {"hours": round(hours, 4), "hours_in_episodes_ge_60_min": round(long_h, 4),
            "episodes": [{"start_s": round(a, 3), "end_s": round(b, 3), "kind": k} for a, b, k in eps]}


def _vigour(sch: Schedule, rng: np.random.Generator) -> np.ndarray:
    """Per-segment motion multipliers: light activity among standing and sitting fidgets,
    slow strolls among walks (one draw per segment, so the stream does not depend on which
    segments qualify)."""
    p = sch.params
    k = len(sch)
    u = rng.random(k)
    mult = rng.lognormal(0.0, 0.25, k)
    v = np.ones(k)
    fid = sch.motion == M["fidget"]
    light = fid & (((sch.activity == A["standing"]) & (u < p.light_share_standing))
                   | ((sch.activity == A["sitting"]) & (u < p.light_share_sitting)))
    v[light] = p.light_vigour * mult[light]
    stroll = (sch.activity == A["walking"]) & (u < p.stroll_share)
    v[stroll] = p.stroll_vigour * mult[stroll]
    return v


def _with_offwrist(sch: Schedule, rng: np.random.Generator) -> Schedule:
    """``sch`` with off-wrist episodes (device flat on a table, ``nonwear_table``) laid over the
    waking day: Poisson(``offwrist_per_week`` per 7 days) episodes of ``offwrist_min_h`` to
    ``offwrist_max_h`` hours starting 08:00-20:00, never over sleep or another nonwear."""
    p = sch.params
    days = sch.duration_s / 86400.0
    n = int(rng.poisson(max(p.offwrist_per_week, 0.0) * days / 7.0))
    nd = max(int(np.ceil(days + sch.start_hour / 24.0)), 1)
    cand = []
    for _ in range(n):  # fixed number of draws per episode
        day = int(rng.integers(0, nd))
        a = (day * 24.0 + rng.uniform(8.0, 20.0) - sch.start_hour) * 3600.0
        b = a + rng.uniform(p.offwrist_min_h, max(p.offwrist_max_h, p.offwrist_min_h)) * 3600.0
        cand.append((a, b))
    keep: list[tuple[float, float]] = []
    sleepish = np.isin(sch.activity, [A["sleep"], A["nonwear_table"], A["nonwear_drawer"]])
    for a, b in sorted(cand):
        a, b = max(a, 0.0), min(b, sch.duration_s)
        if b - a < 600.0 or (keep and a < keep[-1][1] + 1800.0):
            continue
        over = (sch.start < b) & (sch.end > a)
        if (over & sleepish).any():
            continue
        keep.append((a, b))
    if not keep:
        return sch
    cols = ("start", "end", "activity", "posture", "motion", "trans_s", "step_hz", "group")
    parts = {c: [] for c in cols}
    next_group = int(sch.group.max()) + 1
    edges = [0.0] + [x for ab in keep for x in ab] + [np.inf]
    for j in range(len(keep) + 1):
        lo, hi = edges[2 * j], edges[2 * j + 1]
        m = (sch.end > lo) & (sch.start < hi)  # the worn segments between episodes, clipped
        idx = np.flatnonzero(m)
        for c in cols:
            parts[c].append(getattr(sch, c)[idx].copy())
        parts["start"][-1] = np.maximum(parts["start"][-1], lo)
        parts["end"][-1] = np.minimum(parts["end"][-1], hi)
        if j < len(keep):
            a, b = keep[j]
            for c, val in zip(cols, (a, b, A["nonwear_table"], P["none"], M["still"], 3.0, 0.0,
                                     next_group)):
                parts[c].append(np.array([val], dtype=getattr(sch, c).dtype))
            next_group += 1
    new = {c: np.concatenate(parts[c]) for c in cols}
    ok = new["end"] - new["start"] > 0.05
    new = {c: v[ok] for c, v in new.items()}
    new["trans_s"] = np.minimum(new["trans_s"], 0.4 * (new["end"] - new["start"]))
    steps = sch.steps
    for a, b in keep:
        steps = steps[(steps < a) | (steps >= b)]
    return Schedule(**new, steps=steps, start_hour=sch.start_hour, duration_s=sch.duration_s,
                    params=p)


def _awake_day(bouts, rng, p: WearerParams, t: float, sleep: float, wake: float) -> float:
    """Fill [t, sleep) with awake bouts; returns sleep."""
    # fixed events of the day: shower (table), drawer nonwear, a run
    events = []
    if rng.random() < p.shower_per_day:
        s = wake + rng.uniform(0.2, 1.5) * 3600.0
        events.append((s, s + rng.uniform(15, 30) * 60.0, "nonwear_table"))
    if rng.random() < p.drawer_per_day:
        s = wake + rng.uniform(3, 12) * 3600.0
        events.append((s, s + rng.uniform(1, 4) * 3600.0, "nonwear_drawer"))
    if rng.random() < p.runs_per_week / 7.0:
        s = wake + rng.uniform(1, 12) * 3600.0
        events.append((s, s + rng.uniform(20, 45) * 60.0, "running"))
    for _ in range(rng.poisson(p.long_walk_per_day)):
        s = wake + rng.uniform(0.5, 14) * 3600.0
        events.append((s, s + rng.uniform(15, 45) * 60.0, "walking"))
    events = sorted(e for e in events if e[0] >= t and e[1] <= sleep)
    kept = []
    for e in events:  # drop overlaps
        if not kept or e[0] >= kept[-1][1] + 60.0:
            kept.append(e)
    shares = np.array([p.sit_share, p.stand_share, p.lying_share])
    shares = np.append(shares, max(0.0, 1.0 - shares.sum()))
    shares /= shares.sum()
    prev = None
    for ev in kept + [(sleep, sleep, None)]:
        while t < ev[0] - 1.0:
            while True:
                k = rng.choice(4, p=shares)
                if k != prev:
                    break
            prev = k
            act, med = (("sitting", p.sit_bout_min), ("standing", p.stand_bout_min),
                        ("lying", p.lying_bout_min), ("walking", p.walk_bout_min))[k]
            dur = max(20.0, rng.lognormal(np.log(med * 60.0), 0.8))
            u = min(ev[0], t + dur)
            bouts.append((t, u, act))
            t = u
        if ev[2] is not None:
            t = max(t, ev[0])
            bouts.append((t, ev[1], ev[2]))
            t = ev[1]
            prev = None
    return max(t, sleep)


def _generator(entropy: list) -> np.random.Generator:
    """``np.random.default_rng(np.random.SeedSequence(entropy))`` (the same stream: default_rng
    wraps PCG64), built directly: half the cost, which counts at two generators per segment."""
    return np.random.Generator(np.random.PCG64(np.random.SeedSequence(entropy)))


# ----------------------------------------------------------------------------- fast trig
_TWO_PI = 2.0 * np.pi


def _sin(x: np.ndarray) -> np.ndarray:
    """sin in float32 after an exact float64 range reduction (numpy's float64 sin is not
    vectorised on every CPU: ~30x slower; float32 keeps 1e-7 relative precision here)."""
    x = np.asarray(x, np.float64)
    r = x - np.rint(x * (1.0 / _TWO_PI)) * _TWO_PI
    return np.sin(r.astype(np.float32))


def _cos(x: np.ndarray) -> np.ndarray:
    x = np.asarray(x, np.float64)
    r = x - np.rint(x * (1.0 / _TWO_PI)) * _TWO_PI
    return np.cos(r.astype(np.float32))


def _sincos(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(_sin(x), _cos(x)) with one range reduction."""
    x = np.asarray(x, np.float64)
    r = (x - np.rint(x * (1.0 / _TWO_PI)) * _TWO_PI).astype(np.float32)
    return np.sin(r), np.cos(r)


def _phase_cols(t: np.ndarray, w: np.ndarray, p: np.ndarray):
    """For each column j, arg = t * w[j] + p[j] range-reduced to [-pi, pi] in float32 (the
    same float64 operations as _sin's), yielded as (j, reduced) in one reused buffer."""
    n = t.shape[0]
    a = np.empty(n)
    r = np.empty(n)
    r32 = np.empty(n, np.float32)
    for j in range(w.shape[0]):
        np.multiply(t, w[j], out=a)
        a += p[j]
        np.multiply(a, 1.0 / _TWO_PI, out=r)
        np.rint(r, out=r)
        r *= _TWO_PI
        np.subtract(a, r, out=r)
        r32[:] = r
        yield j, r32


def _sincos_cols(t: np.ndarray, w: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(_sin(arg), _cos(arg)) of arg = t[:, None] * w + p (float64 (n,), (3,), (3,)) as (n, 3),
    one column at a time (contiguous; the same operations per element as the broadcast form)
    with one range reduction for both. The float32 values are returned as float64: the
    matrix products that follow take float64 (a float32 operand would be cast inside the
    product, several times slower than a cast here)."""
    S = np.empty((t.shape[0], w.shape[0]))
    C = np.empty((t.shape[0], w.shape[0]))
    for j, r32 in _phase_cols(t, w, p):
        S[:, j] = np.sin(r32)
        C[:, j] = np.cos(r32)
    return S, C


def _sin_cols(t: np.ndarray, w: np.ndarray, p: np.ndarray) -> np.ndarray:
    """_sin(t[:, None] * w + p) as (n, m) float32, one column at a time."""
    S = np.empty((t.shape[0], w.shape[0]), np.float32)
    for j, r32 in _phase_cols(t, w, p):
        np.sin(r32, out=S[:, j])
    return S


def _cross3(a, b) -> np.ndarray:
    """Cross product of two 3-vectors (np.cross has a large per-call overhead)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def _prefix_below(t: np.ndarray, s0: float, n: int) -> int:
    """Number of leading rows of increasing t with t - s0 < 1 (as computed in float64)."""
    k = int(np.searchsorted(t, s0 + 1.0, side="left"))
    while k > 0 and t[k - 1] - s0 >= 1.0:
        k -= 1
    while k < n and t[k] - s0 < 1.0:
        k += 1
    return k


def _suffix_below(t: np.ndarray, s1: float, n: int) -> int:
    """Number of trailing rows of increasing t with s1 - t < 1 (as computed in float64)."""
    k = n - int(np.searchsorted(t, s1 - 1.0, side="right"))
    while k > 0 and s1 - t[n - k] >= 1.0:
        k -= 1
    while k < n and s1 - t[n - k - 1] < 1.0:
        k += 1
    return k


def _steps_until(steps: np.ndarray, t: np.ndarray) -> np.ndarray:
    """For increasing t: the number of heel strikes at or before each time,
    ``np.searchsorted(steps, t, side="right")``, searched among the strikes between t[0] and
    t[-1] only (those before are all counted, those after none: the same counts)."""
    if t.shape[0] == 0:
        return np.zeros(0, np.intp)
    lo = int(np.searchsorted(steps, t[0], side="right"))
    hi = int(np.searchsorted(steps, t[-1], side="right"))
    return lo + np.searchsorted(steps[lo:hi], t, side="right")


def _fade(edges: list, *arrays: np.ndarray) -> None:
    """Multiply each array's rows (1-D, or 2-D by row) by the envelope on the fading edges
    (``SiteModel._envelope_edges``), in place."""
    for rows, env in edges:
        for x in arrays:
            x[rows] *= env if x.ndim == 1 else env[:, None]


def _outer(a: np.ndarray, b) -> np.ndarray:
    """(n,) x (3,) -> (n, 3) by broadcasting (np.outer has per-call overhead)."""
    return np.asarray(a)[:, None] * np.asarray(b)


# ----------------------------------------------------------------------------- rotations
def _length(v: np.ndarray) -> np.float64:
    """Euclidean length of a float vector: sqrt(v . v), the arithmetic of np.linalg.norm(v)
    (the same number) without its per-call dispatch (several calls per segment)."""
    return np.sqrt(v.dot(v))


def _rot(axis, angle) -> np.ndarray:
    axis = np.asarray(axis, np.float64)
    axis = axis / _length(axis)
    x, y, z = axis
    c, s = np.cos(angle), np.sin(angle)
    C = 1 - c
    return np.array([[c + x * x * C, x * y * C - z * s, x * z * C + y * s],
                     [y * x * C + z * s, c + y * y * C, y * z * C - x * s],
                     [z * x * C - y * s, z * y * C + x * s, c + z * z * C]])


def _random_rotation(rng) -> np.ndarray:
    q = rng.normal(size=4)
    q /= _length(q)
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def _axis_angle(R) -> tuple[np.ndarray, float]:
    """Axis and angle of a rotation matrix (angle in [0, pi])."""
    c = np.clip((np.trace(R) - 1) / 2, -1.0, 1.0)
    ang = float(np.arccos(c))
    v = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    nv = _length(v)
    if ang < 1e-9:
        return np.array([0.0, 0.0, 1.0]), 0.0
    if nv < 1e-9:  # angle ~ pi: axis from the symmetric part
        B = (R + np.eye(3)) / 2
        i = int(np.argmax(np.diag(B)))
        ax = B[:, i] / np.sqrt(max(B[i, i], 1e-12))
        return ax / _length(ax), ang
    return v / nv, ang


# Body postures: columns = body axes (front, left, head) in world coordinates.
_BODY = {
    "upright": np.eye(3),
    "sitting": np.eye(3),
    "supine": np.array([[0, 0, 1], [0, -1, 0], [1, 0, 0]], float),  # front up, head forward
    "prone": np.array([[0, 0, 1], [0, 1, 0], [-1, 0, 0]], float),  # front down
    "left_side": np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]], float),  # left side down
    "right_side": np.array([[0, 0, 1], [1, 0, 0], [0, 1, 0]], float),  # left side up
    "none": np.eye(3),
}

# Device mounting on the body segment (columns = device x, y, z in segment axes front/left/up).
_MOUNT = {
    "hip": np.array([[0, 0, -1], [0, 1, 0], [1, 0, 0]], float),  # x up, y left, z back
    "thigh": np.array([[0, 0, 1], [0, 1, 0], [-1, 0, 0]], float),  # x down the thigh, z front
    "ankle": np.array([[0, 0, 1], [0, 1, 0], [-1, 0, 0]], float),
}
_SITE_CODE = {s: i for i, s in enumerate(SITES)}

# Gait dynamics per site: (scale of the trunk's periodic acceleration, heel-strike scale,
# swing amplitude walk/run in degrees, pendulum radius in m, swing axis)
_GAIT = {
    "wrist": dict(body=0.85, heel=0.6, swing=(25.0, 45.0), radius=0.6),
    "hip": dict(body=1.0, heel=1.0, swing=(3.0, 5.0), radius=0.0),
    "thigh": dict(body=1.0, heel=1.1, swing=(20.0, 35.0), radius=0.25),
    "ankle": dict(body=1.1, heel=3.0, swing=(25.0, 45.0), radius=0.42),
}
# Micro-motion of a worn device at rest: (frequency range Hz, share of the variance, harmonics)
# per physiological source; the per-axis RMS of the sum is WearerParams.still_micromotion_mg.
_MICRO = (((0.2, 0.33), 0.35, 1),   # breathing
          ((0.9, 1.4), 0.40, 2),    # pulse (ballistocardiographic), fundamental + 2nd harmonic
          ((8.0, 12.0), 0.25, 2))   # physiological tremor: two components in the band
_WORN_AT_REST = (A["sleep"], A["lying"], A["sitting"], A["standing"])
# Fidget amplitude (deg) and linear acceleration (g) per site
_FIDGET = {"wrist": (6.0, 0.03), "hip": (1.2, 0.012), "thigh": (2.5, 0.02), "ankle": (3.0, 0.02)}


# ----------------------------------------------------------------------------- per-site rendering
@dataclass
class _SegParams:
    R_base: np.ndarray
    axis: np.ndarray  # oscillation axis (world)
    amp: np.ndarray  # fidget: angle amplitudes (rad) of 3 sines; gait: [swing amplitude]
    freq: np.ndarray
    phase: np.ndarray
    lin_dir: np.ndarray  # (3, 3) directions of fidget linear accelerations (rows)
    lin_amp: np.ndarray  # (3,) g
    gait_amp: np.ndarray  # (3,) vertical, forward, lateral trunk acceleration amplitudes (g)
    heel: float  # heel-strike peak (g)
    radius: float  # pendulum radius (m)


class SiteModel:
    """Renders the schedule at one body site (see the module docstring)."""

    def __init__(self, schedule: Schedule, site: str = "wrist", seed: int = 1):
        if site not in SITES:
            raise ValueError(f"site must be one of {', '.join(SITES)}, got {site!r}")
        self.schedule = schedule
        self.site = site
        self.seed = int(seed)
        # one mounting error per recording (device strapped slightly rotated)
        r = np.random.default_rng(np.random.SeedSequence([self.seed, 10, _SITE_CODE[site]]))
        self._mount_err = _rot(r.normal(size=3), np.deg2rad(r.uniform(2.0, 10.0)))
        self._cache: dict[int, _SegParams] = {}
        self._end_cache: dict[int, np.ndarray] = {}
        self._micro_cache: dict[int, Optional[tuple]] = {}

    # --------------------------------------------------------------- per-segment parameters
    def _rng(self, i: int) -> np.random.Generator:
        return _generator([self.seed, 11, _SITE_CODE[self.site], int(i)])

    def params(self, i: int) -> _SegParams:
        sp = self._cache.get(i)
        if sp is not None:
            return sp
        if len(self._cache) > 64:
            self._cache.clear()
        sch = self.schedule
        r = _generator([self.seed, 12, _SITE_CODE[self.site], int(sch.group[i])])  # orientation
        act = ACTIVITIES[sch.activity[i]]
        post = POSTURES[sch.posture[i]]
        mot = MOTIONS[sch.motion[i]]
        site = self.site
        if act == "nonwear_table":
            u = r.random()
            if u < 0.65:
                R = _rot([0, 0, 1], r.uniform(0, 2 * np.pi))  # flat, face up
            elif u < 0.9:
                R = _rot([1, 0, 0], np.pi) @ _rot([0, 0, 1], r.uniform(0, 2 * np.pi))  # face down
            else:
                R = _rot([1, 0, 0], np.pi / 2) @ _rot([0, 0, 1], r.uniform(0, 2 * np.pi))  # on its side
            R = _rot(r.normal(size=3), np.deg2rad(r.uniform(0, 3))) @ R
        elif act == "nonwear_drawer":
            R = _random_rotation(r)
        elif site == "wrist":
            if mot == "gait":  # arm hanging: forearm (device x) down, random roll about it
                R = (_rot([0, 0, 1], r.uniform(-0.4, 0.4)) @ _rot([0, 1, 0], np.pi / 2)
                     @ _rot([1, 0, 0], r.uniform(-np.pi, np.pi)))
                R = _rot(r.normal(size=3), np.deg2rad(r.uniform(0, 15))) @ R
            elif act in ("sleep", "lying") or r.random() < 0.5:
                R = _random_rotation(r)  # wrists take every orientation over a week
            else:  # forearm on a desk / lap: palm down-ish, with large spread
                R = _rot(r.normal(size=3), np.deg2rad(r.uniform(0, 70))) @ _rot([0, 0, 1], r.uniform(-np.pi, np.pi))
        else:
            body = _BODY[post]
            seg = np.eye(3)
            if site in ("thigh",) and post == "sitting":
                seg = _rot([0, 1, 0], -np.pi / 2 + r.normal(0, 0.15))  # thigh horizontal, knee forward
            elif site == "ankle" and post == "sitting":
                seg = _rot([0, 1, 0], r.normal(0.2, 0.25))
            elif site == "hip" and post == "sitting":
                seg = _rot([0, 1, 0], -r.uniform(0.1, 0.45))  # reclined pelvis
            tilt = _rot(r.normal(size=3), np.deg2rad(r.uniform(0, 6)))
            R = body @ seg @ tilt @ _MOUNT[site] @ self._mount_err
        # oscillation
        r = self._rng(i)
        gait = _GAIT[site]
        if mot == "gait":
            running = act == "running"
            amp_deg = gait["swing"][1 if running else 0] * r.uniform(0.7, 1.3)
            axis = np.array([0.0, 0.0, 1.0]) if site == "hip" else np.array([0.0, 1.0, 0.0])
            amp = np.array([np.deg2rad(amp_deg)])
            freq = np.array([0.0])
            phase = np.array([r.uniform(0, 2 * np.pi)])
            base = (0.9, 0.45, 0.15) if running else (0.28, 0.15, 0.06)
            gait_amp = np.array(base) * gait["body"] * r.uniform(0.8, 1.2, 3)
            heel = (1.6 if running else 0.5) * gait["heel"] * r.uniform(0.7, 1.3)
            lin_dir = np.zeros((3, 3))
            lin_amp = np.zeros(3)
            radius = gait["radius"]
        else:
            fa, la = _FIDGET[site]
            if act in ("sleep", "lying"):
                fa, la = fa * 0.7, la * 0.7
            axis = r.normal(size=3)
            axis /= _length(axis)
            amp = np.deg2rad(fa) * r.uniform(0.3, 1.0, 3) if mot == "fidget" else np.zeros(3)
            freq = r.uniform(0.15, 2.5, 3)
            phase = r.uniform(0, 2 * np.pi, 3)
            lin_dir = r.normal(size=(3, 3))
            lin_dir /= np.linalg.norm(lin_dir, axis=1, keepdims=True)
            lin_amp = la * r.uniform(0.2, 1.0, 3) if mot == "fidget" else np.zeros(3)
            gait_amp = np.zeros(3)
            heel = 0.0
            radius = 0.0
        if sch.vigour is not None and sch.vigour[i] != 1.0:  # light activity, strolls
            v = float(sch.vigour[i])  # linear accelerations scale fully, angles up to 3x
            amp, lin_amp, gait_amp, heel = amp * min(v, 3.0), lin_amp * v, gait_amp * v, heel * v
        sp = _SegParams(R, axis, amp, freq, phase, lin_dir, lin_amp, gait_amp, heel, radius)
        self._cache[i] = sp
        return sp

    def micromotion(self, i: int):
        """The micro-motion of still segment i of a worn device: (directions (m, 3) unit vectors,
        world; amplitudes (m,) g; frequencies (m,) Hz; phases (m,) rad), or None (nonwear,
        moving segments, or ``still_micromotion_mg`` 0). Drawn from a stream of its own, so
        switching it off leaves every other draw unchanged."""
        sch = self.schedule
        rms_mg = float(getattr(sch.params, "still_micromotion_mg", 0.0))
        if (rms_mg <= 0 or MOTIONS[sch.motion[i]] != "still"
                or int(sch.activity[i]) not in _WORN_AT_REST):
            return None
        r = np.random.default_rng(np.random.SeedSequence([self.seed, 13, _SITE_CODE[self.site], int(i)]))
        # per-axis RMS (g) of this segment; a component along a random direction puts a third
        # of its variance on each axis on average
        rms = rms_mg / 1000.0 * r.lognormal(0.0, 0.5) * np.sqrt(3.0)
        amp, freq = [], []
        for (lo, hi), share, parts in _MICRO:
            if parts == 1:
                freq += [r.uniform(lo, hi)]
                var = [share]
            elif lo < 2.0:  # a fundamental and its harmonic
                f0 = r.uniform(lo, hi)
                freq += [f0, 2.0 * f0]
                var = [0.7 * share, 0.3 * share]
            else:  # components spread over the band
                freq += list(r.uniform(lo, hi, parts))
                var = [share / parts] * parts
            amp += [np.sqrt(2.0 * v) * rms for v in var]
        m = len(freq)
        phase = r.uniform(0.0, 2 * np.pi, m)
        d = r.normal(size=(m, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        return d, np.asarray(amp), np.asarray(freq), phase

    def _micro_terms(self, i: int):
        """Segment i's micro-motion as rendered: angular frequencies (m,) rad/s, phases at the
        segment's start (m,) rad and the device-frame amplitude of each component (m, 3)
        float32 g; None without micro-motion. Kept for the segment's later blocks."""
        if i in self._micro_cache:
            return self._micro_cache[i]
        mm = self.micromotion(i)
        terms = None
        if mm is not None:
            d, amp, freq, phase = mm
            wf = 2 * np.pi * freq
            terms = (wf, phase + wf * self.schedule.start[i],
                     (amp[:, None] * (d @ self.params(i).R_base)).astype(np.float32))
        if len(self._micro_cache) > 64:
            self._micro_cache.clear()
        self._micro_cache[i] = terms
        return terms

    def micromotion_window_moments(self, i: int, start_s: np.ndarray, width_s: float):
        """Mean (k, 3) and RMS about that mean (k, 3), g in the device frame, of segment i's
        micro-motion over windows [start_s, start_s + width_s) (closed form over continuous time;
        zeros when the segment has none). For window-level simulation without samples."""
        a = np.asarray(start_s, np.float64).reshape(-1)
        mm = self.micromotion(i)
        if mm is None:
            z = np.zeros((a.shape[0], 3))
            return z, z.copy()
        d, amp, freq, phase = mm
        c = amp[:, None] * (d @ self.params(i).R_base)  # (m, 3) per component and axis
        w = 2 * np.pi * freq
        ph0 = w[None, :] * a[:, None] + phase[None, :]
        ph1 = ph0 + w[None, :] * width_s
        mean_k = (np.cos(ph0) - np.cos(ph1)) / (w[None, :] * width_s)  # window mean of each sine
        sq_k = 0.5 - (np.sin(2 * ph1) - np.sin(2 * ph0)) / (4 * w[None, :] * width_s)
        mean = mean_k @ c
        var = np.maximum(sq_k @ (c * c) - mean_k ** 2 @ (c * c), 0.0)  # cross terms average out
        return mean, np.sqrt(var)

    def _angle(self, i: int, sp: _SegParams, t: np.ndarray):
        """Oscillation angle (rad) and its first and second derivatives at times t."""
        mot = MOTIONS[self.schedule.motion[i]]
        if mot == "still":
            z = np.zeros_like(t)
            return z, z, z
        if mot == "fidget":
            w = 2 * np.pi * sp.freq
            arg = w[None, :] * t[:, None] + sp.phase[None, :]
            s, c = np.sin(arg), np.cos(arg)
            return s @ sp.amp, c @ (sp.amp * w), -(s @ (sp.amp * w * w))
        # gait: swing at the stride frequency (half the step frequency), locked to the steps
        ph, dph = self._step_phase(i, t)
        arg = np.pi * ph + sp.phase[0]
        w = np.pi * dph
        return sp.amp[0] * np.sin(arg), sp.amp[0] * w * np.cos(arg), -sp.amp[0] * w * w * np.sin(arg)

    def _step_phase(self, i: int, t: np.ndarray):
        """Continuous step count (phase) at t and its rate (steps/s), from the heel strikes."""
        st = self.schedule.steps
        hz = self.schedule.step_hz[i]
        k = np.searchsorted(st, t, side="right") - 1
        k0 = np.clip(k, 0, max(st.size - 2, 0))
        t0 = st[k0]
        t1 = st[k0 + 1] if st.size > 1 else t0 + 1.0 / hz
        iv = np.where(t1 > t0, t1 - t0, 1.0 / hz)
        iv = np.where(iv > 2.5 / hz, 1.0 / hz, iv)  # across gaps between gait segments
        ph = k0 + (t - t0) / iv
        return ph, 1.0 / iv

    def orientation_at_end(self, i: int) -> np.ndarray:
        """Device orientation at the end of segment i."""
        R = self._end_cache.get(i)
        if R is not None:
            return R
        sp = self.params(i)
        t1 = np.array([self.schedule.end[i]])
        ang, _, _ = self._angle(i, sp, t1)
        env = self._envelope(i, t1)
        R = _rot(sp.axis, float(ang[0] * env[0])) @ sp.R_base
        if len(self._end_cache) > 64:
            self._end_cache.clear()
        self._end_cache[i] = R
        return R

    def _envelope(self, i: int, t: np.ndarray) -> np.ndarray:
        """Oscillation fades in over 1 s after the transition and out over 1 s before the end
        (float32; all ones in the middle of a segment)."""
        if self._envelope_flat(i, t):
            return np.ones(t.shape[0], np.float32)
        s0 = self.schedule.start[i] + self.schedule.trans_s[i]
        s1 = self.schedule.end[i]
        return np.clip(np.minimum(t - s0, s1 - t), 0.0, 1.0).astype(np.float32)

    def _envelope_flat(self, i: int, t: np.ndarray) -> bool:
        """True when ``_envelope(i, t)`` is all ones (t inside the segment's middle)."""
        s0 = self.schedule.start[i] + self.schedule.trans_s[i]
        s1 = self.schedule.end[i]
        return bool(t.shape[0] and t[0] - s0 >= 1.0 and s1 - t[-1] >= 1.0)

    def _envelope_edges(self, i: int, t: np.ndarray) -> list:
        """The fade-in and fade-out of ``_envelope(i, t)`` (t increasing): a list of (rows,
        envelope on those rows) covering every sample within 1 s of either end, where the
        envelope can be below one; it is exactly one everywhere else (x * 1 = x: the products
        there are skipped, the same numbers)."""
        s0 = self.schedule.start[i] + self.schedule.trans_s[i]
        s1 = self.schedule.end[i]
        n = t.shape[0]
        k0 = _prefix_below(t, s0, n)  # rows with t - s0 < 1
        k1 = n - _suffix_below(t, s1, n)  # rows from k1 on have s1 - t < 1
        if k0 >= k1:
            rows = [slice(0, n)] if n else []
        else:
            rows = [r for r in (slice(0, k0), slice(k1, n)) if r.stop > r.start]
        return [(r, np.clip(np.minimum(t[r] - s0, s1 - t[r]), 0.0, 1.0).astype(np.float32))
                for r in rows]

    # --------------------------------------------------------------- rendering
    BLOCK = 16384  # samples per inner block (keeps temporaries in cache)

    def render(self, t: np.ndarray, gyro: bool = False, dtype=np.float64):
        """Specific force (n, 3) in g in the device frame at true times t (s, increasing), and the
        angular rate (n, 3) in deg/s when ``gyro`` (else None). ``dtype`` of the force array
        (float32 halves the memory traffic of the simulator's hot path)."""
        t = np.asarray(t, np.float64)
        n = t.shape[0]
        f = np.empty((n, 3), dtype)
        w = np.zeros((n, 3)) if gyro else None
        if n == 0:
            return f, w
        sch = self.schedule
        i0 = int(sch.segment_at(t[0]))
        i1 = int(sch.segment_at(t[-1]))
        bounds = np.searchsorted(t, sch.start[i0 + 1:i1 + 1], side="left")
        edges = np.concatenate([[0], bounds, [n]])
        for j, i in enumerate(range(i0, i1 + 1)):
            a, b = int(edges[j]), int(edges[j + 1])
            for c in range(a, b, self.BLOCK):
                d = min(b, c + self.BLOCK)
                self._render_segment(i, t[c:d], f[c:d], None if w is None else w[c:d])
        return f, w

    def _render_segment(self, i: int, t: np.ndarray, f: np.ndarray, w: Optional[np.ndarray]) -> None:
        sch = self.schedule
        sp = self.params(i)
        s0 = sch.start[i]
        tr = sch.trans_s[i]
        nt = int(np.searchsorted(t, s0 + tr, side="left")) if tr > 0 else 0
        if nt:  # opening transition from the previous segment's final orientation
            R_prev = self.orientation_at_end(i - 1) if i > 0 else sp.R_base
            ax, phi = _axis_angle(sp.R_base @ R_prev.T)
            u = np.clip((t[:nt] - s0) / tr, 0.0, 1.0)
            ang = phi * (u * u * (3 - 2 * u))
            push = _outer(_sin(np.pi * u) * (0.15 * min(phi, 1.0)), ax)  # a small push/pull
            _device_force(ang, ax, R_prev, push, out=f[:nt])
            if w is not None:
                w[:nt] = _outer(phi * 6 * u * (1 - u) / tr, R_prev.T @ ax) * (180 / np.pi)
        if nt == t.shape[0]:
            return
        tm = t[nt:]
        mot = MOTIONS[sch.motion[i]]
        if mot == "still":
            terms = self._micro_terms(i)
            if terms is None:
                f[nt:] = sp.R_base[2, :]  # R^T (0, 0, 1): the third row of R
                if w is not None:
                    w[nt:] = 0.0
                return
            wf, phase0, coef = terms
            # R^T (e_z + L): gravity plus the micro-acceleration, into the device frame
            S = _sin_cols(tm - s0, wf, phase0)
            f[nt:] = S @ coef
            for j in range(3):  # f += R^T e_z by column (the (n, 3)-by-(3,) broadcast is slower)
                c = f[nt:, j]
                c += sp.R_base[2, j]
            if w is not None:
                w[nt:] = 0.0  # linear: no rotation
            return
        edges = self._envelope_edges(i, tm)  # the envelope is one elsewhere
        if mot == "fidget":
            wf = 2 * np.pi * sp.freq
            S, Cc = _sincos_cols(tm - s0, wf, sp.phase + wf * s0)
            ang = S @ sp.amp
            c1, s1 = np.cos(1.0), np.sin(1.0)  # scalars
            L = (S @ ((sp.lin_amp * c1)[:, None] * sp.lin_dir)
                 + Cc @ ((sp.lin_amp * s1)[:, None] * sp.lin_dir))
            _fade(edges, ang, L)
            _device_force(ang, sp.axis, sp.R_base, L, out=f[nt:])
            if w is not None:
                dang = Cc @ (sp.amp * wf)
                _fade(edges, dang)
                w[nt:] = _outer(dang, sp.R_base.T @ sp.axis) * (180 / np.pi)
            return
        # gait: trunk acceleration locked to the steps, heel strikes, swing at stride frequency
        st = sch.steps
        hz = sch.step_hz[i]
        k = _steps_until(st, tm) - 1
        k0 = np.clip(k, 0, max(st.size - 2, 0))
        t0 = st[k0]
        iv = st[k0 + 1] - t0
        iv = np.where((iv > 0) & (iv < 2.5 / hz), iv, 1.0 / hz)
        dt = tm - t0
        ph = k0 + dt / iv
        x = np.minimum(dt * 40.0, 60.0).astype(np.float32)
        heel = np.where(k >= 0, x * np.exp(1.0 - x), 0.0)  # peak 1 at 25 ms
        two = 2 * np.pi * ph
        ga = sp.gait_amp
        L = np.empty((tm.shape[0], 3))
        L[:, 0] = ga[1] * _sin(two + 0.3)
        L[:, 1] = ga[2] * _sin(0.5 * two)
        L[:, 2] = ga[0] * _cos(two) + sp.heel * heel
        arg = 0.5 * two + sp.phase[0]
        wv = np.pi / iv
        amp = sp.amp[0]
        sa, ca = _sincos(arg)
        ang = amp * sa
        dang = amp * wv * ca
        _fade(edges, L, ang, dang)
        if sp.radius > 0:  # pendulum: device at radius r below the pivot, rotating about axis
            ddang = -ang * wv * wv
            u0 = np.array([0.0, 0.0, -sp.radius])  # perpendicular to the swing axis
            u1 = _cross3(sp.axis, u0)
            s, c = _sincos(ang)
            alpha = -ddang * s - dang * dang * c
            beta = ddang * c - dang * dang * s
            for j in range(3):  # L += (_outer(alpha, u0) + _outer(beta, u1)) / G, by column
                L[:, j] += (alpha * u0[j] + beta * u1[j]) / G
            _device_force(ang, sp.axis, sp.R_base, L, out=f[nt:], sc=(s, c))
        else:
            _device_force(ang, sp.axis, sp.R_base, L, out=f[nt:])
        if w is not None:
            w[nt:] = _outer(dang, sp.R_base.T @ sp.axis) * (180 / np.pi)


def _device_force(ang: np.ndarray, axis: np.ndarray, R_ref: np.ndarray,
                  L: Optional[np.ndarray] = None, out: Optional[np.ndarray] = None,
                  sc: Optional[tuple] = None) -> np.ndarray:
    """Device-frame specific force R_ref^T Rot(axis, -ang) (e_z + L), L the world dynamic
    acceleration (n, 3) in g (Rodrigues' formula, expanded with constant vectors); float32.
    Written into ``out`` (n, 3) when given; ``sc``: ``_sincos(ang)`` if already known. Computed one device axis at a time on contiguous
    vectors (the (n, 1)-by-(3,) broadcasts are several times slower), each element with the
    same float32 operations in the same order as the broadcast form: the same numbers."""
    f32 = np.float32
    s, c = sc if sc is not None else _sincos(ang)
    oc = f32(1.0) - c
    kR = (axis @ R_ref).astype(f32)
    g0 = R_ref[2, :].astype(f32)
    g1 = (np.array([axis[1], -axis[0], 0.0]) @ R_ref).astype(f32)  # axis x e_z
    g2 = (axis[2] * kR).astype(f32)
    n = c.shape[0]
    if out is None:
        out = np.empty((n, 3), f32)
    if L is not None:
        L = L.astype(f32, copy=False)
        Kx = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
        LR = (L @ R_ref.astype(f32)).T.copy()  # rows: device axes
        LK = (L @ (Kx.T @ R_ref).astype(f32)).T.copy()
        ocLa = oc * (L @ axis.astype(f32))
    o = np.empty(n, f32)
    tmp = np.empty(n, f32)
    for j in range(3):
        np.multiply(c, g0[j], out=o)
        o -= np.multiply(s, g1[j], out=tmp)
        o += np.multiply(oc, g2[j], out=tmp)
        if L is not None:
            o += np.multiply(c, LR[j], out=tmp)
            o -= np.multiply(s, LK[j], out=tmp)
            o += np.multiply(ocLa, kR[j], out=tmp)
        out[:, j] = o
    return out
