"""One recording's rhythm row from its epoch series (``rhythm_row``) and the table's columns.

Inputs per epoch (consecutive epochs of the recording, gaps included): start (UTC ns), ENMO (mg),
invalid (not clean: nonwear, clipping, gap, QC, filter warm-up), and with sleep the SIB and SPT
flags. ``zone`` gives the local midnights and dates. See metrics.py for each metric and rules.py
for their sources.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from . import metrics, rules

DAY_NS = 86400 * 10**9

# column -> (unit, definition) ; docs/columns.md lists the same
RHYTHM_COLUMNS = [
    "cosinor_days", "time_offset_h", "is", "iv", "phi",
    "cosinor_mesor", "cosinor_amplitude", "cosinor_acrophase_rad", "cosinor_acrophase_h",
    "cosinor_r2", "ext_minimum", "ext_amplitude", "ext_alpha", "ext_beta", "ext_acrophase_h",
    "ext_up_mesor_h", "ext_down_mesor_h", "ext_mesor", "ext_f_pseudo", "ext_r2",
    "m10_avday_mg", "m10_avday_start_h", "l5_avday_mg", "l5_avday_start_h", "ra_avday",
    "ra_day_mean", "ra_days", "sri", "sri_day_pairs"]


def frag_column(name: str, mode: str) -> str:
    """The rhythm table's column of GGIR part 6's FRAG_<name>_<mode>: lower case, '.' -> '_'."""
    return f"frag_{name.lower().replace('.', '_')}_{mode}"


RHYTHM_COLUMNS += [frag_column(k, "day") for k in metrics.FRAG_DAY] \
    + [frag_column(k, "spt") for k in metrics.FRAG_SPT] + ["timezone"]


def local_midnights(t_ns: np.ndarray, zone) -> np.ndarray:
    """0-based indices of the epochs that start at a local midnight."""
    local = zone.local_ns(t_ns) if zone.known else t_ns
    return np.flatnonzero(local % DAY_NS == 0)


def average_day(enmo_mg: np.ndarray, invalid: np.ndarray, epoch_s: float) -> np.ndarray:
    """GGIR's imputation average day: per slot of the day from the first epoch the mean of the
    valid epochs, 0 for a slot never valid (R/g.impute.R:366-410)."""
    per_day = int(round(86400 / epoch_s))
    n = enmo_mg.shape[0]
    slot = np.arange(n) % per_day
    ok = ~np.asarray(invalid, bool) & np.isfinite(enmo_mg)
    s = np.bincount(slot[ok], weights=enmo_mg[ok], minlength=per_day)
    c = np.bincount(slot[ok], minlength=per_day)
    return np.where(c > 0, s / np.maximum(c, 1), 0.0)


def rhythm_row(t_ns: np.ndarray, enmo_mg: np.ndarray, invalid: np.ndarray, zone, epoch_s: float,
               sib: Optional[np.ndarray] = None, spt: Optional[np.ndarray] = None,
               days: Optional[list] = None) -> dict:
    """The rhythm table's row (column -> value; None where not defined)."""
    row = {c: None for c in RHYTHM_COLUMNS}
    row["timezone"] = zone.label
    n = t_ns.shape[0]
    if n == 0:
        return row
    mid = local_midnights(t_ns, zone)
    ci = metrics.cosinor_input(enmo_mg / 1000.0, invalid, mid, epoch_s)  # GGIR's ENMO is in g
    if ci.enough and ci.time_offset_h is not None:
        c = metrics.cosinor(ci.minutes, ci.time_offset_h)
        row.update(cosinor_days=c.ndays, time_offset_h=c.time_offset_h,
                   cosinor_mesor=c.mesor, cosinor_amplitude=c.amplitude,
                   cosinor_acrophase_rad=c.acrophase_rad, cosinor_acrophase_h=c.acrophase_h,
                   cosinor_r2=c.r2, ext_minimum=c.ext_minimum, ext_amplitude=c.ext_amplitude,
                   ext_alpha=c.ext_alpha, ext_beta=c.ext_beta, ext_acrophase_h=c.ext_acrophase_h,
                   ext_up_mesor_h=c.ext_up_mesor_h, ext_down_mesor_h=c.ext_down_mesor_h,
                   ext_mesor=c.ext_mesor, ext_f_pseudo=c.ext_f_pseudo, ext_r2=c.ext_r2,
                   **{"is": c.ivis.interdaily_stability, "iv": c.ivis.intradaily_variability,
                      "phi": c.ivis.phi})
    per_day = int(round(86400 / epoch_s))
    if n > per_day and mid.shape[0]:  # GGIR's average day needs more than one day
        prof = average_day(enmo_mg, invalid, epoch_s)
        first = int(mid[0]) % per_day
        m10, m10h = metrics.average_day_mx(prof, first, epoch_s, 10.0, np.argmax)
        l5, l5h = metrics.average_day_mx(prof, first, epoch_s, 5.0, np.argmin)
        row.update(m10_avday_mg=m10, m10_avday_start_h=m10h, l5_avday_mg=l5, l5_avday_start_h=l5h,
                   ra_avday=metrics.relative_amplitude(m10, l5))
    ras = [metrics.relative_amplitude(d.get("m10_mg"), d.get("l5_mg")) for d in (days or [])
           if d.get("valid_day") and d.get("date") != "all"]
    ras = [r for r in ras if r is not None]
    row["ra_days"] = len(ras)
    row["ra_day_mean"] = float(np.mean(ras)) if ras else None
    if sib is not None and n > 2 * per_day:  # GGIR part 3: at least two days
        off = zone.offsets_s(t_ns) if zone.known else np.zeros(n, np.int64)
        pairs = metrics.sleep_regularity(sib, invalid, t_ns // 10**9, off, epoch_s)
        kept = [s for _, s, f in pairs if f > rules.SRI_MIN_FRAC_VALID]
        row["sri_day_pairs"] = len(kept)
        row["sri"] = float(np.mean(kept)) if kept else None
    row.update(fragmentation(enmo_mg, invalid, sib, spt, epoch_s))
    return row


def part5_classes(enmo_mg, invalid, sib, spt, epoch_s: float):
    """GGIR part 5's behavioural classes (engine/timeuse/levels.py) on the clean epochs, with
    GGIR's default thresholds (part 6 takes the first threshold set: part6_threshold_combi)."""
    from ..timeuse.levels import levels
    n = enmo_mg.shape[0]
    spt = np.zeros(n, bool) if spt is None else np.asarray(spt, bool)
    sib = np.zeros(n, bool) if sib is None else np.asarray(sib, bool)
    value = np.where(np.asarray(invalid, bool), np.nan, enmo_mg)
    return levels(value, spt, sib, epoch_s, (rules.LIGHT_MG, rules.MODERATE_MG, rules.VIGOROUS_MG)), spt


def day_classes(lv) -> np.ndarray:
    """g.fragmentation's waking classes from part 5's (R/g.fragmentation.R:100-107, 122-126):
    1 inactivity (unbouted or in inactivity bouts), 2 light (unbouted or in light bouts), 3 MVPA
    (moderate or vigorous unbouted, or in MVPA bouts); NaN in the sleep period or missing."""
    names = lv.names
    lut = np.full(len(names) + 1, np.nan)  # index -1 (missing) -> the last entry, NaN
    for i, c in enumerate(names):
        if c == "day_IN_unbt" or c.startswith("day_IN_bts"):
            lut[i] = 1.0
        elif c == "day_LIG_unbt" or c.startswith("day_LIG_bts"):
            lut[i] = 2.0
        elif c in ("day_MOD_unbt", "day_VIG_unbt") or c.startswith("day_MVPA_bts"):
            lut[i] = 3.0
    return lut[lv.level]


def fragmentation(enmo_mg, invalid, sib, spt, epoch_s: float) -> dict:
    """GGIR part 6's fragmentation columns (g.fragmentation "day" on the waking part, "spt" on the
    sleep periods when sleep is on), on part 5's classes of the clean epochs."""
    lv, spt_b = part5_classes(np.asarray(enmo_mg, np.float64), invalid, sib, spt, epoch_s)
    out = {}
    d = metrics.fragmentation_day(day_classes(lv), 60.0 / epoch_s)
    out.update({frag_column(k, "day"): v for k, v in d.items()})
    if spt is not None:
        names = list(lv.names)
        lev = lv.level
        wake = np.isin(lev, [names.index(c) for c in ("spt_wake_IN", "spt_wake_LIG", "spt_wake_MOD",
                                                      "spt_wake_VIG")])
        pa = np.isin(lev, [names.index(c) for c in ("spt_wake_LIG", "spt_wake_MOD", "spt_wake_VIG")])
        missing = ~spt_b | (lev < 0)
        # as GGIR, also without any sleep period: no fragments, and GGIR's TP of (0 + 1e-6) /
        # (0 + 1e-6) = 1
        sp = metrics.fragmentation_spt(pa, wake, missing)
        out.update({frag_column(k, "spt"): v for k, v in sp.items()})
    return out
