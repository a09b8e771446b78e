"""GGIR part 5's behavioural classes of every epoch (``identify_levels``; rules.py cites each
line): the sleep period's sleep and wake by intensity, the waking part's unbouted intensities and
its hierarchical bouts (MVPA bouts first, longest first, then inactivity bouts, then light bouts,
each on the epochs no earlier bout took).

``levels(value, spt, sib, epoch_s, th)`` -> ``Levels``: ``level`` (class index per epoch, -1 where
the value is missing), ``total`` (1-4: waking inactive / light / moderate / vigorous, 0 elsewhere:
GGIR's OLEVELS), ``names`` (GGIR's class names, in index order) and ``bouts`` (one boolean array
per bout class: the epochs g.getbout put in that class's bouts, GGIR's ``bc.mvpa`` / ``bc.in`` /
``bc.lig`` rows, whose runs GGIR counts as bouts).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..outcomes.bouts import ggir_bouts
from . import rules

SPT_NAMES = ("spt_sleep", "spt_wake_IN", "spt_wake_LIG", "spt_wake_MOD", "spt_wake_VIG")
UNBOUTED_NAMES = ("day_IN_unbt", "day_LIG_unbt", "day_MOD_unbt", "day_VIG_unbt")
TOTAL_NAMES = ("IN", "LIG", "MOD", "VIG")


def bout_class_names(kind: str, minutes) -> list:
    """GGIR's names of one bout kind's classes, longest first: day_MVPA_bts_10, day_MVPA_bts_5_10,
    day_MVPA_bts_1_5 (identify_level.R:57-62)."""
    m = sorted(minutes, reverse=True)
    return [f"day_{kind}_bts_{m[0]:g}"] + [f"day_{kind}_bts_{m[i]:g}_{m[i - 1]:g}"
                                            for i in range(1, len(m))]


def class_names() -> list:
    out = list(SPT_NAMES) + list(UNBOUTED_NAMES)
    for kind, (minutes, _) in rules.BOUT_CLASSES.items():
        out += bout_class_names(kind, minutes)
    return out


@dataclass(frozen=True)
class Levels:
    level: np.ndarray  # int16 class index, -1: value missing
    total: np.ndarray  # int8 0-4
    names: tuple
    bouts: dict  # class name -> bool array


def levels(value, spt, sib, epoch_s: float, th) -> Levels:
    """``th``: (light, moderate, vigorous) lower edges (light None: no light band; vigorous None:
    no vigorous band). ``value`` NaN: the epoch is in no class and marks no bout."""
    v = np.asarray(value, np.float64)
    spt = np.asarray(spt, bool)
    sib = np.asarray(sib, bool)
    lig, mod, vig = th
    lig = mod if lig is None else lig
    vig = np.inf if vig is None else vig
    ok = np.isfinite(v)
    n = v.shape[0]
    band = np.full(n, 3, np.int8)  # the first edge the value is under, as nested np.where
    with np.errstate(invalid="ignore"):
        band[v < vig] = 2
        band[v < mod] = 1
        band[v < lig] = 0
    level = np.full(n, -1, np.int16)
    day = ~spt
    level[spt & ~sib & ok] = 1 + band[spt & ~sib & ok]   # spt_wake_IN .. VIG
    level[spt & sib] = 0  # spt_sleep (by the SIB, whatever the value)
    level[day & ok] = 5 + band[day & ok]  # day_*_unbt
    total = np.zeros(n, np.int8)
    total[day & ok] = 1 + band[day & ok]
    epm = max(1, int(round(60.0 / epoch_s)))
    taken = np.zeros(n, bool)  # GGIR's refe > 0
    bouts = {}
    cls = len(SPT_NAMES) + len(UNBOUTED_NAMES)
    with np.errstate(invalid="ignore"):
        marks = {"MVPA": ok & (v >= mod), "IN": ok & (v < lig), "LIG": ok & (v >= lig) & (v < mod)}
    for kind, (minutes, criterion) in rules.BOUT_CLASSES.items():
        for name, m in zip(bout_class_names(kind, minutes), sorted(minutes, reverse=True)):
            x = marks[kind] & ~taken & day
            b = ggir_bouts(x, int(round(m * 60.0 / epoch_s)), epm, criterion)
            level[day & b & ok] = cls
            bouts[name] = b
            taken |= b
            cls += 1
    return Levels(level, total, tuple(class_names()), bouts)
