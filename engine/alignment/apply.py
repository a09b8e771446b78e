"""Resample the other device onto the reference clock with a fitted clock model (pass 2).

For every point ``t`` of a uniform output grid on the reference clock, the other device's clock
reads ``u = t + offset(t)``; its acceleration at ``u`` is interpolated from its own samples:

* ``previous`` (the paper's default): the last sample at or before u (keeps amplitudes, so ENMO
  and MAD of the aligned stream equal the original's);
* ``linear``;
* ``cubic``: 4-point Lagrange on the samples' actual times (for activity-type analyses).

Streaming: the other source is read block by block; a small tail of samples is kept (more when
the model has a backward step, whose data the clock maps twice). Grid points with no sample within
the gap tolerance, before/after the other recording, or inside a step's uncertainty window are
NaN: nothing is imputed.
"""

from __future__ import annotations

from typing import Iterator, Optional

import numpy as np

from .fit import ClockFit
from .signal import GAP_FACTOR

INTERPOLATIONS = ("previous", "linear", "cubic")
MAX_OUT = 1 << 16  # output points per chunk


def _interp(u: np.ndarray, t: np.ndarray, a: np.ndarray, kind: str, gap_s: float) -> np.ndarray:
    """Interpolate samples (t, a (n, c)) at u (inside [t[0], t[-1]])."""
    n = t.size
    j = np.clip(np.searchsorted(t, u, side="right") - 1, 0, n - 1)  # t[j] <= u
    jn = np.minimum(j + 1, n - 1)
    exact = t[j] == u
    gap = ((t[jn] - t[j]) > gap_s) & ~exact
    if kind == "previous":
        out = a[j].astype(np.float64)
    elif kind == "linear":
        span = t[jn] - t[j]
        w = np.where(span > 0, (u - t[j]) / np.where(span > 0, span, 1.0), 0.0)
        out = a[j] * (1 - w)[:, None] + a[jn] * w[:, None]
    elif kind == "cubic":
        # support t[j-1..j+2], shifted inwards at the ends of the buffer
        first = np.clip(j - 1, 0, max(n - 4, 0))
        idx = np.minimum(first[:, None] + np.arange(4)[None, :], n - 1)
        tt = t[idx]
        ok = np.all(np.diff(tt, axis=1) > 0, axis=1)
        w = np.ones((u.size, 4))
        for m in range(4):
            for k in range(4):
                if k != m:
                    den = np.where(ok, tt[:, m] - tt[:, k], 1.0)
                    w[:, m] *= (u - tt[:, k]) / den
        out = np.einsum("pk,pkc->pc", w, a[idx])
        if not ok.all():  # fewer than 4 samples: linear
            out[~ok] = _interp(u[~ok], t, a, "linear", gap_s)
        # a gap among the 4 support points also invalidates the point
        gap |= np.any(np.diff(tt, axis=1) > gap_s, axis=1) & ~exact
    else:
        raise ValueError(f"interpolation must be one of {INTERPOLATIONS}")
    out[gap] = np.nan
    return out


def aligned_chunks(other, fit: ClockFit, t0_ns: int, out_rate: Optional[float] = None,
                   interpolation: str = "previous", start_s: float = 0.0,
                   end_s: Optional[float] = None, nan_in_steps: bool = True
                   ) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """Yield (time_ns on the reference clock, accel_g (k, 3) float64) chunks of the other device
    resampled onto the grid ``t0_ns + start_s + i / out_rate`` (default rate: the other
    device's nominal rate). ``other`` is a fresh Source of the other recording."""
    if interpolation not in INTERPOLATIONS:
        raise ValueError(f"interpolation must be one of {INTERPOLATIONS}")
    rate = float(out_rate or other.info.sample_rate_nominal)
    gap_s = GAP_FACTOR / float(other.info.sample_rate_nominal)
    back = max([0.0] + [-s.size / fit.rate for s in fit.steps])  # backward steps (s)
    keep_s = back + 4.0 / other.info.sample_rate_nominal + 1.0
    windows = [s.window_s for s in fit.steps] if nan_in_steps else []
    tb = np.zeros(0)
    ab = np.zeros((0, 3))
    k_next: Optional[int] = None

    def emit(limit_u: float):
        nonlocal k_next, tb, ab
        if tb.size == 0:
            return
        if k_next is None:
            # first grid point whose u reaches the first sample (u ~ t + offset)
            t_guess = tb[0] - float(fit.offset_s(tb[0]))
            t_guess = tb[0] - float(fit.offset_s(t_guess))
            k_next = max(int(np.floor((max(t_guess, start_s) - start_s) * rate)) - 2, 0)
        while True:
            k = k_next + np.arange(MAX_OUT)
            t = start_s + k / rate
            if end_s is not None:
                t = t[t <= end_s]
            if t.size == 0:
                return
            u = t + fit.offset_s(t)
            over = np.nonzero(u > limit_u)[0]
            m = over[0] if over.size else t.size
            if m == 0:
                return
            t, u = t[:m], u[:m]
            lead = u < tb[0]
            vals = _interp(np.clip(u, tb[0], tb[-1]), tb, ab, interpolation, gap_s)
            vals[lead | (u > tb[-1])] = np.nan
            for lo, hi in windows:
                vals[(t >= lo) & (t <= hi)] = np.nan
            k_next += m
            # keep samples the next grid points may still need
            if k_next is not None:
                t_n = start_s + k_next / rate
                u_n = t_n + float(fit.offset_s(t_n))
                cut = np.searchsorted(tb, u_n - keep_s) - 4
                if cut > 0:
                    tb, ab = tb[cut:], ab[cut:]
            good = ~np.isnan(vals[:, 0])
            if good.any():
                yield (t0_ns + np.round(t * 1e9).astype(np.int64), vals)
            if over.size:
                return

    margin = 2 if interpolation == "cubic" else 0
    for blk in other:
        if blk.n == 0:
            continue
        t = (blk.time_ns - t0_ns).astype(np.float64) * 1e-9
        a = blk.accel_g()
        if tb.size:
            ok = t > tb[-1]
            t, a = t[ok], a[ok]
        tb = np.concatenate([tb, t])
        ab = np.concatenate([ab, a])
        if tb.size > margin + 1:
            yield from emit(tb[-1 - margin])
    yield from emit(tb[-1] if tb.size else -np.inf)
