"""GENEActiv ``.bin`` reader: a streaming Source of Blocks (spec: ../shared/specs/geneactiv-format.md).

The file is text: a header of ``key:value`` lines in sections, then 10-line pages of 300 samples
(each sample 12 hex characters: x, y, z 12-bit two's complement, 10-bit light, button, reserved).

What the reader does, in order:

* **header** parsed by section heading and key (not line numbers), CR LF or LF, NUL/space padding,
  comma decimals; the original GENEA format (and anything else) is refused with a typed error;
* **pages** read in batches of ``batch_pages`` from a byte stream (plain file, gzip stream, or a file
  still being written with ``follow=True``); hex decoded with a numpy lookup table over the bytes of
  all pages of a batch at once;
* **times**: every page is anchored on its own ``Page Time`` (device local time minus the header
  time zone -> UTC ns); sample times are linear between consecutive page times (so "85.7 Hz" comes
  out as the true 600/7 Hz); the last page of a segment uses the previous step, or 300/rate;
* **QC**: a page with bad hex, a bad time or a bad length is skipped and logged; a sequence gap,
  a skipped page or a page-time step that disagrees with 300/rate by more than ``time_tolerance``
  starts a new segment and is logged; lines that are not pages are skipped up to the next
  ``Recorded Data`` line (resynchronisation) and logged; a truncated final page yields its complete
  12-character samples and is logged; a header page count that disagrees with the file is logged.

Accel counts are returned raw (int16) with ``accel_counts_per_g = gain/100`` and
``accel_zero = offset/100`` per axis, so ``Block.accel_g()`` equals ``(raw*100 - offset)/gain``.
Per page (``unit_*``): index in the file, ``Sequence Number``, temperature (degC) and battery (V)
from the page lines, ``light`` = the raw light of the page's first sample, ``temperature_raw`` = -1
(no ADC code in the format). Per sample: ``per_sample["light_raw"]`` (10 bits; lux = raw * Lux /
Volts of the header) and ``per_sample["button"]``.

Why a page-time step off by more than ``time_tolerance`` is not interpolated: both 50 Hz Ver4.08a
files we have show 6.5 s between pages 0 and 1 (6.0 s everywhere else); interpolating would put
page 0 at 46 Hz. We keep the rate within the page and record the 0.52 s as a gap (new segment).
"""

from __future__ import annotations

import itertools
import re
from dataclasses import dataclass, fields as dc_fields
from pathlib import Path
from typing import Callable, Iterator, Optional, Union

import numpy as np

from stillpoint.engine.core.blocks import (PER_SAMPLE_BUTTON, PER_SAMPLE_LIGHT_RAW, Block, DeviceInfo, QCEvent,
                             QCReport)
from .byteio import (FollowingReader, check_recording_path, consumed_fraction, is_gzip, open_bytes, read_exact,
                     stream_damage)
from .constants import (GNA_GAIN_MAX, GNA_HEX_PER_SAMPLE, GNA_LIGHT_CAL_RANGE, GNA_LIGHT_SHIFT,
                        GNA_OFFSET_MAX, GNA_PAGE_MARKER, GNA_RATE_85_7, GNA_SAMPLES_PER_PAGE,
                        NS_TIME_RANGE_MS, PLAUSIBLE_BATTERY_V, PLAUSIBLE_RATE_HZ,
                        PLAUSIBLE_TEMPERATURE_C, PLAUSIBLE_TIME_NS, PLAUSIBLE_YEARS, gna_accel_scale,
                        gna_rate_hz)
from stillpoint.engine.core.errors import (CorruptRecordingError, TruncatedRecordingError,
                     UnsupportedFormatError)
from .geneactiv_header import (CALIBRATION_KEYS, SUBJECT_KEYS, TRIAL_KEYS, GeneactivHeader,
                               header_range_g, header_rate_hz, parse_header_text, parse_number,
                               parse_time_ms, parse_times_ms, parse_timezone)

__all__ = ["GeneactivReader", "read_header", "decode_hex_samples", "GeneactivWriter"]  # noqa: F822 - lazy (__getattr__)

PAGE_HEX_CHARS = GNA_SAMPLES_PER_PAGE * GNA_HEX_PER_SAMPLE  # 3600
APPROX_PAGE_BYTES = 3800  # a page with its 9 text lines, for sizing reads (never for allocation)
HEADER_LIMIT_BYTES = 1 << 20  # a header longer than this is not a GENEActiv header
MAX_QC_EVENTS = 10_000  # QC events listed per file (as the .cwa reader); the rest are counted
MAX_LINE_BYTES = 1 << 20  # a "line" longer than this is garbage (a data line is 3600 characters)
MAX_PAGE_FIELD_LINES = 24
MAX_FIELD_LINE_BYTES = 512  # a page's key:value line is short; a longer line is its data line
# (line within the page, key prefix) that a standard page must have for the fast path
_FAST_KEYS = ((1, b"Device Unique Serial Code:"), (2, b"Sequence Number:"), (3, b"Page Time:"),
              (4, b"Unassigned:"), (5, b"Temperature:"), (6, b"Battery voltage:"),
              (7, b"Device Status:"), (8, b"Measurement Frequency:"))  # "key:value" lines allowed between a marker and its hex line
_MARKER = GNA_PAGE_MARKER.encode()
_MARKER_CR = _MARKER + b"\r"
_MARKER_RE = re.compile(rb"(?:^|\n)Recorded Data[ \t\r\x00]*(?:\n|$)")
_VALUE_STRIP = b" \t\r\x00"
_NOT_PAGE_REASONS = ("page_count_mismatch", "header_value")  # QC events that say nothing of a page


def _data_chars(line: bytes) -> bytes:
    """A page's data line without its line ending (one CR before the LF). Nothing else is stripped:
    a space, tab, NUL or any other byte after the hex characters is part of the line (damage that
    makes its length wrong), never padding. The general parser and the fast path both use this."""
    return line[:-1] if line.endswith(b"\r") else line


# Two hex characters (read as one little-endian uint16: first character in the low byte) -> the
# byte they spell; 0x100 marks a pair holding a character that is not a hex digit. 128 KB table:
# one gather per 2 characters.
def _pair_table() -> np.ndarray:
    digit = np.full(256, 255, np.uint16)
    digit[np.frombuffer(b"0123456789", np.uint8)] = np.arange(10)
    digit[np.frombuffer(b"ABCDEF", np.uint8)] = np.arange(10, 16)
    digit[np.frombuffer(b"abcdef", np.uint8)] = np.arange(10, 16)
    pair = np.arange(65536)
    first, second = digit[pair & 0xFF], digit[pair >> 8]
    return np.where((first == 255) | (second == 255), 0x100, (first << 4) | second).astype(np.uint16)


_HEX_PAIR = _pair_table()


