"""The rest-activity rhythm metrics as pure functions on a recording's series (rules.py cites
each rule's source).

* ``cosinor_input``: GGIR's ``apply_cosinor_IS_IV_Analyses`` series: invalid epochs missing, one
  hour of missing values after 02:00 on the first day whose midnights are not 24 h apart, the
  start trimmed to the first valid epoch, minute means of 12 consecutive epochs from there, and
  the hours from the first valid epoch to the next midnight (``time_offset_h``);
* ``ivis``: GGIR's ``g.IVIS`` (binarised at the light threshold, hourly means, IS, IV, phi);
* ``cosinor``: ActCR's ``ActCosinor`` and ``ActExtendCosinor`` as GGIR's
  ``cosinor_IS_IV_Analyses`` calls them (log(mg + 1), acrophase moved by the time offset, R2);
* ``relative_amplitude``: (M10 - L5) / (M10 + L5);
* ``sleep_regularity``: GGIR's ``CalcSleepRegularityIndex`` per day pair;
* ``transition_probabilities``: GGIR's ``g.fragmentation`` ``TransProb`` between inactive and
  active runs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from ..tables.days import relative_amplitude  # noqa: F401  (one definition, used here)
from . import rules


# ---------------------------------------------------------------------------- the series
@dataclass
class CosinorInput:
    minutes: np.ndarray  # minute means (NaN: no valid epoch in the minute), from the first valid
    time_offset_h: Optional[float]
    enough: bool  # more than 24 h of valid epochs (GGIR fits nothing otherwise)


def dst_insert_at(midnights: np.ndarray, per_day: int) -> Optional[int]:
    """Where GGIR inserts an hour of missing values (0-based position, inserted before it): after
    02:00 (plus one epoch) on the first day whose midnights are not ``per_day`` epochs apart."""
    m = np.asarray(midnights, np.int64)
    gap = np.flatnonzero(np.diff(m) != per_day)
    if not gap.shape[0]:
        return None
    return int(m[gap[0]]) + 1 + 2 * per_day // 24


def cosinor_input(values: np.ndarray, invalid: np.ndarray, midnights, epoch_s: float) -> CosinorInput:
    """The minute series GGIR fits (``values`` per epoch, ``invalid`` per epoch, ``midnights``:
    0-based indices of the epochs that start at local midnight)."""
    per_day = int(round(86400 / epoch_s))
    per_h = per_day // 24
    x = np.where(np.asarray(invalid, bool), np.nan, np.asarray(values, np.float64))
    q = np.asarray(invalid, bool).astype(np.float64)
    at = dst_insert_at(midnights, per_day)
    if at is not None and at < x.shape[0]:
        x = np.concatenate([x[:at], np.full(per_h, np.nan), x[at:]])
        q = np.concatenate([q[:at], np.full(per_h, np.nan), q[at:]])
    first = 0
    if (q == 1).any():
        ok = np.flatnonzero(q == 0)
        if ok.shape[0] and ok[0] != 0:
            first = int(ok[0])
            x = x[first:]
    enough = int(np.isfinite(x).sum()) > per_day
    m = np.asarray(midnights, np.int64)
    after = m[m >= first]
    offset = (float(after[0] - first) / per_h) if after.shape[0] else None
    k = max(1, int(round(60 / epoch_s)))
    n = x.shape[0]
    pad = (-n) % k
    xx = np.concatenate([x, np.full(pad, np.nan)]).reshape(-1, k)
    cnt = np.isfinite(xx).sum(axis=1)
    sums = np.nansum(xx, axis=1)
    minutes = np.where(cnt > 0, sums / np.maximum(cnt, 1), np.nan)
    return CosinorInput(minutes, offset, enough)


def whole_days(minutes: np.ndarray) -> np.ndarray:
    """GGIR: whole days only, then trailing days without data dropped."""
    n = rules.MINUTES_PER_DAY
    x = minutes[:n * (minutes.shape[0] // n)]
    while x.shape[0] >= n and not np.isfinite(x[-n:]).any():
        x = x[:-n]
    return x


def to_mg(x: np.ndarray) -> np.ndarray:
    """GGIR's unit guess: a series whose maximum is below 13 and mean below 1 is taken as g."""
    ok = np.isfinite(x)
    if ok.any() and np.max(x[ok]) < 13 and np.mean(x[ok]) < 1:
        x = np.where(ok, x * 1000.0, np.nan)
    return x


