"""Nights from the 5 s epoch stream: GGIR's night windows, the HDCZA window with the daysleeper
re-run, the guider order, and the night's onset, wake and measures from the SIBs.

``SleepStage.push(rows)`` takes epoch rows (``engine.tables.EpochRows``, consecutive epochs,
gap rows included) and returns ``(rows, spt, sib)`` for the rows that are final; ``flush()``
returns the rest. A night is decided once the data reach 6 h past its closing noon (GGIR's
daysleeper re-run looks there), so the stage holds at most about 30 h of epochs (noon to noon
plus 6 h, and at most ``HOLD_EPOCHS`` when a still stretch leaves the SIBs undecided): a few
hundred kB whatever the recording's length. See rules.py for every rule's source.

Night of a midnight ``m`` (an epoch starting at 00:00:00 local): epochs ``m - 12 h + 1`` to
``m + 12 h`` (GGIR counts its window from noon, so its hours are the epoch starts, see
docs/sleep.md). Guider: the sleep log's night when it has one, else HDCZA, else L5 +- 6 h.
Onset and wake: the first and last SIB overlapping the guider window (the guider window itself
when none does, or when it was built over nonwear: guider ``HDCZA+invalid``).
"""

from __future__ import annotations

import datetime as _dt
from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from ..timezones import Zone
from . import rules
from .hdcza import HdczaOptions, SptEstimate, hdcza
from .sib import SibStream

DAY_NS = 86400 * 10**9


@dataclass
class SleepOptions:
    hdcza: HdczaOptions = field(default_factory=HdczaOptions)
    angle_deg: float = rules.ANGLE_THRESHOLD_DEG
    time_min: float = rules.TIME_THRESHOLD_MIN
    sleep_log: Optional[object] = None  # engine.sleep.diary.SleepLog of the participant

    def to_dict(self) -> dict:
        h = self.hdcza
        return {"anglethreshold": self.angle_deg, "timethreshold": self.time_min,
                "HDCZA_threshold": list(h.threshold) if np.ndim(h.threshold) else h.threshold,
                "HASPT_ignore_invalid": h.ignore_invalid, "spt_min_block_dur": h.min_block_min,
                "spt_max_gap_dur": h.max_gap_min, "spt_max_gap_ratio": h.max_gap_ratio,
                "sleep_log": str(self.sleep_log.path) if self.sleep_log else None,
                "sleep_log_nights": len(self.sleep_log.nights) if self.sleep_log else 0}


@dataclass
class Night:
    date: _dt.date  # the evening's local date
    window: tuple  # epoch indices [first, last] of the noon-to-noon window
    guider: str
    guider_span: Optional[tuple]  # [first, stop) epochs of the guider window
    spt: Optional[tuple]  # [onset, wake) epochs
    estimate: Optional[SptEstimate] = None
    estimate_base: int = 0  # window start the estimate's indices count from
    daysleeper: bool = False
    window_hours: float = 24.0
    dst: bool = False  # the night's noon-to-noon local day is 23 or 25 h long
    sleep_epochs: int = 0
    awakenings: int = 0
    nonwear_epochs: int = 0
    bouts: list = field(default_factory=list)  # [first, stop) of the SIBs inside the SPT
    invalid_epochs: int = 0  # nonwear or gap epochs in the window
    day_epochs: int = 17280  # epochs in 24 h (GGIR's NepochsInDay)
    cut_start: bool = False  # the recording starts inside the night's window
    cut_end: bool = False  # the recording ends inside the night's window
    sib_overlap: bool = True  # a SIB overlaps the guider window (else GGIR's cleaningcode 5)
    spt_at_edge: bool = False  # the sleep period (or its guider) runs into the recording's start / end

    @property
    def fraction_invalid(self) -> float:
        """GGIR's ``fraction.night.invalid``: invalid epochs plus the epochs a 24-h window lacks,
        over a 24-h window's epochs, at most 1 (rules.py)."""
        n = self.window[1] - self.window[0] + 1
        per_day = self.day_epochs
        return min(1.0, (self.invalid_epochs + max(0, per_day - n)) / per_day)

    @property
    def cleaningcode(self) -> int:
        """GGIR part 4's ``cleaningcode``: 0 sleep log, 1 no sleep log, 5 no SIB overlaps the
        guider window, 2 too little valid data (more than ``24 - includenightcrit`` hours
        invalid or missing); later rules win as in GGIR (rules.py)."""
        code = 0 if self.guider == "sleeplog" else 1
        if not self.sib_overlap:
            code = 5
        if self.fraction_invalid > (24.0 - rules.INCLUDE_NIGHT_CRIT_H) / 24.0:
            code = 2
        return code

    @property
    def valid(self) -> bool:
        """A night a study keeps: GGIR's cleaned part 4 (cleaningcode 0 or 1) and a sleep period
        not cut by the recording's start or end."""
        return self.cleaningcode <= rules.VALID_CLEANINGCODE_MAX and not self.spt_at_edge