def decode_hex_samples(hex_bytes: Union[bytes, np.ndarray], n_samples: int):
    """Decode ``n_samples`` 12-character samples from the start of ``hex_bytes`` (vectorised).

    Returns (accel (n, 3) int16 two's-complement 12-bit, light (n,) uint16 10-bit, button (n,) uint8,
    bad (n,) bool: the sample holds a character that is not a hex digit). [GNA] §5
    """
    n = int(n_samples)
    if isinstance(hex_bytes, np.ndarray):
        pairs = hex_bytes.reshape(-1)[:n * 12].view("<u2")
    else:
        pairs = np.frombuffer(hex_bytes, "<u2", count=n * 6)
    b = _HEX_PAIR[pairs].reshape(n, 6)  # 6 bytes per sample
    if b.max(initial=0) > 0xFF:
        bad = (b > 0xFF).any(axis=1)
        b = b & 0xFF
    else:
        bad = np.zeros(n, bool)
    words = np.empty((n, 4), np.uint16)  # x, y, z, low 12 bits
    words[:, 0] = (b[:, 0] << 4) | (b[:, 1] >> 4)
    words[:, 1] = ((b[:, 1] & 0xF) << 8) | b[:, 2]
    words[:, 2] = (b[:, 3] << 4) | (b[:, 4] >> 4)
    words[:, 3] = ((b[:, 4] & 0xF) << 8) | b[:, 5]
    # sign-extend 12 -> 16 bits: values >= 2048 are negative (actipy's '> 2048' is a bug)
    accel = (words[:, :3] << 4).view(np.int16) >> 4
    low = words[:, 3]
    light = low >> GNA_LIGHT_SHIFT
    button = ((low >> 1) & 1).astype(np.uint8)
    return accel, light, button, bad


@dataclass
class _Run:
    """Consecutive pages that passed the structural checks, decoded (a fast-path run or one page)."""

    index: np.ndarray  # (P,) int64 position among the pages of the file (0-based)
    seq: np.ndarray  # (P,) int64 Sequence Number
    t_ms: np.ndarray  # (P,) int64 Page Time, device clock, ms since 1970
    temperature: np.ndarray  # (P,) float64
    battery: np.ndarray  # (P,) float64
    freq: np.ndarray  # (P,) float64 page Measurement Frequency, NaN when absent
    counts: np.ndarray  # (P,) int64 samples per page (300, fewer only for a last partial page)
    accel: np.ndarray  # (N, 3) int16
    light: np.ndarray  # (N,) uint16
    button: np.ndarray  # (N,) uint8

    @property
    def pages(self) -> int:
        return int(self.seq.shape[0])

    def offsets(self) -> np.ndarray:
        return np.concatenate([[0], np.cumsum(self.counts)]).astype(np.int64)

    @staticmethod
    def single(index, seq, t_ms, temperature, battery, freq, accel, light, button) -> "_Run":
        return _Run(np.array([index], np.int64), np.array([seq], np.int64), np.array([t_ms], np.int64),
                    np.array([temperature], np.float64), np.array([battery], np.float64),
                    np.array([np.nan if freq is None else freq], np.float64),
                    np.array([accel.shape[0]], np.int64), accel, light, button)


@dataclass
class _Skip:
    """A page (or stretch of text) that was dropped: forces a segment break."""

    index: int
    desync: bool = False  # text that was not a page (how many pages it held is unknown)


def _slice_run(run: _Run, lo: int, hi: int) -> _Run:
    """Pages [lo, hi) of a run."""
    off = run.offsets()
    a, b = int(off[lo]), int(off[hi])
    return _Run(run.index[lo:hi], run.seq[lo:hi], run.t_ms[lo:hi], run.temperature[lo:hi],
                run.battery[lo:hi], run.freq[lo:hi], run.counts[lo:hi], run.accel[a:b], run.light[a:b],
                run.button[a:b])


def _take_pages(run: _Run, keep: np.ndarray) -> _Run:
    """The pages ``keep`` (sorted positions) of a run, with their samples."""
    off = run.offsets()
    rows = np.concatenate([np.arange(off[k], off[k + 1]) for k in keep.tolist()]).astype(np.int64)
    return _Run(run.index[keep], run.seq[keep], run.t_ms[keep], run.temperature[keep],
                run.battery[keep], run.freq[keep], run.counts[keep], run.accel[rows],
                run.light[rows], run.button[rows])


def _merge_runs(items: list) -> list:
    """Join consecutive runs (e.g. pages of the general parser) so later stages see few, long runs."""
    out: list = []
    group: list = []

    def flush():
        if len(group) == 1:
            out.append(group[0])
        elif group:
            cat = np.concatenate
            out.append(_Run(*(cat([getattr(r, f.name) for r in group]) for f in dc_fields(_Run))))
        group.clear()

    for x in items:
        if isinstance(x, _Run):
            group.append(x)
        elif x is not None:
            flush()
            out.append(x)
    flush()
    return out


def _open_stream(path: Path, follow: bool, follow_done, follow_idle_s: float):
    if follow:
        if is_gzip(path):
            raise UnsupportedFormatError(path, "follow mode reads a plain .bin that is still being written; a gzip file cannot be followed")
        return FollowingReader(path, is_done=follow_done, idle_timeout=follow_idle_s)
    return open_bytes(path)