# ---------------------------------------------------------------------------- IS / IV / phi
@dataclass
class Ivis:
    interdaily_stability: Optional[float]
    intradaily_variability: Optional[float]
    phi: Optional[float]


def hourly(x: np.ndarray, epoch_s: float = 60.0) -> np.ndarray:
    """Means over consecutive hours from the first value, missing values left out (NaN when an
    hour has none)."""
    k = int(round(3600 / epoch_s))
    n = x.shape[0]
    xx = np.concatenate([x, np.full((-n) % k, np.nan)]).reshape(-1, k)
    cnt = np.isfinite(xx).sum(axis=1)
    return np.where(cnt > 0, np.nansum(xx, axis=1) / np.maximum(cnt, 1), np.nan)


def ivis(x: np.ndarray, epoch_s: float = 60.0, threshold: Optional[float] = rules.LIGHT_MG) -> Ivis:
    """GGIR's ``g.IVIS`` on a series (mg, NaN missing)."""
    x = np.asarray(x, np.float64)
    if threshold is not None:
        x = np.where(np.isfinite(x), np.where(x > threshold, 0.0, 1.0), np.nan)
    xi = hourly(x, epoch_s) if epoch_s < 3600 else x
    if xi.shape[0] <= 1:
        return Ivis(None, None, None)
    hour = np.arange(xi.shape[0]) % 24
    ok = np.isfinite(xi)
    xh = np.array([xi[ok & (hour == h)].mean() for h in range(24) if (ok & (hour == h)).any()])
    xm = float(np.mean(xh))
    n = int(ok.sum())
    dev = np.sum((xi[ok] - xm) ** 2)
    d = np.diff(xi)
    is_ = float(np.sum((xh - xm) ** 2) * n / (24 * dev)) if dev else None
    iv = float(np.sum(d[np.isfinite(d)] ** 2) * n / ((n - 1) * dev)) if dev and n > 1 else None
    return Ivis(is_, iv, ar1_phi(xi[ok]))


def ar1_phi(y: np.ndarray) -> Optional[float]:
    """The AR(1) coefficient by exact Gaussian maximum likelihood with a mean (R's
    ``arima(order = c(1, 0, 0))``; R finds the same optimum numerically, to its tolerance)."""
    y = np.asarray(y, np.float64)
    n = y.shape[0]
    if n < 3 or np.ptp(y) == 0:
        return None
    from scipy.optimize import minimize  # ~0.35 s of imports: only when there is a fit to do

    def nll(p):
        phi, mu = math.tanh(p[0]), p[1]
        e = y - mu
        s = (1 - phi * phi) * e[0] ** 2 + np.sum((e[1:] - phi * e[:-1]) ** 2)
        return 0.5 * n * math.log(s / n) - 0.5 * math.log(1 - phi * phi)

    e = y - y.mean()
    r1 = float(np.sum(e[1:] * e[:-1]) / np.sum(e * e))
    best = minimize(nll, [math.atanh(max(min(r1, 0.99), -0.99)), float(y.mean())],
                    method="Nelder-Mead", options={"xatol": 1e-12, "fatol": 1e-14, "maxiter": 20000})
    best = minimize(nll, best.x, method="BFGS", options={"gtol": 1e-10})
    return float(math.tanh(best.x[0]))


# ---------------------------------------------------------------------------- cosinor
@dataclass
class Cosinor:
    mesor: Optional[float] = None
    amplitude: Optional[float] = None
    acrophase_rad: Optional[float] = None
    acrophase_h: Optional[float] = None
    r2: Optional[float] = None
    ndays: Optional[float] = None
    ext_minimum: Optional[float] = None
    ext_amplitude: Optional[float] = None
    ext_alpha: Optional[float] = None
    ext_beta: Optional[float] = None
    ext_acrophase_h: Optional[float] = None
    ext_f_pseudo: Optional[float] = None
    ext_up_mesor_h: Optional[float] = None
    ext_down_mesor_h: Optional[float] = None
    ext_mesor: Optional[float] = None
    ext_r2: Optional[float] = None
    ivis: Ivis = field(default_factory=lambda: Ivis(None, None, None))
    time_offset_h: Optional[float] = None


def _correct_acrophase(b: float, g: float) -> float:
    """cosinor2's ``correct.acrophase`` from the cos (b) and sin (g) coefficients."""
    a = math.atan(abs(g / b))
    if b > 0 and g > 0:
        return -a
    if b > 0 and g < 0:
        return -2 * math.pi + a
    if b < 0 and g > 0:
        return -math.pi + a
    return -math.pi - a


