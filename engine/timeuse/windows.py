"""GGIR part 5's time use per window: wake-to-wake (WW), midnight-to-midnight (MM) and
onset-to-onset (OO) windows of a recording, from its epochs and nights (rules.py cites each rule).

``time_use(series, nights, zone, epoch_s, cut)`` -> one dict per window: the window's span, the
night inside it and its guider, the sleep period (sleep and wake in it), the waking part, nonwear
and invalid time, minutes per intensity band and GGIR bout minutes per band in the waking part
(clean epochs only), and whether GGIR's part 5 report would keep the window.
"""

from __future__ import annotations

import numpy as np

from ..outcomes.bouts import ggir_bouts
from . import rules

DAY_NS = 86400 * 10**9
BANDS = ("inactive", "light", "moderate", "vigorous", "mvpa")
WINDOW_COLUMNS = (
    ["window_type", "window_number", "date", "start_local", "end_local", "window_cut", "night",
     "guider", "night_valid", "duration_h", "valid_h", "nonwear_h", "invalid_h", "spt_h",
     "sleep_h", "wake_spt_h", "day_h", "nonwear_perc_day", "nonwear_perc_spt", "metric",
     "thresholds_mg"]
    + [f"min_day_{b}" for b in BANDS]
    + [f"bout_min_day_{b}_{m}m" for b in BANDS[1:] for m in rules.BOUT_MINUTES]
    + ["window_valid"])


def thresholds(cut=None) -> tuple:
    """(metric column, light, moderate, vigorous) of a registry set, else GGIR's defaults."""
    if cut is None:
        return ("enmo_mg",) + rules.DEFAULT_THRESHOLDS_MG
    return (cut.column, cut.light, cut.moderate, cut.vigorous)


def band_masks(value, waking_clean, th) -> dict:
    _, lig, mod, vig = th
    v = np.where(waking_clean & np.isfinite(value), value, np.nan)
    ok = np.isfinite(v)
    lo = lig if lig is not None else mod
    out = {"inactive": ok & (v < lo)}
    out["light"] = ok & (v >= lig) & (v < mod) if lig is not None else np.zeros(v.shape, bool)
    out["moderate"] = ok & (v >= mod) & ((v < vig) if vig is not None else True)
    out["vigorous"] = ok & (v >= vig) if vig is not None else np.zeros(v.shape, bool)
    out["mvpa"] = ok & (v >= mod)
    return out


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


def time_use(t_ns, value, clean, nonwear, sib, spt, nights, zone, epoch_s: float, cut=None) -> list:
    """``nights``: engine.sleep Night objects (their ``spt`` epochs index these arrays)."""
    from ..timezones import local_text
    n = t_ns.shape[0]
    if n == 0:
        return []
    h = epoch_s / 3600.0
    th = thresholds(cut)
    spt = np.asarray(spt, bool)
    waking_clean = ~spt & np.asarray(clean, bool)
    masks = band_masks(np.asarray(value, np.float64), waking_clean, th)
    epm = max(1, int(round(60 / epoch_s)))
    bouts = {(b, m): ggir_bouts(masks[b], m * epm, epm) for b in BANDS[1:] for m in rules.BOUT_MINUTES}
    local = zone.local_ns(t_ns) if zone.known else t_ns
    midnights = np.flatnonzero(local % DAY_NS == 0).tolist()
    with_spt = [x for x in nights if x.spt is not None]
    spans = [x.spt for x in with_spt]
    cs = {k: np.concatenate([[0], np.cumsum(v.astype(np.int64))]) for k, v in
          [("clean", np.asarray(clean, bool)), ("nonwear", np.asarray(nonwear, bool)),
           ("invalid", ~np.asarray(clean, bool)), ("spt", spt),
           ("sleep", spt & np.asarray(sib, bool)), ("spt_nonwear", spt & np.asarray(nonwear, bool)),
           ("day_nonwear", ~spt & np.asarray(nonwear, bool)), ("day_invalid", ~spt & ~np.asarray(clean, bool))]
          + [(f"b_{b}", masks[b]) for b in BANDS]
          + [(f"bt_{b}_{m}", v) for (b, m), v in bouts.items()]}
    rows = []
    for kind, num, a, b, k in _windows(spans, n, midnights):
        if b <= a:
            continue
        def c(key):  # noqa: E306
            return int(cs[key][b] - cs[key][a])
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
             "nonwear_perc_day": 100.0 * c("day_nonwear") / day_e if day_e else None,
             "nonwear_perc_spt": 100.0 * c("spt_nonwear") / spt_e if spt_e else None,
             "metric": th[0], "thresholds_mg": "/".join("" if x is None else f"{x:g}" for x in th[1:])}
        for bnd in BANDS:
            r[f"min_day_{bnd}"] = c(f"b_{bnd}") * epoch_s / 60.0
        for (bnd, m) in bouts:
            r[f"bout_min_day_{bnd}_{m}m"] = c(f"bt_{bnd}_{m}") * epoch_s / 60.0
        wear_day = (day_e - c("day_invalid")) / day_e if day_e else 0.0
        ok = wear_day >= rules.INCLUDE_DAY_CRIT - 1e-12 and spt_e > 0 and day_e > 0
        if kind == "MM":
            ok = ok and dur * h >= rules.MINIMUM_MM_HOURS - 1e-9
        r["window_valid"] = int(ok)
        rows.append(r)
    order = {"WW": 0, "MM": 1, "OO": 2}
    rows.sort(key=lambda r: (order[r["window_type"]], r["window_number"]))
    return rows