class GeneactivReader:
    """Streaming Source over a GENEActiv ``.bin`` (or ``.bin.gz``) file.

    >>> with GeneactivReader("rec.bin") as src:      # doctest: +SKIP
    ...     for block in src: ...                    # Blocks of up to batch_pages pages
    ...     print(src.qc.as_dict())

    ``timezone`` overrides the header's ``Time Zone`` (e.g. "+01:00", "GMT -04:00", seconds).
    ``follow=True`` keeps reading a file that is still being written until ``follow_done()``
    returns True or no byte arrives for ``follow_idle_s`` seconds.
    ``time_tolerance``: relative disagreement between a page-time step and 300/rate above which
    the step is treated as a time jump (new segment) instead of being interpolated.
    """

    def __init__(self, path, *, batch_pages: int = 256, follow: bool = False,
                 timezone: Union[str, int, None] = None, follow_done: Optional[Callable[[], bool]] = None,
                 follow_idle_s: float = 5.0, time_tolerance: float = 0.01):
        self.path = Path(path)
        if batch_pages < 1:
            raise ValueError("batch_pages must be >= 1")
        self.batch_pages = int(batch_pages)
        self.time_tolerance = float(time_tolerance)
        check_recording_path(self.path)
        self._f = _open_stream(self.path, follow, follow_done, follow_idle_s)
        try:
            self.header, self._rest = _read_header(self._f, self.path)
            self.info = _device_info(self.header, self.path, timezone, self._rest)
        except BaseException:
            self._f.close()
            raise
        self.qc = QCReport(unit="page")
        self._iterated = False
        self._samples = 0
        # (lines, bytes) of a desync stretch still being skipped
        self._desync_open: Optional[tuple[int, int]] = None
        self._n_events = 0  # events listed or counted past the cap
        self._unlisted: list = []  # (event, always) logged but not yet listed (see _event)
        try:  # the header text was decoded as UTF-8, or as Latin-1 when it is not UTF-8
            self._serial = self.info.device_id.encode("latin-1")
        except UnicodeEncodeError:
            self._serial = self.info.device_id.encode("utf-8")
        self._serial_line = b"Device Unique Serial Code:" + self._serial
        self._serial_line_cr = self._serial_line + b"\r"
        self._serial_warned = False
        self._time_warned = False
        self._rate_warned = False
        for fault in self.info.header.get("channel_faults", ()):
            self._event(0, "header_value", fault)

    # ------------------------------------------------------------------ Source protocol
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self) -> None:
        try:
            self._f.close()
        except Exception:  # pragma: no cover - closing must never mask the real error
            pass

    def progress(self) -> Optional[float]:
        """Share of the file read so far: for progress bars."""
        return consumed_fraction(self._f)

    def __iter__(self) -> Iterator[Block]:
        if self._iterated:
            raise RuntimeError("a GeneactivReader is single-pass; open the file again")
        self._iterated = True
        try:
            yield from self._blocks()
        finally:
            self._list_events()  # a read stopped early still lists what it logged
            self.close()

    # ------------------------------------------------------------------ internals
    def _event(self, index: int, reason: str, detail: str = "", time_ns=None, samples: int = 0,
               always: bool = False):
        """Log a QC event. Events are not logged in file order (all pages of a batch are parsed
        before the segment checks of its pages run), so they wait here until _list_events puts
        them on the list in file order; the list, and which events the cap leaves out, is then
        the same at every batch size."""
        self._unlisted.append((QCEvent(index=index, reason=reason, detail=detail, time_ns=time_ns,
                                       samples=samples), always))

    def _list_events(self, upto: Optional[int] = None) -> None:
        """List the logged events of pages <= ``upto`` (all when None) in file order (stable: the
        events of one page keep the order they were logged in). The list is capped at
        MAX_QC_EVENTS (memory stays bounded on a file that is damaged throughout; at most a batch
        of events waits); later events are still counted in total/skipped/segments."""
        if not self._unlisted:
            return
        if upto is None:
            ready, self._unlisted = self._unlisted, []
        else:
            ready = [x for x in self._unlisted if x[0].index <= upto]
            if not ready:
                return
            self._unlisted = [x for x in self._unlisted if x[0].index > upto]
        ready.sort(key=lambda x: x[0].index)
        for event, always in ready:
            self._n_events += 1
            if self._n_events <= MAX_QC_EVENTS or always:
                self.qc.add(event)
            elif self._n_events == MAX_QC_EVENTS + 1:
                self.qc.add(QCEvent(index=event.index, reason="qc_log_truncated",
                                    detail=f"more than {MAX_QC_EVENTS} QC events; later ones are "
                                           "counted in total/skipped but not listed"))

    def _sanitise(self, run: _Run) -> Optional[_Run]:
        """Page fields that no device writes: a Page Time outside the int64-ns range (the page is
        skipped: its samples cannot be timed), a time before/after the plausible years, a
        temperature/battery outside the sensor's range or not finite (set to NaN), a page rate that
        is not plausible (the header's rate is used). Each is logged; nothing passes silently."""
        lo_ms, hi_ms = NS_TIME_RANGE_MS
        tz_ms = self.info.timezone_offset_s * 1000
        t_utc = run.t_ms - tz_ms
        out_of_range = (t_utc <= lo_ms + 86_400_000) | (t_utc >= hi_ms - 86_400_000)
        if out_of_range.any():
            for i in np.flatnonzero(out_of_range).tolist():
                self.qc.valid -= 1
                self.qc.skipped += 1
                self._event(int(run.index[i]), "bad_page_time",
                            f"Page Time ({int(run.t_ms[i]) // 31_556_952_000 + 1970:d} or so) is outside "
                            "the representable range 1678..2261; page skipped",
                            samples=int(run.counts[i]))
            keep = np.flatnonzero(~out_of_range)
            if not keep.size:
                return None
            run = _take_pages(run, keep)
            t_utc = run.t_ms - tz_ms
        if not self._time_warned:
            t_ns = t_utc * 1_000_000
            odd = np.flatnonzero((t_ns < PLAUSIBLE_TIME_NS[0]) | (t_ns >= PLAUSIBLE_TIME_NS[1]))
            if odd.size:
                self._time_warned = True
                i = int(odd[0])
                self._event(int(run.index[i]), "implausible_time",
                            f"Page Time {np.datetime64(int(t_ns[i]), 'ns')} is outside "
                            f"{PLAUSIBLE_YEARS[0]}..{PLAUSIBLE_YEARS[1]} (device clock never set?); "
                            "times are kept as recorded (logged once)", time_ns=int(t_ns[i]))
        for name, arr, (lo, hi), unit in (("Temperature", run.temperature, PLAUSIBLE_TEMPERATURE_C, "degC"),
                                          ("Battery voltage", run.battery, PLAUSIBLE_BATTERY_V, "V")):
            bad = ~np.isnan(arr) & ~((arr >= lo) & (arr <= hi))
            for i in np.flatnonzero(bad).tolist():
                self._event(int(run.index[i]), "bad_value",
                            f"{name} {arr[i]:g} {unit} is outside {lo:g}..{hi:g}; set to NaN")
            if bad.any():
                arr[bad] = np.nan
        lo, hi = PLAUSIBLE_RATE_HZ
        badf = ~np.isnan(run.freq) & ~((run.freq >= lo) & (run.freq <= hi))
        if badf.any():
            if not self._rate_warned:
                self._rate_warned = True
                i = int(np.flatnonzero(badf)[0])
                self._event(int(run.index[i]), "bad_page_frequency",
                            f"page Measurement Frequency {run.freq[i]:g} Hz is not a plausible rate "
                            f"({lo:g}..{hi:g} Hz); the header's {self.info.sample_rate_nominal:g} Hz "
                            "is used for such pages (logged once)")
            run.freq[badf] = np.nan
        return run

    def _nominal_steps(self, freq: np.ndarray) -> np.ndarray:
        """ns that 300 samples take at each page's own rate (the header's when a page has none)."""
        rate = np.where(np.isfinite(freq) & (freq > 0), freq, self.info.sample_rate_nominal)
        return np.rint(GNA_SAMPLES_PER_PAGE / rate * 1e9).astype(np.int64)

    def _blocks(self) -> Iterator[Block]:
        """Segment and time the page runs (vectorised per run), then cut them into Blocks.

        Every page is timed with the step to the next page's Page Time; the last page seen is held
        back until the next page (or the end) decides its step. A pair of consecutive pages breaks
        the segment on a sequence gap, a time jump, skipped pages or skipped text; a page followed by
        a break takes the previous step of its segment, or 300/rate.
        """
        tz_ns = self.info.timezone_offset_s * 10**9
        nominal_rate = self.info.sample_rate_nominal
        tol = self.time_tolerance
        per_page = GNA_SAMPLES_PER_PAGE
        header_freq_text = self.header.get("Measurement Frequency", "Configuration Info")
        freq_warned = False
        held: Optional[_Run] = None  # the last page seen (one-page run), its step not known yet
        held_prev_step: Optional[int] = None  # step of the page before `held`, same segment
        skipped = 0  # pages skipped since `held`
        desynced = False  # non-page text skipped since `held`
        segment = 0
        self._pending: list = []  # (run, lo, hi, steps, segments) awaiting emission
        self._pending_pages = 0

        for item in self._pages():
            if isinstance(item, _Skip):
                if item.desync:
                    desynced = True
                    self._list_events(item.index - 1)  # page item.index is still to come
                else:
                    skipped += 1
                    self._list_events(item.index)
                continue
            upto = int(item.index[-1])  # every event of pages <= upto is logged once this item is done
            run = self._sanitise(item)
            if run is None:
                self._list_events(upto)
                continue
            if not freq_warned and nominal_rate:
                bad = np.flatnonzero(np.isfinite(run.freq)
                                     & (np.abs(run.freq - nominal_rate) > 1e-6 * nominal_rate))
                if bad.size:
                    freq_warned = True
                    self._event(int(run.index[bad[0]]), "frequency_mismatch",
                                f"page Measurement Frequency {run.freq[bad[0]]:g} Hz differs from the "
                                f"header's {header_freq_text!r}; pages are timed with their own value")
            h = 1 if held is not None else 0
            cat = np.concatenate
            seq = cat([held.seq, run.seq]) if held is not None else run.seq
            t = cat([held.t_ms, run.t_ms]) if held is not None else run.t_ms
            freq = cat([held.freq, run.freq]) if held is not None else run.freq
            q = seq.shape[0]
            expect = self._nominal_steps(freq[:-1])
            step = (t[1:] - t[:-1]) * 1_000_000
            mult = np.ones(q - 1, np.int64)
            if h:
                mult[0] += skipped  # after skipped pages, expect as many more pages
            seq_bad = seq[1:] != seq[:-1] + mult
            time_bad = np.abs(step - mult * expect) > np.maximum(2_000_000, tol * expect)
            if h and desynced:  # how many pages the skipped text held is unknown: no checks
                seq_bad[0] = time_bad[0] = False
            brk = seq_bad | time_bad
            if h and (skipped or desynced):
                brk[0] = True
            # steps of pages 0..q-2: their own, or (before a break) the previous step of the segment
            prev_in_seg = np.empty(q - 1, np.int64)
            if q > 1:
                prev_in_seg[0] = held_prev_step if (h and held_prev_step is not None) else expect[0]
                prev_in_seg[1:] = np.where(brk[:-1], expect[1:], step[:-1])
            steps = np.where(brk, prev_in_seg, step)
            segs = segment + cat([[0], np.cumsum(brk)]).astype(np.int64)
            for k in np.flatnonzero(seq_bad | time_bad).tolist():
                pidx = int(run.index[k + 1 - h])
                when = int(t[k + 1]) * 1_000_000 - tz_ns
                if seq_bad[k]:
                    self._event(pidx, "sequence_gap",
                                f"Sequence Number {seq[k]} -> {seq[k + 1]}; new segment", time_ns=when)
                if time_bad[k]:
                    self._event(pidx, "time_jump",
                                f"Page Time step {step[k] / 1e9:.3f} s where {per_page} samples at "
                                f"{(freq[k + 1] if np.isfinite(freq[k + 1]) else nominal_rate):g} Hz "
                                f"take {expect[k] / 1e9:.3f} s; new segment", time_ns=when)
            # everything but the last page is timed now
            if held is not None:
                self._queue(held, 0, 1, steps[:1], segs[:1])
            if run.pages > 1:
                self._queue(run, 0, run.pages - 1, steps[h:], segs[h:-1])
            last = run.pages - 1
            held = _slice_run(run, last, last + 1)
            held_prev_step = int(step[-1]) if (q > 1 and not brk[-1]) else None
            segment = int(segs[-1])
            skipped, desynced = 0, False
            self._list_events(upto)
            while self._pending_pages >= self.batch_pages:
                yield from self._emit(self.batch_pages, tz_ns)
        self._list_events()
        if held is not None:
            step = held_prev_step if held_prev_step is not None else int(self._nominal_steps(held.freq)[0])
            self._queue(held, 0, 1, np.array([step], np.int64), np.array([segment], np.int64))
        while self._pending_pages:
            yield from self._emit(self.batch_pages, tz_ns)
        self.qc.segments = segment + 1 if (held is not None) else 0
        n_hdr = self.info.header.get("number_of_pages")
        if n_hdr is not None and n_hdr != self.qc.total:
            self._event(self.qc.total, "page_count_mismatch",
                        f"header Number of Pages is {n_hdr}, the file holds {self.qc.total}", always=True)
            self._list_events()
        if self.qc.valid == 0 and self.qc.events and any(
                e.reason not in _NOT_PAGE_REASONS for e in self.qc.events):
            counts: dict[str, int] = {}
            for e in self.qc.events:
                if e.reason not in _NOT_PAGE_REASONS:
                    counts[e.reason] = counts.get(e.reason, 0) + 1
            why = ", ".join(f"{k} x{v}" for k, v in counts.items())
            raise CorruptRecordingError(
                self.path, f"none of the {self.qc.total} page(s) after the header is readable ({why})")

    def _queue(self, run: _Run, lo: int, hi: int, steps: np.ndarray, segs: np.ndarray) -> None:
        if hi > lo:
            self._pending.append((run, lo, hi, steps, segs))
            self._pending_pages += hi - lo

    def _emit(self, max_pages: int, tz_ns: int) -> Iterator[Block]:
        """Take up to ``max_pages`` timed pages off the queue; one Block per segment among them."""
        take, need = [], max_pages
        while need and self._pending:
            run, lo, hi, steps, segs = self._pending[0]
            n = min(need, hi - lo)
            take.append((run, lo, lo + n, steps[:n], segs[:n]))
            if n == hi - lo:
                self._pending.pop(0)
            else:
                self._pending[0] = (run, lo + n, hi, steps[n:], segs[n:])
            need -= n
            self._pending_pages -= n
        # split the taken pages where the segment changes
        parts: list = []
        for run, lo, hi, steps, segs in take:
            cuts = np.flatnonzero(segs[1:] != segs[:-1]) + 1
            edges = [0] + cuts.tolist() + [hi - lo]
            for a, b in zip(edges[:-1], edges[1:]):
                seg = int(segs[a])
                if parts and parts[-1][0] == seg:
                    parts[-1][1].append((run, lo + a, lo + b, steps[a:b]))
                else:
                    parts.append((seg, [(run, lo + a, lo + b, steps[a:b])]))
        for seg, pieces in parts:
            yield self._block(pieces, seg, tz_ns)

    def _block(self, pieces, segment: int, tz_ns: int) -> Block:
        cat = np.concatenate
        counts = cat([r.counts[lo:hi] for r, lo, hi, _ in pieces])
        starts = cat([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
        t0 = cat([r.t_ms[lo:hi] for r, lo, hi, _ in pieces]) * 1_000_000 - tz_ns
        steps = cat([s for _, _, _, s in pieces]).astype(np.int64)
        n = int(counts.sum())
        within = np.arange(n, dtype=np.int64) - np.repeat(starts, counts)
        # linear between page anchors: t_k + i * step_k / 300 (floor to whole ns)
        time_ns = np.repeat(t0, counts) + (within * np.repeat(steps, counts)) // GNA_SAMPLES_PER_PAGE
        sl = []
        for r, lo, hi, _ in pieces:
            off = r.offsets()
            sl.append((r, int(off[lo]), int(off[hi])))
        accel = cat([r.accel[a:b] for r, a, b in sl])
        light = cat([r.light[a:b] for r, a, b in sl])
        button = cat([r.button[a:b] for r, a, b in sl])
        hdr = self.info.header
        counts_per_g, zero = gna_accel_scale(hdr["gains"], hdr["offsets"])
        block = Block(
            time_ns=time_ns,
            accel=accel,
            accel_counts_per_g=counts_per_g,
            accel_zero=zero,
            unit_index=cat([r.index[lo:hi] for r, lo, hi, _ in pieces]).astype(np.int64),
            unit_sequence=cat([r.seq[lo:hi] for r, lo, hi, _ in pieces]).astype(np.int64),
            unit_start=starts,
            temperature_c=cat([r.temperature[lo:hi] for r, lo, hi, _ in pieces]).astype(np.float64),
            temperature_raw=np.full(counts.shape[0], -1, np.int32),
            light=light[starts].astype(np.int32),
            battery_v=cat([r.battery[lo:hi] for r, lo, hi, _ in pieces]).astype(np.float64),
            events=np.zeros(counts.shape[0], np.uint8),
            per_sample={PER_SAMPLE_LIGHT_RAW: light, PER_SAMPLE_BUTTON: button},
            segment=segment,
            first_sample=self._samples,
        )
        self._samples += n
        return block

    # ------------------------------------------------------------------ page parsing
    def _pages(self) -> Iterator[Union[_Run, _Skip]]:
        """Pages in file order (decoded) and _Skip markers, from the byte stream in batches."""
        chunk_bytes = self.batch_pages * APPROX_PAGE_BYTES
        buf = self._rest
        self._rest = b""
        eof = False
        index = 0  # page position in the file
        while True:
            if not eof:
                chunk = read_exact(self._f, chunk_bytes) if not isinstance(self._f, FollowingReader) \
                    else self._f.read(chunk_bytes)
                if not chunk:
                    eof = True
                    why = stream_damage(self._f)
                    if why:  # damaged gzip / follow-mode idle stop: every byte before it is used
                        reason = "follow_idle_stop" if getattr(self._f, "idle_stop", None) else "read_error"
                        self._event(index, reason, f"reading stopped: {why}", always=True)
                else:
                    buf = buf + chunk if buf else chunk
            if eof and not buf:
                return
            lines = buf.split(b"\n")
            self._ends_with_newline = buf.endswith(b"\n")
            if eof:
                if lines and lines[-1] == b"":
                    lines.pop()
                tail = b""
            else:
                tail = lines.pop()
                if len(tail) > MAX_LINE_BYTES:
                    # no line break for far longer than any page line: parse it now as a (bad) line
                    # so the buffer stays bounded; the desync scan skips and logs it
                    lines.append(tail)
                    tail = None
            items, consumed, index = self._parse_lines(lines, index, eof)
            yield from items
            if eof:
                return
            rest = lines[consumed:]
            if tail is not None:
                rest.append(tail)
            buf = b"\n".join(rest)

    def _parse_lines(self, lines: list[bytes], index: int, eof: bool):
        """Parse complete lines into pages. Returns (items, lines consumed, next page index).

        Stops before an incomplete page unless at end of file.
        """
        out: list[Union[_Run, _Skip, None]] = []  # None: a page decoded later, in a batch
        cand: list[tuple] = []  # (index, fields, hex, partial, position in out)
        L = len(lines)
        i = 0
        while i < L:
            line = lines[i]
            if not (line == _MARKER or line == _MARKER_CR or line.strip(_VALUE_STRIP) == _MARKER):
                j = i + 1
                while j < L and not (lines[j] == _MARKER or lines[j] == _MARKER_CR
                                     or lines[j].strip(_VALUE_STRIP) == _MARKER):
                    j += 1
                if j == L and not eof:
                    skipped_bytes = sum(len(x) + 1 for x in lines[i:j])
                    if skipped_bytes < 4 * self.batch_pages * APPROX_PAGE_BYTES:
                        break  # wait for more bytes: the next marker may still come
                nbytes = sum(len(x) + 1 for x in lines[i:j])
                if any(x.strip(_VALUE_STRIP) for x in lines[i:j]):
                    nlines = j - i
                    if self._desync_open:
                        # the same stretch of non-page text, seen over several reads: one event (it
                        # waits unlisted until page `index` is done; see _blocks)
                        open_at = [k for k, (e, _) in enumerate(self._unlisted)
                                   if e.reason == "desync" and e.index == index]
                        if open_at:
                            del self._unlisted[open_at[-1]]
                            nlines += self._desync_open[0]
                            nbytes += self._desync_open[1]
                    self._desync_open = (nlines, nbytes)
                    where = "at the end of the file" if (j == L and eof) else f"before page {index}"
                    self._event(index, "desync",
                                f"skipped {nlines} line(s), {nbytes} bytes, that are not a page "
                                f"{where}; resynchronised on the next '{GNA_PAGE_MARKER}' line")
                    out.append(_Skip(index, desync=True))
                i = j
                continue
            # a page: key:value lines up to the hex line
            self._desync_open = None
            if not cand:  # fast path for a run of standard 10-line pages (keeps the order of `out`)
                n_fast = self._fast_pages(lines, i, L, index, out)
                if n_fast:
                    i += 10 * n_fast
                    index += n_fast
                    continue
            k = i + 1
            fields: dict[bytes, bytes] = {}
            while k < L and k - i <= MAX_PAGE_FIELD_LINES:
                ln = lines[k]
                key, sep, value = ln.partition(b":")
                # the data line: the first line that is not "key:value" (or too long to be one, e.g.
                # a hex line with a damaged character that happens to be a colon)
                if not sep or len(ln) > MAX_FIELD_LINE_BYTES or ln.strip(_VALUE_STRIP) == _MARKER:
                    break
                fields[key] = value
                k += 1
            if k >= L:
                if not eof:
                    break  # page not complete yet
                self.qc.total += 1
                self.qc.skipped += 1
                self._event(index, "truncated_page",
                            "the file ends inside the page's text lines, before its data line")
                out.append(_Skip(index))
                index += 1
                i = k
                continue
            hexline = _data_chars(lines[k])
            nchar = len(hexline)
            if nchar < PAGE_HEX_CHARS and k == L - 1 and not eof:
                break  # a short data line may be the last page: decide once the next bytes (or EOF) come
            self.qc.total += 1
            if hexline.strip(_VALUE_STRIP) == _MARKER or k - i > MAX_PAGE_FIELD_LINES:
                self.qc.skipped += 1
                self._event(index, "bad_page", "the page has no data line")
                out.append(_Skip(index))
                index += 1
                i = k
                continue
            last_line = eof and k == L - 1
            if nchar == PAGE_HEX_CHARS:
                cand.append((index, fields, hexline, False, len(out)))
                out.append(None)  # placeholder, filled after vectorised decode
            elif last_line and GNA_HEX_PER_SAMPLE <= nchar < PAGE_HEX_CHARS:
                cand.append((index, fields, hexline, "terminated" if self._ends_with_newline else "cut",
                             len(out)))
                out.append(None)
            else:
                self.qc.skipped += 1
                self._event(index, "bad_page_length",
                            f"data line has {nchar} characters, expected {PAGE_HEX_CHARS}",
                            samples=min(nchar // GNA_HEX_PER_SAMPLE, GNA_SAMPLES_PER_PAGE))
                out.append(_Skip(index))
            index += 1
            i = k + 1
        self._decode_candidates(cand, out)
        return _merge_runs(out), i, index

    def _fast_pages(self, lines: list[bytes], i: int, L: int, index: int, out: list) -> int:
        """Decode the run of standard pages starting at line ``i`` with whole-run numpy operations.

        A standard page is exactly: marker, serial, Sequence Number, Page Time, Unassigned,
        Temperature, Battery voltage, Device Status, Measurement Frequency, 3600 hex characters
        (all lines ending alike). Returns how many pages were handled (0: use the general parser).
        """
        cr = lines[i].endswith(b"\r")
        marker = _MARKER_CR if cr else _MARKER
        P = (L - i) // 10
        if P < 2:
            return 0
        end = i + 10 * P
        rep = itertools.repeat
        ok = np.fromiter(map(marker.__eq__, lines[i:end:10]), bool, P)
        # the data line: exactly PAGE_HEX_CHARS characters once _data_chars has taken its line ending
        # off, i.e. ending in CR exactly when the marker line does (any other last byte is damage)
        ok &= np.fromiter(map(len, lines[i + 9:end:10]), np.int64, P) == PAGE_HEX_CHARS + cr
        ok &= np.fromiter(map(bytes.endswith, lines[i + 9:end:10], rep(b"\r")), bool, P) == cr
        for off, key in _FAST_KEYS:
            ok &= np.fromiter(map(bytes.startswith, lines[i + off:end:10], rep(key)), bool, P)
            # as in the general parser, a line longer than MAX_FIELD_LINE_BYTES is never a
            # key:value line (it ends the page's text lines as its data line)
            ok &= np.fromiter(map(len, lines[i + off:end:10]), np.int64, P) <= MAX_FIELD_LINE_BYTES
        # the serial line must name the header's device (else the general parser logs it)
        serial = self._serial_line_cr if cr else self._serial_line
        ok &= np.fromiter(map(serial.__eq__, lines[i + 1:end:10]), bool, P)
        bad = np.flatnonzero(~ok)
        P = int(bad[0]) if bad.size else P
        if P < 2:
            return 0
        end = i + 10 * P
        cut = -1 if cr else None

        def values(off: int, key: bytes) -> bytes:
            text = b"\n".join(lines[i + off:end:10])
            # CR only as the line ending (one per line, at its end): anything else -> general parser
            if text.count(b"\r") != (P if cr else 0) or (cr and not all(
                    map(bytes.endswith, lines[i + off:end:10], rep(b"\r")))):
                raise ValueError("stray CR")
            if text.count(key) != P:  # each line starts with the key (checked); nowhere else
                raise ValueError("key repeated inside a value")
            return text.replace(key, b"").replace(b"\r", b"")

        try:
            seq = np.array(values(2, b"Sequence Number:").split()).astype(np.int64)
            # numbers may use a comma decimal separator ("21,5"), as parse_number accepts
            temp = np.array(values(5, b"Temperature:").replace(b",", b".").split()).astype(np.float64)
            batt = np.array(values(6, b"Battery voltage:").replace(b",", b".").split()).astype(np.float64)
            freq = np.array(values(8, b"Measurement Frequency:").replace(b",", b".").split()
                            ).astype(np.float64)
            tbytes = values(3, b"Page Time:")
            if seq.size and (seq.min() < 0 or seq.max() >= 2**62):
                return 0  # the general parser logs the out-of-range Sequence Number
            if not (seq.shape[0] == temp.shape[0] == batt.shape[0] == freq.shape[0] == P
                    and len(tbytes) == 24 * P - 1):
                return 0
        except (ValueError, OverflowError):
            return 0  # comma decimals, empty values, huge numbers...: the general parser handles them
        tms, tok = parse_times_ms(tbytes.split(b"\n"))
        freq = np.where(np.abs(freq - 85.7) < 1e-6, GNA_RATE_85_7, freq)
        hexes = np.frombuffer(b"".join(lines[i + 9:end:10]), np.uint8).reshape(P, -1)[:, :cut]
        acc, light, button, badhex = decode_hex_samples(np.ascontiguousarray(hexes), P * GNA_SAMPLES_PER_PAGE)
        badpage = badhex.reshape(P, GNA_SAMPLES_PER_PAGE).any(axis=1) if badhex.any() else np.zeros(P, bool)
        self.qc.total += P
        good = ~badpage & tok
        index_arr = np.arange(index, index + P, dtype=np.int64)
        counts = np.full(P, GNA_SAMPLES_PER_PAGE, np.int64)
        per = GNA_SAMPLES_PER_PAGE
        j = 0
        while j < P:  # runs of good pages, and the bad pages between them, in file order
            if good[j]:
                k = j
                while k < P and good[k]:
                    k += 1
                out.append(_Run(index_arr[j:k], seq[j:k], tms[j:k], temp[j:k], batt[j:k], freq[j:k],
                                counts[j:k], acc[j * per:k * per], light[j * per:k * per],
                                button[j * per:k * per]))
                self.qc.valid += k - j
                j = k
                continue
            self.qc.skipped += 1
            if badpage[j]:
                self._event(index + j, "bad_hex", "data line holds characters that are not hex digits",
                            samples=GNA_SAMPLES_PER_PAGE)
            else:
                v = lines[i + 10 * j + 3].strip(_VALUE_STRIP)[10:].decode("latin-1")
                self._event(index + j, "bad_page_time", f"Page Time {v!r} is not a valid time",
                            samples=GNA_SAMPLES_PER_PAGE)
            out.append(_Skip(index + j))
            j += 1
        return P

    def _decode_candidates(self, cand, out) -> None:
        if not cand:
            return
        full = [c for c in cand if not c[3]]
        decoded: dict[int, tuple] = {}
        if full:
            acc, light, button, bad = decode_hex_samples(b"".join(c[2] for c in full),
                                                         len(full) * GNA_SAMPLES_PER_PAGE)
            P = len(full)
            acc = acc.reshape(P, GNA_SAMPLES_PER_PAGE, 3)
            light = light.reshape(P, GNA_SAMPLES_PER_PAGE)
            button = button.reshape(P, GNA_SAMPLES_PER_PAGE)
            bad_page = bad.reshape(P, GNA_SAMPLES_PER_PAGE).any(axis=1)
            for j, c in enumerate(full):
                decoded[c[0]] = (acc[j], light[j], button[j], bool(bad_page[j]))
        for c in cand:
            if c[3]:
                n = len(c[2]) // GNA_HEX_PER_SAMPLE
                acc, light, button, bad = decode_hex_samples(c[2], n)
                decoded[c[0]] = (acc, light, button, bool(bad.any()))
        # page times: vectorised for the standard fixed-width form, per page otherwise
        tvals = [c[1].get(b"Page Time", b"").strip(_VALUE_STRIP) for c in cand]
        parsed = parse_times_ms(tvals)
        tms = [int(t) if ok else None for t, ok in zip(parsed[0].tolist(), parsed[1].tolist())]
        freq_cache: dict[bytes, Optional[float]] = {}
        for c, t in zip(cand, tms):
            index, fields, hexline, partial, pos = c
            acc, light, button, bad = decoded[index]
            n = acc.shape[0]
            reason: Optional[str] = None
            detail = ""
            if bad:
                reason, detail = "bad_hex", "data line holds characters that are not hex digits"
            elif t is None:
                v = fields.get(b"Page Time")
                reason = "bad_page_time"
                detail = ("no Page Time line" if v is None
                          else f"Page Time {v.strip(_VALUE_STRIP).decode('latin-1')!r} is not a valid time")
            else:
                try:
                    seq = int(fields[b"Sequence Number"].strip(_VALUE_STRIP))
                    if not 0 <= seq < 2**62:
                        reason, detail = "bad_page_header", f"Sequence Number {seq} is out of range"
                except (KeyError, ValueError):
                    reason, detail = "bad_page_header", "Sequence Number missing or not an integer"
            if reason:
                self.qc.skipped += 1
                self._event(index, reason, detail, samples=n)
                out[pos] = _Skip(index)
                continue
            fv = fields.get(b"Measurement Frequency")
            if fv not in freq_cache:
                try:
                    freq_cache[fv] = gna_rate_hz(fv.strip(_VALUE_STRIP).decode("latin-1")) if fv else None
                except (ValueError, IndexError):
                    freq_cache[fv] = None
            sv = fields.get(b"Device Unique Serial Code")
            if sv is not None and sv.strip(_VALUE_STRIP) != self._serial and not self._serial_warned:
                self._serial_warned = True
                self._event(index, "serial_mismatch",
                            f"page Device Unique Serial Code {sv.strip(_VALUE_STRIP).decode('latin-1')!r} "
                            f"differs from the header's {self.info.device_id!r} (logged once); "
                            "the page is kept")
            self.qc.valid += 1
            if partial == "cut":
                self._event(index, "truncated_page",
                            f"the file ends inside the data line: {n} of {GNA_SAMPLES_PER_PAGE} samples "
                            f"({len(hexline)} of {PAGE_HEX_CHARS} hex characters); "
                            "the complete samples are returned")
            elif partial:
                self._event(index, "partial_page",
                            f"the last page holds {n} of {GNA_SAMPLES_PER_PAGE} samples "
                            f"({len(hexline)} hex characters); they are returned")
            out[pos] = _Run.single(index, seq, t, _num(fields.get(b"Temperature")),
                                   _num(fields.get(b"Battery voltage")), freq_cache[fv], acc, light, button)


_NUM_CACHE: dict[bytes, float] = {}


def _num(v: Optional[bytes]) -> float:
    """A page's number field (comma decimals allowed); NaN when absent or unreadable. Cached: the
    same few temperature/battery strings repeat over a recording."""
    if v is None:
        return float("nan")
    x = _NUM_CACHE.get(v)
    if x is None:
        try:
            x = parse_number(v.decode("latin-1"))
        except (ValueError, IndexError):
            x = float("nan")
        if len(_NUM_CACHE) < 100_000:
            _NUM_CACHE[v] = x
    return x


# ---------------------------------------------------------------------- header
def _read_header(f, path: Path) -> tuple[GeneactivHeader, bytes]:
    """Read up to the first "Recorded Data" line. Returns (header, bytes from that line on)."""
    buf = read_exact(f, 4096)
    if not buf:
        raise TruncatedRecordingError(path, "file is empty")
    head = buf.lstrip(b"\xef\xbb\xbf")
    if not head.startswith(b"Device Identity"):
        if head.startswith(b"GENEA"):
            raise UnsupportedFormatError(
                path, "this is an original GENEA (2010) file, not GENEActiv .bin; it is not supported")
        raise UnsupportedFormatError(
            path, f"not a GENEActiv .bin file: it must start with 'Device Identity', first bytes are "
                  f"{head[:16]!r}")
    buf = head
    while True:
        m = _MARKER_RE.search(buf)
        if m:
            start = m.start() + (1 if buf[m.start():m.start() + 1] == b"\n" else 0)
            text, rest = buf[:start], buf[start:]
            break
        if len(buf) > HEADER_LIMIT_BYTES:
            raise CorruptRecordingError(
                path, f"no '{GNA_PAGE_MARKER}' line in the first {HEADER_LIMIT_BYTES} bytes: "
                      "the header never ends")
        more = f.read(65536)
        if not more:
            text, rest = buf, b""
            break
        buf += more
    try:
        decoded = text.decode("utf-8")
    except UnicodeDecodeError:
        decoded = text.decode("latin-1")
    hdr = parse_header_text(decoded)
    missing = [k for k in CALIBRATION_KEYS if hdr.get(k, "Calibration Data") in (None, "")]
    if missing:
        n_lines = decoded.count("\n") + 1
        if not rest:
            raise TruncatedRecordingError(
                path, f"header ends early after {n_lines} line(s): missing {', '.join(missing)} "
                      "(Calibration Data)", where="header")
        raise CorruptRecordingError(path, f"header lacks {', '.join(missing)} (Calibration Data)",
                                    where="header")
    if not rest and "Memory Status" not in hdr.sections:
        n_lines = decoded.count("\n") + 1
        raise TruncatedRecordingError(
            path, f"header ends early after {n_lines} line(s): no 'Memory Status' section and no pages",
            where="header")
    return hdr, rest


def _light_calibration(hdr: GeneactivHeader) -> tuple[Optional[float], Optional[float], list]:
    """(Volts, Lux, faults) of the header's Calibration Data. Light in lux is raw * Lux / Volts
    ([GNA] §5), so each must be a number within GNA_LIGHT_CAL_RANGE; otherwise both are None (the
    light in lux is blank) and ``faults`` says which value and why (the reader logs each as a
    ``header_value`` QC event)."""
    values = {}
    for key in ("Volts", "Lux"):
        text = hdr.get(key, "Calibration Data")
        try:
            values[key] = parse_number(text)
        except (ValueError, IndexError, AttributeError):
            why = "missing" if text in (None, "") else f"{text!r} is not a number"
            return None, None, [f"Calibration Data: {key} {why}; light in lux unavailable"]
    lo, hi = GNA_LIGHT_CAL_RANGE
    bad = [k for k, v in values.items() if not lo <= v <= hi]  # NaN is not within either
    if bad:
        k = bad[0]
        return None, None, [f"Calibration Data: {k} {values[k]:g} is not a light calibration "
                            f"({lo:g}..{hi:g}); light in lux unavailable"]
    return values["Volts"], values["Lux"], []


def _device_info(hdr: GeneactivHeader, path: Path, timezone, rest: bytes = b"") -> DeviceInfo:
    warnings = hdr.warnings
    gains, offsets = [], []
    for axis in "xyz":
        try:
            gf = parse_number(hdr.get(f"{axis} gain", "Calibration Data"))
            of = parse_number(hdr.get(f"{axis} offset", "Calibration Data"))
        except (ValueError, IndexError, AttributeError):
            raise CorruptRecordingError(path, f"Calibration Data: {axis} gain/offset is not a number",
                                        where="header") from None
        if not (np.isfinite(gf) and 0 < gf <= GNA_GAIN_MAX):
            raise CorruptRecordingError(path, f"Calibration Data: {axis} gain is {gf:g}, must be in "
                                              f"(0, {GNA_GAIN_MAX}]", where="header")
        if not (np.isfinite(of) and abs(of) <= GNA_OFFSET_MAX):
            raise CorruptRecordingError(path, f"Calibration Data: {axis} offset is {of:g}, must be "
                                              f"within +-{GNA_OFFSET_MAX}", where="header")
        g, o = int(round(gf)), int(round(of))
        if g <= 0:
            raise CorruptRecordingError(path, f"Calibration Data: {axis} gain is {g}, must be > 0",
                                        where="header")
        gains.append(g)
        offsets.append(o)
    volts, lux, faults = _light_calibration(hdr)
    warnings.extend(faults)
    if timezone is not None:
        try:
            tz = parse_timezone(timezone)
        except ValueError as e:
            raise ValueError(f"timezone override: {e}") from None
    else:
        tzv = hdr.get("Time Zone", "Configuration Info")
        try:
            tz = parse_timezone(tzv)
        except ValueError as e:
            raise CorruptRecordingError(
                path, f"Configuration Info: {e}; pass timezone= (CLI --timezone) to set it",
                where="header") from None
    rate = header_rate_hz(hdr)
    lo, hi = PLAUSIBLE_RATE_HZ
    if rate is None or not lo <= rate <= hi:
        bad_header = rate
        rate = None
        m = re.search(rb"Measurement Frequency:([^\r\n]*)", rest[:8192])
        try:
            rate = gna_rate_hz(m.group(1).strip(_VALUE_STRIP).decode("latin-1")) if m else None
        except (ValueError, IndexError):
            rate = None
        if rate is None or not lo <= rate <= hi:
            what = ("no readable Measurement Frequency" if bad_header is None and rate is None else
                    f"Measurement Frequency {bad_header if bad_header is not None else rate:g} Hz is "
                    f"not a plausible rate ({lo:g}..{hi:g} Hz)")
            raise CorruptRecordingError(path, f"{what} in the header or the first page",
                                        where="header")
        warnings.append("Configuration Info: Measurement Frequency " +
                        ("missing" if bad_header is None else f"{bad_header:g} Hz is not plausible") +
                        f"; {rate:g} Hz taken from the first page")
    start_text = hdr.get("Start Time", "Configuration Info")
    start_ms = parse_time_ms(start_text) if start_text else None
    if start_text and start_ms is None:
        warnings.append(f"Configuration Info: Start Time {start_text!r} is not a valid time "
                        "(sample times come from the pages' Page Time)")
    n_pages = None
    npv = hdr.get("Number of Pages", "Memory Status")
    if npv:
        try:
            n_pages = int(npv.split()[0])
        except ValueError:
            warnings.append(f"Memory Status: Number of Pages {npv!r} is not an integer")
    drift = re.search(r"clock drift\s*([-+]?\d+(?:[.,]\d+)?)\s*s", hdr.get("Extract Notes", "Trial Info") or "")
    header: dict = hdr.flat()
    header.update({
        # the vendor software notes the device clock's drift at extraction, e.g. "(device clock drift
        # -1.459s)"; reported here, not applied
        "clock_drift_s": float(drift.group(1).replace(",", ".")) if drift else None,
        "gains": tuple(gains), "offsets": tuple(offsets), "volts": volts, "lux": lux,
        "model": hdr.get("Device Model", "Device Identity", ""),
        "number_of_pages": n_pages,
        "start_time_ns": None if start_ms is None else (start_ms * 1_000_000 - tz * 10**9),
        "header_lines": hdr.lines,
        "warnings": warnings,
        "channel_faults": faults,  # header values that leave a channel blank (QC events when read)
    })
    metadata = {}
    for k in TRIAL_KEYS + SUBJECT_KEYS:
        v = hdr.get(k)
        if v:
            metadata[k] = v
    return DeviceInfo(
        device_type="GENEActiv",
        device_id=hdr.get("Device Unique Serial Code", "Device Identity", "") or "",
        session_id=None,
        firmware=hdr.get("Device Firmware Version", "Device Identity", "") or "",
        sample_rate_nominal=rate,
        accel_range_g=header_range_g(hdr),
        channels=("accel_x", "accel_y", "accel_z"),
        timezone_offset_s=tz,
        metadata=metadata,
        header=header,
        path=str(path),
    )


def read_header(path, *, timezone=None) -> DeviceInfo:
    """DeviceInfo from the header only (fast: reads no pages)."""
    p = Path(path)
    check_recording_path(p)
    with open_bytes(p) as f:
        hdr, rest = _read_header(f, p)
        return _device_info(hdr, p, timezone, rest)


def _late_import_writer():
    from .geneactiv_writer import GeneactivWriter as W
    return W


def __getattr__(name):  # lazy re-export keeps the reader importable on its own
    if name == "GeneactivWriter":
        return _late_import_writer()
    raise AttributeError(name)

