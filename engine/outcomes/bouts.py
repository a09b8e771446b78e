"""GGIR's bout rule (``g.getbout``, wadpac/GGIR ``R/g.getbout.R`` @388064b7), on one day's epochs.

``x`` marks the epochs that meet a band's condition. With ``L`` the bout length in epochs and
``e = 60 / epoch_s`` epochs per minute:

1. breaks (lines 5-17): an epoch whose centred window of ``e + 1`` epochs holds no marked epoch
   (inside a pause of more than a minute) counts ``-L``, so no bout can span it;
2. windows (lines 18-24): the centred mean over ``L`` epochs, the input padded with ``-L`` beyond
   its ends, is at least ``criterion`` (GGIR's ``boutcriter``, 0.8: a fifth of a bout may be below
   the threshold);
3. extent (lines 28-88): each run of window centres becomes a bout from ``floor(L/2)`` epochs
   before its first centre to ``floor(L/2)`` after its last, each end pulled in to the nearest
   marked epoch; runs are taken in order, and a start inside the previous bout moves to the first
   marked epoch after that bout (so two close bouts can leave a pause between them unmarked).

The centred windows follow ``zoo::rollmean(align = "center")``: a window of ``k`` epochs at ``i``
spans ``i - (floor((k+1)/2) - 1)`` to ``i + k - floor((k+1)/2)``. GGIR applies the rule per day
(``g.analyse.perday.R`` lines 647-668: ``mvpadur`` 1, 5, 10 min, ``boutcriter`` 0.8); so do we.
"""

from __future__ import annotations

import numpy as np

BOUT_CRITERION = 0.8  # GGIR params_phyact boutcriter default


def _centred_sums(v: np.ndarray, k: int) -> np.ndarray:
    """Sum over the ``zoo`` centred window of ``k`` at every index; 0 where it does not fit."""
    n = v.shape[0]
    left = (k + 1) // 2 - 1
    out = np.zeros(n, dtype=np.float64)
    if n < k:
        return out
    c = np.concatenate([[0], np.cumsum(v)])
    s = c[k:] - c[:-k]  # window starting at j
    out[left:left + s.shape[0]] = s
    return out


def quiet_pieces(x: np.ndarray, quiet: int) -> list:
    """[a, b) pieces covering ``x``, cut in the middle of every run of at least ``quiet``
    unmarked epochs."""
    m = np.flatnonzero(x)
    if not m.shape[0]:
        return [(0, x.shape[0])]
    g = np.flatnonzero(np.diff(m) - 1 >= quiet)
    edges = [0] + ((m[g] + m[g + 1] + 1) // 2).tolist() + [x.shape[0]]
    return list(zip(edges[:-1], edges[1:]))


def ggir_bouts(x: np.ndarray, bout_epochs: int, epochs_per_minute: int,
               criterion: float = BOUT_CRITERION) -> np.ndarray:
    """Epochs inside bouts (bool), GGIR's rule on the marked epochs ``x``.

    Computed piece by piece, cut inside the runs of unmarked epochs longer than twice a bout and
    a minute's break window (a sleep period, a night off): every epoch within a bout and a minute
    of such a cut is a break (GGIR's -L), as the pieces' padding is, and a bout's centre, start
    and end lie within a bout of a marked epoch, so each piece's bouts are the whole series'.
    Memory follows the longest piece, not the recording."""
    x = np.asarray(x, bool)
    n = x.shape[0]
    L = int(bout_epochs)
    if n == 0 or L < 1:
        return np.zeros(n, bool)
    pieces = quiet_pieces(x, 2 * (L + epochs_per_minute + 2))
    if len(pieces) == 1:
        return _bouts(x, L, epochs_per_minute, criterion)
    out = np.zeros(n, bool)
    for a, b in pieces:
        if x[a:b].any():
            out[a:b] = _bouts(x[a:b], L, epochs_per_minute, criterion)
    return out


def _bouts(x: np.ndarray, L: int, epochs_per_minute: int, criterion: float) -> np.ndarray:
    """ggir_bouts on one piece (``x`` bool, ``L`` >= 1)."""
    n = x.shape[0]
    xi = x.astype(np.int64)
    pad = -(-epochs_per_minute // 2)
    xp = np.concatenate([np.zeros(pad, np.int64), xi, np.zeros(pad, np.int64)])
    brk = _centred_sums(xp, epochs_per_minute + 1)[pad:pad + n] == 0
    xt = np.where(brk, -L, xi)
    app = -(-L // 2)
    xp = np.concatenate([np.full(app, -L, np.int64), xt, np.full(app, -L, np.int64)])
    rm = (_centred_sums(xp, L) / L)[app:app + n]
    if n + 2 * app < L:
        rm[:] = 0.0
    centres = np.flatnonzero(rm >= criterion)
    out = np.zeros(n, bool)
    if not centres.shape[0]:
        return out
    cut = np.flatnonzero(np.diff(centres) != 1) + 1
    first = centres[np.r_[0, cut]]
    last = centres[np.r_[cut - 1, centres.shape[0] - 1]]
    ones = xt == 1
    idx = np.arange(n)
    nxt = np.minimum.accumulate(np.where(ones, idx, n)[::-1])[::-1]  # first marked at or after
    prv = np.maximum.accumulate(np.where(ones, idx, -1))  # last marked at or before
    half = L // 2
    e = prv[np.clip(last + half, 0, n - 1)]
    # GGIR marks the bouts in order: a start that falls on the previous bout (already marked)
    # moves on to the first marked-only epoch after it
    c = np.clip(first - half, 0, n - 1)
    prev_e = np.r_[-1, e[:-1]]
    c = np.where(c <= prev_e, prev_e + 1, c)
    s = np.where(c < n, nxt[np.minimum(c, n - 1)], n)
    ok = (s < n) & (e >= 0)
    lo, hi = np.minimum(s, e)[ok], np.maximum(s, e)[ok]  # R's s:e also runs downwards
    d = np.zeros(n + 1, np.int64)
    np.add.at(d, lo, 1)
    np.add.at(d, hi + 1, -1)
    return np.cumsum(d[:-1]) > 0