class SleepStage:
    HOLD_EPOCHS = 36 * 720  # a still stretch held undecided at most this long (36 h)
    TAKE_EPOCHS = 720  # rows are taken in batches of about an hour

    def __init__(self, zone: Zone, epoch_s: float, options: Optional[SleepOptions] = None):
        self.zone = zone
        self.epoch_ns = int(round(epoch_s * 1e9))
        self.per_h = int(round(3600 / epoch_s))
        self.half = 12 * self.per_h
        options = options if options is not None else SleepOptions()
        self.opts = options
        self.sib = SibStream(epoch_s, options.angle_deg, options.time_min)
        self.first_ns = None
        self.n = 0  # epochs seen
        self.base = 0  # index of the first held epoch
        self._rows = []  # held EpochRows
        self._ang = np.zeros(0)
        self._inv = np.zeros(0, bool)
        self._enmo = np.zeros(0)
        self._sib = np.zeros(0, np.int8)  # decided SIB values from self.base on
        self.midnights = []  # epoch indices of local midnights, in order
        self.first4am = None
        self._night0 = None  # None: unknown; True / False: the first (partial) night exists
        self._next_midnight = 0  # position in self.midnights of the next undecided night
        self.nights: list[Night] = []
        self._spans = []  # [onset, wake) of decided nights
        self.diary = {}  # night date -> (onset, wake) local datetimes
        self._pending = []  # rows not taken yet (less than TAKE_EPOCHS)
        self._pending_n = 0

    # ------------------------------------------------------------------ input
    def push(self, rows):
        """Rows are gathered and taken an hour at a time (the per-call numpy overhead of a few
        epochs at a time would cost more than the work)."""
        if len(rows):
            self._pending.append(rows)
            self._pending_n += len(rows)
        if self._pending_n < self.TAKE_EPOCHS:
            return []
        self._take_pending()
        self._decide(final=False)
        return self._emit(final=False)

    def _take_pending(self) -> None:
        if self._pending:
            first = self._pending[0]
            rows = first if len(self._pending) == 1 else type(first).concat(self._pending)
            self._pending, self._pending_n = [], 0
            self._take(rows)

    def flush(self):
        self._take_pending()
        self._sib = np.concatenate([self._sib, self.sib.flush()])
        self._decide(final=True)
        return self._emit(final=True)

    def _take(self, rows) -> None:
        if self.first_ns is None:
            self.first_ns = int(rows.start_ns[0])
            if self.opts.sleep_log is not None:
                self.diary = self.opts.sleep_log.resolve(self._local_date(self.first_ns))
        i0 = self.n
        k = len(rows)
        self.n += k
        self._rows.append(rows)
        self._ang = np.concatenate([self._ang, np.nan_to_num(rows.anglez_deg, nan=0.0)])
        self._inv = np.concatenate([self._inv, rows.nonwear | rows.gap])
        self._enmo = np.concatenate([self._enmo, np.nan_to_num(rows.enmo_mg, nan=0.0)])
        self._sib = np.concatenate([self._sib, self.sib.push(rows.anglez_deg)])
        if self.sib.done < self.n - self.HOLD_EPOCHS:
            self._sib = np.concatenate([self._sib, self.sib.release(self.n - self.HOLD_EPOCHS)])
        local = rows.start_ns + self.zone.offsets_s(rows.start_ns) * 10**9
        tod = local % DAY_NS
        self.midnights += (np.flatnonzero(tod == 0) + i0).tolist()
        if self.first4am is None and i0 <= 2 * self.half:
            four = np.flatnonzero(tod == 4 * 3600 * 10**9) + i0
            four = four[four <= 2 * self.half]
            if four.shape[0]:
                self.first4am = int(four[0])
        if self._night0 is None and self.midnights:
            m1 = self.midnights[0]
            self._night0 = self.first4am is not None and self.first4am < m1

    # ------------------------------------------------------------------ nights
    def _local_date(self, t_ns: int) -> _dt.date:
        local = t_ns + int(self.zone.offsets_s(np.array([t_ns]))[0]) * 10**9
        return (_dt.datetime(1970, 1, 1) + _dt.timedelta(microseconds=local // 1000)).date()

    def _noon_ns(self, date: _dt.date) -> tuple:
        """UTC of the local noons that open and close the night of ``date``."""
        out = []
        for d in (date, date + _dt.timedelta(days=1)):
            local = int((_dt.datetime.combine(d, _dt.time(12)) - _dt.datetime(1970, 1, 1)).total_seconds()) * 10**9
            guess = local - int(self.zone.offsets_s(np.array([local]))[0]) * 10**9
            out.append(local - int(self.zone.offsets_s(np.array([guess]))[0]) * 10**9)
        return tuple(out)

    def _local_hour(self, i: int) -> int:
        t = self.first_ns + i * self.epoch_ns
        return int(((t + self.zone.offsets_s(np.array([t]))[0] * 10**9) % DAY_NS) // (3600 * 10**9))

    def _windows(self, final: bool):
        """Yield (first, last, midnight or None) of the nights that can be decided now."""
        if self._night0 is None and not final:
            return
        if self._night0 is None:  # no midnight in the recording (final)
            self._night0 = False
        if self._night0:
            m1 = self.midnights[0] if self.midnights else self.n - 1
            last = m1 - self.half
            if not self._ready(last, final):
                return
            self._night0 = False
            yield 0, last, None
        while self._next_midnight < len(self.midnights):
            m = self.midnights[self._next_midnight]
            first, last = m - self.half + 1, m + self.half
            if not self._ready(last, final):
                return
            self._next_midnight += 1
            yield first, last, m
        if final and not self.midnights and self.n:  # GGIR: the last epoch as a dummy midnight
            m = self.n - 1
            self.midnights.append(m)
            self._next_midnight = 1
            yield m - self.half + 1, m + self.half, m

    def _ready(self, last: int, final: bool) -> bool:
        return final or self.n > last + rules.DAYSLEEP_OFFSET_H * self.per_h + self.per_h + 2

    def _decide(self, final: bool) -> None:
        if final and self.n / (2 * self.half) <= rules.MIN_RECORDING_DAYS:
            return
        for first, last, m in list(self._windows(final)):
            cut_start = first <= 0 and not (m is not None and first == 0)
            if 0 <= last < self.n - 1:  # GGIR: a window ending at 11 or 13 o'clock (DST) moves 1 h
                h = self._local_hour(last)
                last += self.per_h if h == 11 else (-self.per_h if h == 13 else 0)
            if last - first < rules.MIN_NIGHT_EPOCHS:
                continue
            cut_end = last > self.n - 1
            last = min(last, self.n - 1)
            first = max(first, 0)
            night = self._night(first, last, m)
            night.cut_start, night.cut_end = cut_start, cut_end
            if night.spt is not None:  # the sleep period or its guider window reaches the cut
                g0, g1 = night.guider_span
                night.spt_at_edge = ((cut_start and min(night.spt[0], g0) <= 1)
                                     or (cut_end and max(night.spt[1], g1) >= self.n - 1))
            self.nights.append(night)

    def _slice(self, a: np.ndarray, first: int, stop: int) -> np.ndarray:
        return a[first - self.base:stop - self.base]

    def _sib_of(self, first: int, stop: int) -> np.ndarray:
        """SIB values of epochs [first, stop), undecided ones as ``SibStream.peek`` sees them."""
        have = self.base + self._sib.shape[0]
        known = self._sib[max(first - self.base, 0):max(stop - self.base, 0)]
        if stop <= have:
            return known
        return np.concatenate([known, self.sib.peek(stop)[max(first, have) - have:]])

    def _night(self, first: int, last: int, m: Optional[int]) -> Night:
        opts = self.opts.hdcza
        est = hdcza(self._slice(self._ang, first, last + 1), self._slice(self._inv, first, last + 1), opts)
        base = first
        daysleeper = False
        off = rules.DAYSLEEP_OFFSET_H * self.per_h
        if est.start is not None and est.end + first >= last - rules.DAYSLEEP_NEAR_NOON_H * self.per_h:
            n0, n1 = first + off, last + off
            if first == 0 and n1 - n0 < 2 * self.half and n1 + 1 > 2 * self.half:
                n0 = n1 - 2 * self.half
            n1 = min(n1, self.n - 1)
            if n1 + 1 < self.n and n1 - n0 > 23 * self.per_h:
                again = hdcza(self._slice(self._ang, n0, n1 + 1), self._slice(self._inv, n0, n1 + 1), opts)
                if again.start is not None and again.end + n0 >= last:
                    est, base, daysleeper = again, n0, True
        midnight_ns = (self.first_ns + m * self.epoch_ns) if m is not None else None
        if midnight_ns is None:  # the partial first night: the midnight before the first noon
            midnight_ns = self.first_ns + (last - self.half) * self.epoch_ns
        date = self._local_date(midnight_ns) - _dt.timedelta(days=1)
        span = None
        guider = "none"
        diary = self.diary.get(date)
        if diary is not None:
            span = self._diary_span(*diary)
            guider = "sleeplog" if span is not None else guider
        if span is None and est.start is not None:
            s0, s1 = est.epochs()
            span, guider = (base + s0, base + s1), est.guider
        if span is None:
            span, guider = self._l5_span(first, last), "L512"
        noon = self._noon_ns(date)
        night = Night(date, (first, last), guider, span, None, est, base, daysleeper,
                      round((last - first + 1) / self.per_h, 4),
                      noon[1] - noon[0] != DAY_NS)
        night.invalid_epochs = int(self._slice(self._inv, first, last + 1).sum())
        night.day_epochs = 2 * self.half
        if span is not None:
            self._refine(night)
        return night

    def _diary_span(self, onset: _dt.datetime, wake: _dt.datetime) -> Optional[tuple]:
        idx = []
        for d in (onset, wake):
            local_ns = int((d - _dt.datetime(1970, 1, 1)).total_seconds()) * 10**9
            guess = local_ns - int(self.zone.offsets_s(np.array([local_ns]))[0]) * 10**9
            utc = local_ns - int(self.zone.offsets_s(np.array([guess]))[0]) * 10**9
            idx.append(-(-(utc - self.first_ns) // self.epoch_ns))
        a, b = max(idx[0], self.base), min(idx[1], self.n)
        return (a, b) if b > a else None

    def _l5_span(self, first: int, last: int) -> Optional[tuple]:
        acc = self._slice(self._enmo, first, last + 1)
        w = rules.L5_HOURS * self.per_h
        w += 1 if w % 2 == 0 else 0
        if acc.shape[0] <= w:
            return None
        c = np.cumsum(np.concatenate([[0.0], acc]))
        means = (c[w:] - c[:-w]) / w
        if np.ptp(means) == 0:
            return None
        centre = first + int(np.argmin(means)) + w // 2
        h = rules.L5_HALF_WINDOW_H * self.per_h
        return max(centre - h, first), min(centre + h, last + 1)

    def _refine(self, night: Night) -> None:
        g0, g1 = night.guider_span
        lo = max(g0 - 2 * self.half, self.base)
        hi = min(g1 + 2 * self.half, self.n)
        sib = self._sib_of(lo, hi)
        d = np.diff(np.concatenate([[0], sib, [0]]))
        s = np.flatnonzero(d == 1) + lo
        e = np.flatnonzero(d == -1) + lo
        over = (s < g1) & (e > g0)
        night.sib_overlap = bool(over.any())
        if over.any() and not night.guider.endswith("+invalid"):
            onset, wake = int(s[over][0]), int(e[over][-1])
        else:
            onset, wake = g0, g1
        night.spt = (onset, wake)
        self._spans.append(night.spt)
        inside = self._sib_of(onset, wake).astype(bool)
        night.sleep_epochs = int(inside.sum())
        dd = np.diff(np.concatenate([[0], inside.astype(np.int8), [0]]))
        bs, be = np.flatnonzero(dd == 1), np.flatnonzero(dd == -1)
        night.bouts = [(onset + int(a), onset + int(b)) for a, b in zip(bs, be)]
        night.awakenings = max(len(night.bouts) - 1, 0)
        night.nonwear_epochs = int(self._slice(self._inv, onset, wake).sum())

    # ------------------------------------------------------------------ output
    def _hold_from(self, final: bool) -> int:
        """Epochs below this are final."""
        if final:
            return self.n
        stop = self.base + self._sib.shape[0]
        if self._night0 is None or self._night0:
            return min(stop, 0)
        if self._next_midnight < len(self.midnights):
            nxt = self.midnights[self._next_midnight] - self.half + 1
        else:
            nxt = self.n - 2 * self.half
        return max(min(stop, nxt), self.base)

    def _emit(self, final: bool):
        stop = self._hold_from(final)
        out = []
        while self._rows and self.base + len(self._rows[0]) <= stop:
            rows = self._rows.pop(0)
            k = len(rows)
            i = np.arange(self.base, self.base + k)
            spt = np.zeros(k, np.int8)
            for a, b in self._spans:
                spt[(i >= a) & (i < b)] = 1
            sib = self._sib[:k].copy()
            if sib.shape[0] < k:  # final: every value is decided
                sib = np.concatenate([sib, np.zeros(k - sib.shape[0], np.int8)])
            out.append((rows, spt, sib))
            self.base += k
            self._sib = self._sib[k:]
            self._ang, self._inv, self._enmo = self._ang[k:], self._inv[k:], self._enmo[k:]
            self._spans = [x for x in self._spans if x[1] > self.base]
        return out