def _ext_model(p, t):
    """min + amp * exp(u) / (1 + exp(u)), u = beta (cos(2 pi (t - phi) / 24) - alpha); the
    logistic as ``expit`` (equal where exp(u) is finite, and finite where it is not)."""
    from scipy.special import expit
    ct = np.cos((t - p[4]) * 2 * np.pi / 24)
    return p[0] + p[1] * expit(p[3] * (ct - p[2]))


def _add24ifneg(x: float) -> float:
    return x + 24 if x < 0 else x


def cosinor(minutes: np.ndarray, time_offset_h: float, threshold: Optional[float] = rules.LIGHT_MG
            ) -> Cosinor:
    """GGIR's ``cosinor_IS_IV_Analyses`` on the minute series of ``cosinor_input``."""
    x = to_mg(whole_days(np.asarray(minutes, np.float64)))
    out = Cosinor(time_offset_h=time_offset_h)
    n = rules.MINUTES_PER_DAY
    if x.shape[0] < n:
        return out
    from scipy.optimize import least_squares  # ~0.35 s of imports: only when there is a fit to do
    ok = np.isfinite(x)
    y = np.log(x[ok] + 1)
    t = (np.tile(np.arange(1, n + 1), x.shape[0] // n) / 60.0)[ok]
    X = np.column_stack([np.ones(t.shape[0]), np.cos(2 * np.pi * t / 24), np.sin(2 * np.pi * t / 24)])
    beta, *_ = np.linalg.lstsq(X, y, rcond=None)
    fitted = X @ beta
    mesor, b, g = (float(v) for v in beta)
    amp = math.hypot(b, g)
    acr = _correct_acrophase(b, g)
    acrotime = -acr * 24 / (2 * math.pi)
    p0 = [max(mesor - amp, 0.0), 2 * amp, 0.0, 2.0, acrotime]
    lo, hi = np.array(rules.EXT_LOWER), np.array(rules.EXT_UPPER)
    p0 = np.clip(p0, lo, hi)
    try:
        fit = least_squares(lambda p: y - _ext_model(p, t), p0, bounds=(lo, hi), method="trf",
                            xtol=1e-15, ftol=1e-15, gtol=1e-15, max_nfev=20000)
        p = fit.x
    except ValueError:  # a fit that leaves the finite numbers: no extended cosinor
        p = np.full(5, np.nan)
    fext = _ext_model(p, t)
    rss_cos = float(np.sum((y - fitted) ** 2))
    rss_ext = float(np.sum((y - fext) ** 2))
    off = time_offset_h
    out.ndays = x.shape[0] / n
    out.mesor, out.amplitude = mesor, amp
    out.acrophase_h = _add24ifneg(acrotime - off)
    a = abs(acr) - (off / 24) * 2 * math.pi
    k = math.ceil(abs(a) / (2 * math.pi))
    out.acrophase_rad = a + k * 2 * math.pi if a < 0 else a
    out.r2 = float(np.corrcoef(y, fitted)[0, 1] ** 2)
    out.ivis = ivis(x, 60.0, threshold)
    if not np.isfinite(p).all():
        return out
    out.ext_minimum, out.ext_amplitude, out.ext_alpha, out.ext_beta = (float(v) for v in p[:4])
    out.ext_acrophase_h = _add24ifneg(float(p[4]) - off)
    out.ext_f_pseudo = ((rss_cos - rss_ext) / 2) / (rss_ext / (y.shape[0] - 5))
    spread = math.acos(float(p[2])) / (2 * math.pi / 24)
    out.ext_up_mesor_h = _add24ifneg(-spread + float(p[4]) - off)
    out.ext_down_mesor_h = _add24ifneg(spread + float(p[4]) - off)
    out.ext_mesor = float(p[0] + p[1] / 2)
    out.ext_r2 = float(np.corrcoef(y, fext)[0, 1] ** 2)
    return out


# ---------------------------------------------------------------------------- M10 / L5 / RA
def average_day_mx(profile: np.ndarray, first_midnight: int, epoch_s: float, hours: float,
                   pick) -> tuple:
    """GGIR's M10 / L5 of the average day (``g.analyse.avday``: the average day turned to start
    at the first midnight, ``g.getM5L5`` windows). Returns (value, start hour)."""
    p = np.concatenate([profile[first_midnight:], profile[:first_midnight]])
    w = int(round(hours * 3600 / epoch_s))
    step = int(round(rules.M_STEP_S / epoch_s))
    starts = np.arange(0, int((24 - hours) * 3600 / rules.M_STEP_S)) * step
    c = np.concatenate([[0.0], np.cumsum(p)])
    means = (c[starts + w] - c[starts]) / w
    i = int(pick(means))
    return float(means[i]), float(starts[i] * epoch_s / 3600)


# ---------------------------------------------------------------------------- SRI
def sleep_regularity(state: np.ndarray, invalid: np.ndarray, t_utc_s: np.ndarray,
                     offsets_s: np.ndarray, epoch_s: float) -> list:
    """GGIR's ``CalcSleepRegularityIndex`` (part 3, on the SIBs): invalid epochs missing, 30-s
    means rounded (half to even, as R), each local date laid on its seconds of the day, then per
    pair of consecutive dates -100 + 200 x the share of slots in the same state among those
    valid on both. Returns [(date, sri or None, frac_valid)] for each pair after the first date
    with a following one (GGIR needs three dates or more)."""
    s = np.where(np.asarray(invalid, bool), np.nan, np.asarray(state, np.float64))
    t = np.asarray(t_utc_s, np.int64)
    if epoch_s < 30 and (30 / epoch_s) == round(30 / epoch_s):
        key = (t // 30) * 30
        if bool(np.all(t[1:] > t[:-1])):  # starts increasing: each 30 s is a run, no sort
            at = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
            uk = key[at]
            sums = np.add.reduceat(np.nan_to_num(s), at)
            nan = np.logical_or.reduceat(np.isnan(s), at)
            cnt = np.diff(np.r_[at, key.shape[0]])
        else:
            uk, inv = np.unique(key, return_inverse=True)
            sums = np.bincount(inv, weights=np.nan_to_num(s))
            nan = np.bincount(inv, weights=np.isnan(s).astype(float)) > 0
            cnt = np.bincount(inv)
            at = np.searchsorted(t, uk)
        vals = np.where(nan, np.nan, np.round(sums / cnt))
        tt = uk
        off = np.asarray(offsets_s, np.int64)[at]
        step, m_slots = 30, 2880
    else:
        vals, tt, off = s, t, np.asarray(offsets_s, np.int64)
        step, m_slots = int(epoch_s), int(86400 // epoch_s)
    local = tt + off
    date = local // 86400
    sec = local % 86400
    dates = np.unique(date)
    max_sec = int(sec.max())
    slots = np.arange(0, max_sec + 1, step)
    ne24, ne23, ne25 = 86400 // step, 23 * 3600 // step, 25 * 3600 // step
    days = []
    for d in dates:
        sel = date == d
        ds, dv = sec[sel], vals[sel]
        order = np.argsort(ds, kind="stable")
        ds, dv = ds[order], dv[order]
        # merge(all = TRUE) with every slot: slots without a row get one (NaN)
        miss = np.setdiff1d(slots, ds)
        allsec = np.concatenate([ds, miss])
        allv = np.concatenate([dv, np.full(miss.shape[0], np.nan)])
        o = np.argsort(allsec, kind="stable")
        allsec, allv = allsec[o], allv[o]
        days.append(allv[allsec < 86400])
    out = []
    if len(dates) - 1 <= 1:
        return out
    for i in range(len(dates) - 1):
        a, b = days[i], days[i + 1]
        if a.shape[0] == ne25:
            a = a[:ne24]
        if b.shape[0] == ne25:
            b = b[:ne24]
        if a.shape[0] == ne23:
            b = b[:ne23]
        if b.shape[0] == ne23:
            a = a[:ne23]
        k = min(a.shape[0], b.shape[0])
        a, b = a[:k], b[:k]
        na = np.isnan(a) | np.isnan(b)
        skipped = int(na.sum())
        same = int((a[~na] == b[~na]).sum())
        frac = round((m_slots - skipped) / m_slots, 4)
        sri = round(-100 + (200 / (m_slots - skipped)) * same, 3) if m_slots != skipped else 0.0
        iso = str(np.datetime64(int(dates[i]), "D"))
        out.append((iso, sri, frac))
    return out


# ---------------------------------------------------------------------------- fragmentation
def _runs(x: np.ndarray):
    """R's ``rle`` of a float series: (values, lengths); a comparison with NA breaks, so every
    NaN is its own run."""
    brk = np.ones(x.shape[0], bool)
    brk[1:] = ~((x[1:] == x[:-1]) & np.isfinite(x[1:]))
    starts = np.flatnonzero(brk)
    return x[starts], np.diff(np.append(starts, x.shape[0]))


def trans_prob(classes: np.ndarray, a=(1,), b=(2, 3)) -> dict:
    """GGIR's ``TransProb`` (R/g.fragmentation.R:21-92) from the runs of classes in ``a`` to those
    in ``b`` and back, on one series of class ids (NaN: left out, splitting it). Keys as GGIR's:
    TPab, TPba, Nab, Nba, totDur_ab and totDur_ba (with more than one run: the epochs of the
    ``a`` runs followed by a ``b`` run, and back)."""
    x = np.asarray(classes, np.float64)
    out = {"TPab": None, "TPba": None, "Nab": 0, "Nba": 0, "totDur_ab": 0, "totDur_ba": 0}
    if x.shape[0] == 0:
        return out
    vals, lens = _runs(x)
    ns = vals.shape[0]
    ina, inb = np.isin(vals, a), np.isin(vals, b)
    if ns == 1:
        if ina[0]:
            out.update(TPab=0.0, TPba=1.0, totDur_ab=int(lens[0]), Nab=1)
        else:
            out.update(TPab=1.0, TPba=0.0, totDur_ba=int(lens[0]), Nba=1)
        return out
    ab = ina[:-1] & inb[1:]
    ba = inb[:-1] & ina[1:]
    nab, nba = int(ab.sum()), int(ba.sum())
    last = set(np.flatnonzero(np.isfinite(vals[:-1]) & np.isnan(vals[1:])).tolist())
    if np.isfinite(vals[-1]):
        last.add(ns - 1)
    last = sorted(last)
    rest = np.delete(vals, last)
    if last and int(np.isfinite(rest).sum()) > 1:
        ca, cb = int(ina[last].sum()), int(inb[last].sum())
    else:
        ca = cb = 0
    da = int(lens[ina].sum()) - ca
    db = int(lens[inb].sum()) - cb
    eps = 1e-6
    out.update(TPab=round((nab + eps) / (da + eps), 6), TPba=round((nba + eps) / (db + eps), 6),
               Nab=nab, Nba=nba, totDur_ab=int(lens[:-1][ab].sum()),
               totDur_ba=int(lens[:-1][ba].sum()))
    return out


def transition_probabilities(classes: np.ndarray, a=(1,), b=(2, 3)) -> tuple:
    """(TP a->b, TP b->a, N a->b, N b->a) of ``trans_prob``."""
    t = trans_prob(classes, a, b)
    return t["TPab"], t["TPba"], t["Nab"], t["Nba"]


def _ratio(n, d):
    """n / d; None where R gives NaN or Inf (d = 0)."""
    if d is None or n is None or d == 0:
        return None
    return n / d


def gini(x: np.ndarray):
    """``ineq::Gini(x, corr = TRUE)`` (ineq 0.2-13, R/ineq.R) as GGIR calls it: sorted values,
    (2 sum(i x_i) / sum(x) - (n + 1)) / (n - 1)."""
    x = np.sort(np.asarray(x, np.float64))
    n = x.shape[0]
    if n < 2 or x.sum() == 0:
        return None
    g = 2.0 * float(np.sum(x * np.arange(1, n + 1))) / float(x.sum()) - (n + 1)
    return g / (n - 1)


def _sd(x: np.ndarray):
    return float(np.std(x, ddof=1)) if x.shape[0] > 1 else None


FRAG_DAY = ("TP_IN2PA", "TP_PA2IN", "Nfrag_IN2PA", "Nfrag_PA2IN", "TP_IN2LIPA", "Nfrag_IN2LIPA",
            "TP_IN2MVPA", "Nfrag_IN2MVPA", "Nfrag_LIPA", "mean_dur_LIPA", "Nfrag_MVPA",
            "mean_dur_MVPA", "Nfrag_PA", "Nfrag_IN", "mean_dur_PA", "mean_dur_IN", "Gini_dur_PA",
            "Gini_dur_IN", "CoV_dur_PA", "CoV_dur_IN", "alpha_dur_PA", "alpha_dur_IN",
            "x0.5_dur_PA", "x0.5_dur_IN", "W0.5_dur_PA", "W0.5_dur_IN", "SD_dur_PA", "SD_dur_IN",
            "NFragPM_PA", "NFragPM_IN")
FRAG_SPT = ("Nfrag_IN", "Nfrag_PA", "TP_IN2PA", "TP_PA2IN", "Nfrag_sleep", "Nfrag_wake",
            "TP_sleep2wake", "TP_wake2sleep")


def fragmentation_day(classes: np.ndarray, xmin: float) -> dict:
    """GGIR's ``g.fragmentation`` in "day" mode with every metric (frag.metrics "all",
    R/g.fragmentation.R:94-235) on the waking classes (1 inactivity, 2 light, 3 MVPA, NaN:
    missing or in the sleep period): GGIR's names (``FRAG_DAY``) -> value. Durations are in
    epochs; ``xmin``: epochs in a minute (the power law's shortest fragment)."""
    y = np.asarray(classes, np.float64)
    o: dict = {k: None for k in FRAG_DAY}
    n = y.shape[0]
    if n > 1:
        t = trans_prob(y, (1,), (2, 3))
        o.update(TP_IN2PA=t["TPab"], TP_PA2IN=t["TPba"], Nfrag_IN2PA=t["Nab"], Nfrag_PA2IN=t["Nba"])
        t = trans_prob(y, (1,), (2,))
        o.update(TP_IN2LIPA=t["TPab"], Nfrag_IN2LIPA=t["Nab"])
        t = trans_prob(y, (1,), (3,))
        o.update(TP_IN2MVPA=t["TPab"], Nfrag_IN2MVPA=t["Nab"])
        t = trans_prob(y, (2,), (1, 3))
        o.update(Nfrag_LIPA=t["Nab"], mean_dur_LIPA=_ratio(t["totDur_ab"], t["Nab"]))
        t = trans_prob(y, (3,), (1, 2))
        o.update(Nfrag_MVPA=t["Nab"], mean_dur_MVPA=_ratio(t["totDur_ab"], t["Nab"]))
    # the binary series: inactivity (1) or not (0)
    x = np.where(np.isnan(y), np.nan, np.where(y == 1, 1.0, 0.0))
    vals, lens = _runs(x) if n else (np.zeros(0), np.zeros(0, np.int64))
    nfrag = int(np.isfinite(vals).sum())
    t = trans_prob(x, (1,), (0,))
    o.update(Nfrag_PA=t["Nba"], Nfrag_IN=t["Nab"], mean_dur_PA=0.0, mean_dur_IN=0.0,
             NFragPM_PA=0.0, NFragPM_IN=0.0)
    if nfrag > 1:
        o["mean_dur_PA"] = _ratio(t["totDur_ba"], t["Nba"])
        o["mean_dur_IN"] = _ratio(t["totDur_ab"], t["Nab"])
        o["NFragPM_PA"] = _ratio(o["Nfrag_PA"], t["totDur_ba"])
        o["NFragPM_IN"] = _ratio(o["Nfrag_IN"], t["totDur_ab"])
        if nfrag >= 10:  # R/g.fragmentation.R:199-234
            for key, v in (("PA", 0.0), ("IN", 1.0)):
                d = lens[vals == v].astype(np.float64)
                sd = _sd(d)
                o[f"SD_dur_{key}"] = sd
                o[f"Gini_dur_{key}"] = gini(d)
                lg = np.log(d)
                o[f"CoV_dur_{key}"] = _ratio(_sd(lg), float(lg.mean()) if lg.shape[0] else None)
                if sd is not None and sd != 0:
                    alpha = 1.0 + d.shape[0] / float(np.sum(np.log(d / xmin)))
                    x05 = 2.0 ** (1.0 / (alpha - 1.0) * xmin)
                    o[f"alpha_dur_{key}"] = alpha
                    o[f"x0.5_dur_{key}"] = x05
                    o[f"W0.5_dur_{key}"] = float(d[d > x05].sum() / d.sum())
    return o


def fragmentation_spt(pa: np.ndarray, wake: np.ndarray, missing: np.ndarray) -> dict:
    """GGIR's ``g.fragmentation`` in "spt" mode (R/g.fragmentation.R:236-267) on the sleep
    period's epochs (``missing``: the waking part and invalid epochs): rest (0) against activity
    (1: awake at light or more), and sleep (0) against wake (1). GGIR's names (``FRAG_SPT``)."""
    o = {}
    for (na, nb, ta, tb), flag in ((("Nfrag_IN", "Nfrag_PA", "TP_IN2PA", "TP_PA2IN"), pa),
                                   (("Nfrag_sleep", "Nfrag_wake", "TP_sleep2wake", "TP_wake2sleep"),
                                    wake)):
        x = np.where(np.asarray(missing, bool), np.nan, np.asarray(flag, bool).astype(np.float64))
        t = trans_prob(x, (0,), (1,))
        o.update({na: t["Nab"], nb: t["Nba"], ta: t["TPab"], tb: t["TPba"]})
    return o
