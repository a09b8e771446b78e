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
    "ra_day_mean", "ra_days", "sri", "sri_day_pairs", "tp_in2pa", "tp_pa2in", "nfrag_in2pa",
    "nfrag_pa2in", "timezone"]


def local_midnights(t_ns: np.ndarray, zone) -> np.ndarray:
    """0-based indices of the epochs that start at a local midnight."""
    local = zone.local_ns(t_ns) if zone.known else t_ns
    return np.flatnonzero(local % DAY_NS == 0)


def intensity_classes(enmo_mg: np.ndarray, invalid: np.ndarray, spt: Optional[np.ndarray],
                      light: float = rules.LIGHT_MG, moderate: float = 100.0) -> np.ndarray:
    """GGIR part 6's day classes per epoch: 1 inactive (< light), 2 light, 3 MVPA (>= moderate);
    NaN inside the sleep period and for invalid epochs."""
    c = np.where(enmo_mg < light, 1.0, np.where(enmo_mg < moderate, 2.0, 3.0))
    drop = np.asarray(invalid, bool) | ~np.isfinite(enmo_mg)
    if spt is not None:
        drop |= np.asarray(spt, bool)
    return np.where(drop, np.nan, c)


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
    tp = metrics.transition_probabilities(intensity_classes(enmo_mg, invalid, spt))
    row.update(tp_in2pa=tp[0], tp_pa2in=tp[1], nfrag_in2pa=tp[2], nfrag_pa2in=tp[3])
    return row
