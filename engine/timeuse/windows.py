"""GGIR part 5's time use per window: wake-to-wake (WW), midnight-to-midnight (MM) and
onset-to-onset (OO) windows of a recording, from its epochs and nights (rules.py cites each rule).

``time_use(t_ns, value, clean, nonwear, sib, spt, nights, zone, epoch_s, cut, imputed)`` -> one
dict per window: the window's span, the night inside it and its guider, the sleep period (sleep
and wake in it), the waking part, nonwear and invalid time, and GGIR's part 5 time use: minutes per
behavioural class (levels.py: sleep-period classes, unbouted intensities, hierarchical bouts),
waking totals per intensity, bouts per bout class and blocks per class, and whether GGIR's part 5
report would keep the window. ``value`` is the metric with imputed values on the epochs that are
not clean when ``imputed`` (GGIR's part 5 series), else with those epochs missing.
"""

from __future__ import annotations

import numpy as np

from . import rules
from .levels import TOTAL_NAMES, class_names, levels

DAY_NS = 86400 * 10**9
_CLASSES = class_names()
_BOUT_CLASSES = [c for c in _CLASSES if "_bts_" in c]
TIMEUSE_COLUMNS = (
    [f"dur_{c}_min" for c in _CLASSES] + [f"dur_day_total_{c}_min" for c in TOTAL_NAMES]
    + ["dur_day_min", "dur_spt_min", "dur_day_spt_min", "N_atleast5minwakenight",
       "sleep_efficiency_after_onset"]
    + [f"Nbouts_{c}" for c in _BOUT_CLASSES]
    + [f"Nblocks_{c}" for c in _CLASSES] + [f"Nblocks_day_total_{c}" for c in TOTAL_NAMES])
WINDOW_COLUMNS = (
    ["window_type", "window_number", "date", "start_local", "end_local", "window_cut", "night",
     "guider", "night_valid", "duration_h", "valid_h", "nonwear_h", "invalid_h", "spt_h",
     "sleep_h", "wake_spt_h", "day_h", "nonwear_perc_day", "nonwear_perc_spt",
     "nonwear_perc_day_spt", "metric", "thresholds_mg", "imputed"]
    + TIMEUSE_COLUMNS + ["window_valid"])


def thresholds(cut=None) -> tuple:
    """(metric column, light, moderate, vigorous) of a registry set, else GGIR's defaults."""
    if cut is None:
        return ("enmo_mg",) + rules.DEFAULT_THRESHOLDS_MG
    return (cut.column, cut.light, cut.moderate, cut.vigorous)


def _runs(x: np.ndarray) -> int:
    """Runs of True (R: length(which(rle(x)$values == 1)))."""
    if not x.shape[0]:
        return 0
    return int(x[0]) + int(np.count_nonzero(x[1:] & ~x[:-1]))


def _segment_time_use(lv, diur, sib, nonwear, a: int, b: int, epoch_s: float, mm_no_edges: bool) -> dict:
    """GGIR's g.part5_analyseSegment figures of the epochs [a, b)."""
    m = epoch_s / 60.0
    k = len(_CLASSES)
    lev = lv.level[a:b]
    counts = np.bincount(lev[lev >= 0], minlength=k)
    tot = np.bincount(lv.total[a:b], minlength=5)
    d = diur[a:b].copy()
    if mm_no_edges:  # GGIR sets diur to 0 over the window while analysing it
        d[:] = False
    r = {f"dur_{c}_min": counts[i] * m for i, c in enumerate(_CLASSES)}
    r.update({f"dur_day_total_{c}_min": tot[i + 1] * m for i, c in enumerate(TOTAL_NAMES)})
    nd, ns = int(np.count_nonzero(~d)), int(np.count_nonzero(d))
    r["dur_day_min"], r["dur_spt_min"], r["dur_day_spt_min"] = nd * m, ns * m, (b - a) * m
    nw = nonwear[a:b]
    r["nonwear_perc_day"] = 100.0 * np.count_nonzero(~d & nw) / nd if nd else None
    r["nonwear_perc_spt"] = 100.0 * np.count_nonzero(d & nw) / ns if ns else None
    r["nonwear_perc_day_spt"] = 100.0 * np.count_nonzero(nw) / (b - a)
    p = np.flatnonzero(lev == 0)
    r["N_atleast5minwakenight"] = max(0, int(np.count_nonzero(np.diff(p) > rules.LONG_WAKE_S / epoch_s)) - 2)
    r["sleep_efficiency_after_onset"] = np.count_nonzero(sib[a:b] & d) / ns if ns else None
    for c in _BOUT_CLASSES:
        r[f"Nbouts_{c}"] = _runs(lv.bouts[c][a:b])
    starts = np.r_[True, lev[1:] != lev[:-1]] if lev.shape[0] else np.zeros(0, bool)
    blocks = np.bincount(lev[starts & (lev >= 0)], minlength=k)
    for i, c in enumerate(_CLASSES):
        r[f"Nblocks_{c}"] = int(blocks[i])
    t = lv.total[a:b]
    tstarts = np.r_[True, t[1:] != t[:-1]] if t.shape[0] else np.zeros(0, bool)
    tb = np.bincount(t[tstarts], minlength=5)
    for i, c in enumerate(TOTAL_NAMES):
        r[f"Nblocks_day_total_{c}"] = int(tb[i + 1])
    return r


