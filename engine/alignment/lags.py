"""Per-block lag between two devices: normalised cross-correlation of the Brønd activity signal
in non-overlapping blocks, with sub-sample refinement, computed incrementally.

``LagEstimator`` receives both devices' grid pieces (from ``signal.GridResampler``) in any
interleaving and emits a ``BlockLag`` as soon as a block and its margins are complete; it holds at
most one block plus margins per device. The lag of a block is the shift ``k`` (grid samples) that
maximises ``corr(ref[n], other[n + k])``: an event at reference-clock time t appears in the other
device's clock at ``t + k / rate``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from .filtering import correlate_valid
from .signal import (ACTIVITY_MIN_G, BLOCK_S, COMMON_RATE_HZ, FILTER_PAD_S, MAX_LAG_SAMPLES,
                     brond_filter)

MIN_COVERAGE = 0.5  # a block needs samples on at least half its grid points in both devices
SUB_BLOCKS = 6  # each block is also correlated in 6 sub-blocks (10 min) to locate steps


def normalized_xcorr(ref: np.ndarray, other_ext: np.ndarray, max_lag: int,
                     centred: bool = True) -> np.ndarray:
    """Normalised cross-correlation for lags -max_lag..max_lag.

    ``other_ext`` is the other device's signal over the reference window extended by ``max_lag``
    samples on both sides, so every lag is computed on a full window (no zero padding).
    ``centred=False`` gives Matlab's ``xcorr(..., 'coeff')`` normalisation (no mean removal),
    ``centred=True`` the Pearson correlation of each shifted window.
    """
    n = ref.size
    L = 2 * max_lag + 1
    if other_ext.size != n + 2 * max_lag:
        raise ValueError("other_ext must be len(ref) + 2*max_lag long")
    r = ref - ref.mean() if centred else ref
    if L <= 64:  # few lags (the fine stage): direct dot products beat an FFT of 2n
        # (not np.dot: a multithreaded BLAS dot is far slower on a loaded machine;
        # docs/performance.md#code-figures)
        num = np.array([(other_ext[j:j + n] * r).sum() for j in range(L)])
    else:
        num = correlate_valid(other_ext, r)  # scipy.signal.correlate(..., "valid", method="fft")
    c2 = np.concatenate([[0.0], np.cumsum(other_ext * other_ext)])
    ss = c2[n:n + L] - c2[:L]
    if centred:
        c1 = np.concatenate([[0.0], np.cumsum(other_ext)])
        s1 = c1[n:n + L] - c1[:L]
        ss = ss - s1 * s1 / n
    den = np.sqrt(np.maximum(ss, 0.0) * float((r * r).sum()))
    out = np.zeros(L)
    ok = den > 1e-12 * max(1.0, float(den.max()) if den.size else 1.0)
    out[ok] = num[ok] / den[ok]
    return out


def peak_lag(corr: np.ndarray, max_lag: int, subsample: bool = True) -> tuple[float, float, bool]:
    """(lag, peak correlation, at_edge): lag of the maximum, refined by a parabola through the
    peak and its neighbours when ``subsample``. ``at_edge`` when the maximum is at +-max_lag."""
    j = int(np.argmax(corr))
    peak = float(corr[j])
    at_edge = j == 0 or j == corr.size - 1
    lag = float(j - max_lag)
    if subsample and not at_edge:
        a, b, c = corr[j - 1], corr[j], corr[j + 1]
        den = a - 2.0 * b + c
        if den < 0:
            d = 0.5 * (a - c) / den
            if abs(d) <= 0.5:
                lag += d
                peak = float(b - 0.25 * (a - c) * d)
    return lag, peak, at_edge


N_CANDIDATES = 7  # highest local maxima kept per block (gait makes the peak ambiguous)
FINE_HALF_S = 5.0  # wide search: candidates are looked for within +-5 s of the coarse peak


def top_peaks(corr: np.ndarray, max_lag: int, k: int = N_CANDIDATES, subsample: bool = True
              ) -> tuple[np.ndarray, np.ndarray]:
    """Lags and heights of the k highest interior local maxima (sub-sample refined), highest
    first. Walking is nearly periodic, so the true lag is often the 2nd or 3rd peak, one step
    period (~0.5 s) away from the highest; the robust fit chooses among them by consensus."""
    c = corr
    if c.size < 3:
        return np.zeros(0), np.zeros(0)
    j = np.nonzero((c[1:-1] > c[:-2]) & (c[1:-1] >= c[2:]))[0] + 1
    if j.size == 0:
        return np.zeros(0), np.zeros(0)
    j = j[np.argsort(c[j])[::-1][:k]]
    lags = (j - max_lag).astype(np.float64)
    heights = c[j].astype(np.float64)
    if subsample:
        a, b, d = c[j - 1], c[j], c[j + 1]
        den = a - 2 * b + d
        off = np.where(den < 0, 0.5 * (a - d) / np.where(den < 0, den, -1.0), 0.0)
        off = np.clip(off, -0.5, 0.5)
        lags += off
        heights = b - 0.25 * (a - d) * off
    return lags, heights


COARSE_ABOVE = 2000  # searches wider than this many samples run coarse-to-fine
COARSE_DECIM = 6  # coarse stage: block means of 6 samples (5 Hz at 30 Hz)


def _block_means(x: np.ndarray, d: int) -> np.ndarray:
    m = x.size // d
    return x[:m * d].reshape(m, d).mean(axis=1)


def wide_lag(ref: np.ndarray, other_ext: np.ndarray, max_lag: int, centred: bool = True,
             subsample: bool = True, decim: int = COARSE_DECIM, fine_half: int = 0,
             n_candidates: int = 0):
    """Coarse-to-fine lag for wide searches: the correlation of ``decim``-sample means over
    +-max_lag finds the peak, the full-rate correlation within +-``fine_half`` samples (default
    2 coarse steps) refines it. Returns (lag, peak, at_edge, coarse correlogram, candidate lags,
    candidate heights); the coarse correlogram's step is ``decim``."""
    n = ref.size
    md = max_lag // decim
    nd = n // decim
    none = np.zeros(0)
    rd = _block_means(ref, decim)[:nd]
    od = _block_means(other_ext[max_lag - md * decim:], decim)[:nd + 2 * md]
    if od.size < nd + 2 * md or nd < 4:
        return np.nan, np.nan, True, none, none, none
    cd = normalized_xcorr(rd, od, md, centred)
    jd = int(np.argmax(cd))
    if jd == 0 or jd == cd.size - 1:
        return float((jd - md) * decim), float(cd[jd]), True, cd, none, none
    kc = (jd - md) * decim
    f = max(2 * decim, int(fine_half))
    f = min(f, max_lag // 2)
    kc = int(np.clip(kc, -max_lag + f, max_lag - f))
    seg = other_ext[max_lag + kc - f:max_lag + kc + f + n]
    c = normalized_xcorr(ref, seg, f, centred)
    lag, peak, edge = peak_lag(c, f, subsample)
    cl, ch = top_peaks(c, f, n_candidates, subsample) if n_candidates else (none, none)
    return kc + lag, peak, edge, cd, kc + cl, ch


@dataclass
class BlockLag:
    """One block's result. Times are seconds since the reference's first sample (its clock)."""

    index: int
    start_s: float
    duration_s: float
    lag: float = np.nan  # grid samples (other minus reference)
    corr: float = np.nan  # peak normalised cross-correlation
    activity_ref: float = np.nan  # mean |‖a‖-1|, g
    activity_other: float = np.nan
    coverage_ref: float = 0.0
    coverage_other: float = 0.0
    valid: bool = False
    reason: str = ""  # why not valid: no_overlap, gap, inactive, edge
    centroid_s: float = np.nan  # activity-weighted time of the block (where its lag applies)
    sub_lags: np.ndarray = field(default_factory=lambda: np.zeros(0))
    sub_corr: np.ndarray = field(default_factory=lambda: np.zeros(0))
    correlogram: Optional[np.ndarray] = None  # float32, lags -max_lag..max_lag, when kept
    correlogram_step: int = 1  # samples between correlogram points (coarse search: decimated)
    cand_lags: np.ndarray = field(default_factory=lambda: np.zeros(0))  # highest local maxima
    cand_corr: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @property
    def centre_s(self) -> float:
        return self.start_s + 0.5 * self.duration_s

    def as_dict(self, rate: float) -> dict:
        d = {"index": self.index, "start_s": round(self.start_s, 6),
             "centroid_s": None if not np.isfinite(self.centroid_s) else round(self.centroid_s, 3),
             "duration_s": round(self.duration_s, 6), "valid": self.valid,
             "coverage_ref": round(self.coverage_ref, 4),
             "coverage_other": round(self.coverage_other, 4)}
        for k in ("lag", "corr", "activity_ref", "activity_other"):
            v = getattr(self, k)
            d[k] = None if not np.isfinite(v) else round(float(v), 6)
        d["lag_s"] = None if not np.isfinite(self.lag) else round(float(self.lag) / rate, 6)
        if self.reason:
            d["reason"] = self.reason
        if self.sub_lags.size:
            d["sub_lags"] = [None if not np.isfinite(x) else round(float(x), 4)
                             for x in self.sub_lags]
        return d


class _GridBuffer:
    """Grid samples of one device from ``k_start`` on, known up to ``k_end``: pieces of data
    (increasing, not overlapping); every point not in a piece is NaN without being stored, so a
    gap of any length costs nothing."""

    def __init__(self, k_start: int):
        self.k_start = k_start
        self.k_end = k_start
        self._pieces: list[tuple[int, np.ndarray]] = []
        self.finished = False

    def append(self, k0: int, values: np.ndarray) -> None:
        if k0 < self.k_end:  # overlap with what we have (or before the start): drop it
            values = values[self.k_end - k0:]
            k0 = self.k_end
        if values.size == 0:
            return
        last = self._pieces[-1] if self._pieces else None
        if last is not None and last[0] + last[1].size == k0:
            self._pieces[-1] = (last[0], np.concatenate([last[1], values]))
        else:
            self._pieces.append((k0, values))
        self.k_end = k0 + values.size

    def has_data(self, k0: int, k1: int) -> bool:
        """Whether any stored point lies in [k0, k1) (False: all NaN there)."""
        return any(a < k1 and a + v.size > k0 for a, v in self._pieces)

    def get(self, k0: int, k1: int) -> np.ndarray:
        out = np.full(k1 - k0, np.nan)
        for a, v in self._pieces:
            lo, hi = max(k0, a), min(k1, a + v.size)
            if hi > lo:
                out[lo - k0:hi - k0] = v[lo - a:hi - a]
        return out

    def trim(self, k: int) -> None:
        if k <= self.k_start:
            return
        kept = []
        for a, v in self._pieces:
            if a + v.size <= k:
                continue
            kept.append((k, v[k - a:].copy()) if a < k else (a, v))
        self._pieces = kept
        self.k_start = k
        self.k_end = max(self.k_end, k)


class LagEstimator:
    """Incremental per-block lags between a reference and another device (see module doc)."""

    def __init__(self, rate: float = COMMON_RATE_HZ, block_s: float = BLOCK_S,
                 max_lag: int = MAX_LAG_SAMPLES, centred: bool = True, subsample: bool = True,
                 activity_min_g: float = ACTIVITY_MIN_G, sub_blocks: int = SUB_BLOCKS,
                 keep_correlograms: bool = False, pad_s: float = FILTER_PAD_S):
        self.rate = float(rate)
        self.B = int(round(block_s * rate))
        self.M = int(max_lag)
        self.P = int(round(pad_s * rate))
        self.centred = centred
        self.subsample = subsample
        self.activity_min_g = activity_min_g
        self.sub_blocks = int(sub_blocks)
        self.keep_correlograms = keep_correlograms
        self.next_block = 0
        self.ref = _GridBuffer(-self.P)
        self.other = _GridBuffer(-self.M - self.P)
        self.ref_end_k: Optional[int] = None  # grid extent once a stream has finished
        self.other_end_k: Optional[int] = None

    # ------------------------------------------------------------------ feeding
    def feed(self, which: str, k0: int, values: np.ndarray) -> list[BlockLag]:
        buf = self.ref if which == "ref" else self.other
        limit = self._last_block_end()
        if limit is not None:  # past the usable span no block reads a sample: none is kept
            reach = limit + self.P + (self.M if buf is self.other else 0)
            if k0 >= reach:
                return self._process_ready()
            values = values[:reach - k0]
        buf.append(k0, values)  # after a gap: a new piece (the points between are not stored)
        return self._process_ready()

    def finish(self, which: str) -> list[BlockLag]:
        """Mark one stream as finished (its extent is final)."""
        if which == "ref":
            self.ref.finished = True
            self.ref_end_k = self.ref.k_end
        else:
            self.other.finished = True
            self.other_end_k = self.other.k_end
        return self._process_ready()

    @property
    def done(self) -> bool:
        return self.ref.finished and self.other.finished

    def finished(self, which: str) -> bool:
        return (self.ref if which == "ref" else self.other).finished

    # ------------------------------------------------------------------ processing
    def _last_block_end(self) -> Optional[int]:
        """Grid end of the usable time span once it is known (both streams' extents)."""
        ends = []
        if self.ref.finished:
            ends.append(self.ref_end_k)
        if self.other.finished:
            ends.append(self.other_end_k)
        return min(ends) if ends else None

    def _process_ready(self) -> list[BlockLag]:
        out = []
        while True:
            s = self.next_block * self.B
            e = s + self.B
            limit = self._last_block_end()
            if limit is not None and e > limit:
                if limit - s >= self.B // 2:  # a partial last block of at least half a block
                    e = limit
                else:
                    break
            ref_ok = self.ref.finished or self.ref.k_end >= e + self.P
            oth_ok = self.other.finished or self.other.k_end >= e + self.M + self.P
            if not (ref_ok and oth_ok):
                break
            out.append(self._block(self.next_block, s, e))
            self.next_block += 1
            if e < self.next_block * self.B:  # partial block was the last one
                break
            nxt = self.next_block * self.B
            self.ref.trim(nxt - self.P)
            self.other.trim(nxt - self.M - self.P)
        return out

    def _block(self, index: int, s: int, e: int) -> BlockLag:
        n, M, P = e - s, self.M, self.P
        bl = BlockLag(index=index, start_s=s / self.rate, duration_s=n / self.rate)
        # a block one device has no point in (a gap, however long) is settled without its arrays
        has_ref, has_oth = self.ref.has_data(s, e), self.other.has_data(s, e)
        if not (has_ref and has_oth):
            bl.coverage_ref = float(np.isfinite(self.ref.get(s, e)).mean()) if has_ref else 0.0
            bl.coverage_other = float(np.isfinite(self.other.get(s, e)).mean()) if has_oth else 0.0
            bl.reason = "no_overlap"
            return bl
        r_raw = self.ref.get(s - P, e + P)
        o_raw = self.other.get(s - M - P, e + M + P)
        r_in = r_raw[P:P + n]
        o_in = o_raw[M + P:M + P + n]
        bl.coverage_ref = float(np.isfinite(r_in).mean())
        bl.coverage_other = float(np.isfinite(o_in).mean())
        if bl.coverage_ref == 0 or bl.coverage_other == 0:
            bl.reason = "no_overlap"
            return bl
        bl.activity_ref = float(np.nanmean(np.abs(r_in)))
        bl.activity_other = float(np.nanmean(np.abs(o_in)))
        if bl.coverage_ref < MIN_COVERAGE or bl.coverage_other < MIN_COVERAGE:
            bl.reason = "gap"
            return bl
        if not (bl.activity_ref > self.activity_min_g and bl.activity_other > self.activity_min_g):
            bl.reason = "inactive"
            return bl
        rf = brond_filter(r_raw, self.rate)[P:P + n]
        of = brond_filter(o_raw, self.rate)[P:P + n + 2 * M]
        if not rf.any() or not of.any():
            bl.reason = "inactive"
            return bl
        # the lag of a block is the lag where its movement is: with drift, that is the
        # activity-weighted time, not the block's start or centre
        w = rf * rf
        bl.centroid_s = (s + float((np.arange(n) * w).sum() / w.sum())) / self.rate
        wide = M > COARSE_ABOVE
        if wide:
            bl.lag, bl.corr, edge, corr, bl.cand_lags, bl.cand_corr = wide_lag(
                rf, of, M, self.centred, self.subsample,
                fine_half=int(round(FINE_HALF_S * self.rate)), n_candidates=N_CANDIDATES)
            bl.correlogram_step = COARSE_DECIM
        else:
            corr = normalized_xcorr(rf, of, M, self.centred)
            bl.lag, bl.corr, edge = peak_lag(corr, M, self.subsample)
            bl.cand_lags, bl.cand_corr = top_peaks(corr, M, N_CANDIDATES, self.subsample)
        if self.keep_correlograms:
            bl.correlogram = corr.astype(np.float32)
        if edge:
            bl.reason = "edge"
        else:
            bl.valid = True
        if self.sub_blocks > 1:
            edges = np.linspace(0, n, self.sub_blocks + 1).astype(int)
            sl = np.full(self.sub_blocks, np.nan)
            sc = np.full(self.sub_blocks, np.nan)
            for i in range(self.sub_blocks):
                a, b = edges[i], edges[i + 1]
                seg = rf[a:b]
                if not seg.any() or b - a < 4 * COARSE_DECIM:
                    continue
                if wide:
                    lag, pk, ed, *_ = wide_lag(seg, of[a:b + 2 * M], M, self.centred,
                                               self.subsample)
                else:
                    c = normalized_xcorr(seg, of[a:b + 2 * M], M, self.centred)
                    lag, pk, ed = peak_lag(c, M, self.subsample)
                if not ed:
                    sl[i], sc[i] = lag, pk
            bl.sub_lags, bl.sub_corr = sl, sc
        return bl