def _windows(spt_spans, n, midnights):
    """(type, number, first, stop, night index or None) of every window."""
    out = []
    wakes = [(b, k) for k, (a, b) in enumerate(spt_spans)]
    onsets = [(a, k) for k, (a, b) in enumerate(spt_spans)]
    for i in range(len(wakes) - 1):
        out.append(("WW", i + 1, wakes[i][0], wakes[i + 1][0], wakes[i + 1][1]))
    for i in range(len(onsets) - 1):
        out.append(("OO", i + 1, onsets[i][0], onsets[i + 1][0], onsets[i][1]))
    edges = list(midnights)
    per_25h = None
    if edges and edges[0] > 0:
        edges = [0] + edges
    if edges and edges[-1] < n:
        edges = edges + [n]
    for i in range(len(edges) - 1):
        out.append(("MM", i + 1, edges[i], edges[i + 1], None))
    del per_25h
    return out


def time_use(t_ns, value, clean, nonwear, sib, spt, nights, zone, epoch_s: float, cut=None,
             imputed: bool = False) -> list:
    """``nights``: engine.sleep Night objects (their ``spt`` epochs index these arrays)."""
    from ..timezones import local_text
    n = t_ns.shape[0]
    if n == 0:
        return []
    h = epoch_s / 3600.0
    th = thresholds(cut)
    spt = np.asarray(spt, bool)
    sib = np.asarray(sib, bool)
    clean = np.asarray(clean, bool)
    nonwear = np.asarray(nonwear, bool)
    value = np.asarray(value, np.float64)
    if not imputed:
        value = np.where(clean, value, np.nan)
    lv = levels(value, spt, sib, epoch_s, th[1:])
    local = zone.local_ns(t_ns) if zone.known else t_ns
    midnights = np.flatnonzero(local % DAY_NS == 0).tolist()
    with_spt = [x for x in nights if x.spt is not None]
    spans = [x.spt for x in with_spt]
    counts = {"clean": lambda a, b: np.count_nonzero(clean[a:b]),
              "nonwear": lambda a, b: np.count_nonzero(nonwear[a:b]),
              "invalid": lambda a, b: (b - a) - np.count_nonzero(clean[a:b]),
              "spt": lambda a, b: np.count_nonzero(spt[a:b]),
              "sleep": lambda a, b: np.count_nonzero(spt[a:b] & sib[a:b]),
              "day_invalid": lambda a, b: (b - a) - np.count_nonzero(spt[a:b] | clean[a:b])}
    rows = []
    for kind, num, a, b, k in _windows(spans, n, midnights):
        if (b - a) * epoch_s <= rules.MINIMUM_WINDOW_S:
            continue
        def c(key):  # noqa: E306
            return int(counts[key](a, b))
        dur, spt_e = b - a, c("spt")
        day_e = dur - spt_e
        night = with_spt[k] if k is not None else None
        if kind == "MM":  # the night that starts on the day's evening
            d = (local[a] // DAY_NS)
            date = str(np.datetime64(int(d), "D"))
            night = next((x for x in with_spt if x.date.isoformat() == date), None)
        elif kind == "WW":
            date = str(np.datetime64(int(local[a] // DAY_NS), "D"))
        else:
            date = night.date.isoformat()
        cut_side = ""
        if kind == "MM":
            cut_side = "start" if (a == 0 and (local[0] % DAY_NS) != 0) else (
                "end" if b == n and (a + int(round(86400 / epoch_s))) > n else "")
        r = {"window_type": kind, "window_number": num, "date": date,
             "start_local": local_text(int(t_ns[a]), zone),
             "end_local": local_text(int(t_ns[b - 1]) + int(round(epoch_s * 1e9)), zone),
             "window_cut": cut_side,
             "night": night.date.isoformat() if night is not None else None,
             "guider": night.guider if night is not None else None,
             "night_valid": int(night.valid) if night is not None else None,
             "duration_h": dur * h, "valid_h": c("clean") * h, "nonwear_h": c("nonwear") * h,
             "invalid_h": c("invalid") * h, "spt_h": spt_e * h, "sleep_h": c("sleep") * h,
             "wake_spt_h": (spt_e - c("sleep")) * h, "day_h": day_e * h,
             "metric": th[0], "thresholds_mg": "/".join("" if x is None else f"{x:g}" for x in th[1:]),
             "imputed": int(imputed)}
        edges = np.diff(spt[a:b - 1].astype(np.int8))
        r.update(_segment_time_use(lv, spt, sib, nonwear, a, b, epoch_s,
                                   kind == "MM" and not np.any(edges)))
        wear_day = (day_e - c("day_invalid")) / day_e if day_e else 0.0
        ok = wear_day >= rules.INCLUDE_DAY_CRIT - 1e-12 and spt_e > 0 and day_e > 0
        if kind == "MM":
            ok = ok and dur * h >= rules.MINIMUM_MM_HOURS - 1e-9
        r["window_valid"] = int(ok)
        rows.append(r)
    order = {"WW": 0, "MM": 1, "OO": 2}
    rows.sort(key=lambda r: (order[r["window_type"]], r["window_number"]))
    return rows
