"""Streaming reader for AX3/AX6 ``.cwa`` recordings (a ``Source``): sectors in, Blocks out.

``CwaReader(path, timezone=0, batch_sectors=2048, follow=False, follow_idle_s=5.0, decode=True)``
reads ``batch_sectors`` 512-byte sectors at a time into one reusable buffer, classifies and decodes
them with numpy (``cwa_decode``), splits the valid sectors into *segments* and times every sample
from the sector anchors (cwa-format.md §7.2: piecewise-linear through the anchors, extrapolated
at a segment's ends with the neighbouring slope, nominal 1/f if a segment has one anchor).
Memory is flat in file length; results do not depend on ``batch_sectors``.

Rules (cwa-format.md §8), each recorded in ``.qc`` (QCReport, unit "sector", index = data-sector
index in the file, 0 = the sector right after the 1024-byte header):

* skipped, samples dropped: ``checksum``, ``bad_tag``, ``bad_length``, ``bad_format`` (unknown
  packing/channels, rate code 0), ``empty``, ``header_sector``, ``legacy_sector``, ``erased``
  (runs of erased sectors are one event), ``duplicate`` (byte-identical copy of the previous
  valid sector), ``untimed`` (a segment without any usable timestamp);
* a new segment starts (no samples dropped): ``restart`` (sequence id back to 0),
  ``session_change``, ``format_change`` (rate code, packing/channels or scale codes),
  ``sequence_gap`` (any step other than +1, incl. out-of-order and repeated ids), ``time_jump``
  (anchor times disagree with the nominal rate by more than 10 % + 50 ms, or do not increase);
* logged: ``rate_mismatch`` (the header's rate differs from the first valid sector's rate code:
  the sectors' rate is ``info.sample_rate_nominal``);
* kept, flagged: ``bad_timestamp`` (invalid date or 0: the sector's anchor is ignored, its samples
  are timed from the neighbouring anchors), ``bad_anchor`` (anchor index not after the previous
  one), ``bad_count`` (sampleCount above capacity, clamped), ``device_overflow`` (event bits 0x10/0x20:
  the device lost samples), ``axis_swap`` (AX6 firmware < 56: accel/gyro triplets look swapped;
  the data are not changed), ``truncated`` (file ends inside a sector), ``read_error`` (a damaged
  or truncated gzip stream: everything decompressible before it is returned),
  ``follow_idle_stop`` (follow mode stopped after ``follow_idle_s`` without growth).

Every event carries ``time_ns``: the anchor time for a segment break, otherwise the data time next
to it (interpolated by sector index inside a Block, else the last valid sample before it). Events
beyond ``MAX_QC_EVENTS`` are counted in total/skipped but not listed (memory stays flat).

A file in which not a single data sector is valid raises ``CorruptRecordingError`` at the end of
iteration (after ``.qc`` is complete); a file with a header and no data sectors yields no Blocks.
``follow=True`` reads a plain file that is still being written (gzip cannot be followed); it ends
after ``follow_idle_s`` seconds without growth, or once ``follow_done()`` returns True and no
more bytes arrive (``follow_done`` may raise to abandon the read). ``.info.header`` also holds an OmApi-style quick
look (``first_sector_time``, ``last_sector_time``, ``data_sectors``) from the first/last 16
sectors, for ``inspect --header-only``. Not decoded (skipped as ``bad_format``): the prototype
9-axis 0x92 format and the pre-release "rate code 0" format.
``decode=False`` skips sample decoding: Blocks carry times and per-sector data, ``accel`` has
shape (n, 0) (fast scans). ``sample_times=False`` skips timing every sample: Blocks carry
``time_ns=None`` and a ``clock`` (``cwa_decode.SampleClock``) that gives the same times for the
samples asked for (passes that only need window boundaries, such as the calibration).
``column_major=True`` decodes into column-major ``accel``/``gyro`` arrays (each axis contiguous:
quicker to decode and to take per-axis statistics from; the same values).
"""

from __future__ import annotations

import gzip
import zlib
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Iterator, Optional

import numpy as np

from stillpoint.engine.core.blocks import Block, DeviceInfo, QCEvent, QCReport
from . import constants as C
from .byteio import (FollowingReader, check_recording_path, consumed_fraction, is_gzip, open_bytes, read_exact,
                     stream_damage)
from .cwa_decode import (EMPTY, ERASED, REASONS, SampleClock, classify, decode_samples,
                         interpolate_times, max_samples, sector_anchors)
from .cwa_layout import FORMATS, SECTOR_DTYPE, parse_header, parse_timezone
from stillpoint.engine.core.errors import (CorruptRecordingError, RecordingError, TruncatedRecordingError,
                     UnsupportedFormatError)

_NS = 1_000_000_000
MAX_QC_EVENTS = 10_000  # events beyond this are counted, not listed (memory stays flat)
TIME_JUMP_REL_TOL = 0.10  # anchor spacing vs nominal rate: relative tolerance ...
TIME_JUMP_ABS_TOL_NS = 50_000_000  # ... plus an absolute slack (anchor jitter at high rates)
AXIS_SWAP_TOL_G = 0.2  # |mean vector| within 1 +- this of 1 g counts as "gravity"


# ----------------------------------------------------------------------------- header
def _open_header(path: Path, follow: bool, idle_s: float, done=None):
    check_recording_path(path, allow_empty=follow)
    if follow and path.stat().st_size >= 2 and is_gzip(path):
        raise UnsupportedFormatError(path, "follow mode reads a plain .cwa that is still being "
                                           "written; a gzip file cannot be followed")
    try:
        f = FollowingReader(path, is_done=done, idle_timeout=idle_s) if follow else open_bytes(path)
    except OSError as e:
        raise RecordingError(path, f"cannot open: {e}") from None
    return f


def _read_or_fail(path: Path, f, n: int) -> bytes:
    try:
        return read_exact(f, n)
    except (EOFError, OSError, zlib.error) as e:
        raise CorruptRecordingError(path, f"cannot read the file (damaged gzip stream?): {e}") from None


def _check_header(path: Path, head: bytes) -> None:
    if not head:
        raise TruncatedRecordingError(path, "file is empty")
    if head[:2] != b"MD":
        printable = sum(32 <= c < 127 or c in (9, 10, 13) for c in head[:256])
        kind = "a text file" if printable >= 0.95 * min(len(head), 256) else "not a CWA file"
        raise UnsupportedFormatError(
            path, f"not an AX3/AX6 .cwa recording ({kind}): expected the header tag 'MD' at "
                  f"offset 0, found {head[:8]!r}")
    if len(head) < C.CWA_HEADER_BYTES:
        raise TruncatedRecordingError(
            path, f"file ends after {len(head)} bytes, inside the {C.CWA_HEADER_BYTES}-byte header")
    length = int.from_bytes(head[2:4], "little")
    if length != 0xFFFC and (length + 4) % C.CWA_SECTOR_BYTES != 0:
        raise CorruptRecordingError(
            path, f"header length field is {length}; a CWA header has 1020 (or 0xFFFC)", "header")


def _device_info(path: Path, h: dict, tz_s: int, first_fmt: Optional[tuple]) -> DeviceInfo:
    gyro = h["gyro_range_dps"] if h["device_type"] == "AX6" else None
    channels: tuple[str, ...] = ("accel_x", "accel_y", "accel_z")
    if first_fmt is not None:
        fmt, light_scale = first_fmt
        if FORMATS[fmt][0] == 6:
            gyro = C.cwa_gyro_range_dps((light_scale >> 10) & 7)
        else:
            gyro = None
    if gyro is not None:
        channels = channels + ("gyro_x", "gyro_y", "gyro_z")
    header = {k: v for k, v in h.items() if k != "metadata"}
    header["data_format"] = None if first_fmt is None else f"0x{first_fmt[0]:02X}"
    return DeviceInfo(
        device_type=h["device_type"], device_id=str(h["device_id"]), session_id=h["session_id"],
        firmware=str(h["firmware_revision"]), sample_rate_nominal=h["sample_rate_hz"],
        accel_range_g=float(h["accel_range_g"]), gyro_range_dps=gyro, channels=channels,
        timezone_offset_s=tz_s, metadata=dict(h["metadata"]), header=header, path=str(path))


def _tail_sectors(path: Path) -> dict:
    """Data-sector count and the last valid sector among the final 16 (plain files only)."""
    size = path.stat().st_size
    n = max(0, (size - C.CWA_HEADER_BYTES) // C.CWA_SECTOR_BYTES)
    out: dict = {"data_sectors": n}
    k = min(n, 16)
    if k:
        with open(path, "rb") as f:
            f.seek(C.CWA_HEADER_BYTES + (n - k) * C.CWA_SECTOR_BYTES)
            b = f.read(k * C.CWA_SECTOR_BYTES)
        sec = np.frombuffer(b, SECTOR_DTYPE, count=len(b) // C.CWA_SECTOR_BYTES)
        ok = np.flatnonzero(classify(sec) == 0)
        if ok.size:
            out["last"] = sec[ok[-1]:ok[-1] + 1]
    return out


def _quick_span(ends: dict, tz_s: int) -> dict:
    """Header-only look at the data (as OmApi does): anchor times of the first and last valid
    sectors among the first/last 16, as ISO UTC; None when unknown (e.g. gzip: no tail seek)."""
    out = {"data_sectors": ends.get("data_sectors")}
    for key in ("first", "last"):
        iso = None
        if key in ends:
            _, t_ns, ok = sector_anchors(ends[key], tz_s)
            if ok[0]:
                iso = str(np.datetime64(int(t_ns[0]), "ns")) + "Z"
        out[f"{key}_sector_time"] = iso
    return out


def read_header(path, *, timezone=0) -> DeviceInfo:
    """Parse only the header (and peek at the first data sectors): fast ``inspect --header-only``."""
    return CwaReader(path, timezone=timezone).info


# ----------------------------------------------------------------------------- state
@dataclass
class _Segment:
    """The open (or closing) segment: samples assigned, anchors retained, chunks not yet emitted."""

    id: int
    fmt: int
    light_scale_hi: int  # lightScale >> 10 (accel and gyro scale codes)
    rate_hz: float
    n: int = 0  # samples assigned (segment-relative index of the next sector's first sample)
    emitted: int = 0  # samples already emitted (or dropped)
    origin: Optional[int] = None  # ns: time of the first accepted anchor
    ag: list = field(default_factory=list)  # retained accepted anchors: sample index
    at: list = field(default_factory=list)  # ... and time (ns)
    n_anchors: int = 0
    slope_first: Optional[float] = None  # ns per sample between the first two anchors
    chunks: list = field(default_factory=list)  # pending decoded sectors (dicts)

    @property
    def nominal_slope(self) -> float:
        return _NS / self.rate_hz


@dataclass
class _Prev:
    """The last valid sector, for segment-break and duplicate detection across batches."""

    seq: int
    session: int
    key: int
    raw: bytes


_UNIT_FIELDS = ("index", "seq", "temp", "light", "battery", "events")


class CwaReader:
    """Read a ``.cwa`` (or ``.cwa.gz``) recording as Blocks; see the module docstring."""

    _untimed: list  # positions in qc.events of events still without a time
    _last_t: Optional[int]  # time of the last sample emitted

    def __init__(self, path, *, timezone=0, batch_sectors: int = 2048, follow: bool = False,
                 follow_idle_s: float = 5.0, decode: bool = True, follow_done=None,
                 sample_times: bool = True, column_major: bool = False):
        self.path = Path(path)
        self.follow_done = follow_done  # follow: callable, True once the writer has finished
        self.tz_s = parse_timezone(timezone)
        if int(batch_sectors) < 1:
            raise ValueError("batch_sectors must be >= 1")
        self.batch_sectors = int(batch_sectors)
        self.follow = bool(follow)
        self.follow_idle_s = float(follow_idle_s)
        self.decode = bool(decode)
        self.sample_times = bool(sample_times)
        self.order = "F" if column_major else "C"
        self._force_slow = False  # testing hook: run the per-sector reference path everywhere
        f = _open_header(self.path, self.follow, self.follow_idle_s)
        try:
            head = _read_or_fail(self.path, f, C.CWA_HEADER_BYTES)
            _check_header(self.path, head)
            first_fmt = None
            first_rate = None  # (data-sector index, Hz) of the first valid sector
            ends = {}
            if not self.follow:
                peek = _read_or_fail(self.path, f, 16 * C.CWA_SECTOR_BYTES)
                k = len(peek) // C.CWA_SECTOR_BYTES
                if k:
                    sec = np.frombuffer(peek, SECTOR_DTYPE, count=k)
                    ok = np.flatnonzero(classify(sec) == 0)
                    if ok.size:
                        s = sec[ok[0]]
                        first_fmt = (int(s["num_axes_bps"]), int(s["light_scale"]))
                        first_rate = (int(ok[0]), C.cwa_rate_hz(int(s["rate_code"])))
                        ends["first"] = sec[ok[0]:ok[0] + 1]
                if not is_gzip(self.path):  # plain file: also look at the last 16 sectors
                    ends.update(_tail_sectors(self.path))
        finally:
            f.close()
        self._header = parse_header(head, self.tz_s)
        self._header.update(_quick_span(ends, self.tz_s))
        self.info = _device_info(self.path, self._header, self.tz_s, first_fmt)
        self._rate_note = None
        if first_rate is not None and first_rate[1] != self.info.sample_rate_nominal:
            # the sectors carry their own rate code: it decides (a wrong header rate would size
            # every downstream window for the wrong number of samples)
            self._header["header_rate_hz"] = self.info.sample_rate_nominal
            self._rate_note = (first_rate[0], f"the header says {self.info.sample_rate_nominal:g} Hz, "
                                              f"the data sectors {first_rate[1]:g} Hz; the sectors' "
                                              "rate is used")
            self.info = replace(self.info, sample_rate_nominal=first_rate[1],
                                header={**self.info.header, "header_rate_hz": self._header["sample_rate_hz"]})
        self.qc = QCReport(unit="sector")
        self._closed = False
        self._started = False
        self._stream = None

    # ------------------------------------------------------------------ Source API
    def close(self) -> None:
        self._closed = True
        if self._stream is not None:
            self._stream.close()
            self._stream = None

    def __enter__(self) -> "CwaReader":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def progress(self) -> Optional[float]:
        """Share of the file read so far (None before the first read, 1 once read and closed):
        for progress bars."""
        stream = getattr(self, "_stream", None)
        if stream is None:
            return 1.0 if getattr(self, "_started", False) else None
        return consumed_fraction(stream)

    def __iter__(self) -> Iterator[Block]:
        if self._started:
            raise RuntimeError("a CwaReader is single-pass; open the file again for another pass")
        self._started = True
        self._init_state()
        if self._rate_note is not None:
            self._event(self._rate_note[0], "rate_mismatch", self._rate_note[1])
        try:
            for sec, first_index, final in self._batches():
                yield from self._process(sec, first_index, final)
            if self._seg is not None:
                yield from self._close_segment()
            self._finish_swap_run()
        finally:
            self.close()
        self.qc.segments = self._n_segments
        self.qc.events.sort(key=lambda e: e.index)  # stable: batch-size independent order
        self._time_events()
        if self.qc.total and not self.qc.valid:
            counts: dict[str, int] = {}
            for e in self.qc.events:
                counts[e.reason] = counts.get(e.reason, 0) + 1
            why = ", ".join(f"{r} x{n}" for r, n in sorted(counts.items()))
            raise CorruptRecordingError(
                self.path, f"none of the {self.qc.total} data sectors is readable ({why})")

    # ------------------------------------------------------------------ state
    def _time_events(self) -> None:
        """Give every QC event without a time the data time near it: interpolated by sector index
        inside an emitted Block, else the last valid sample before it (or the first after)."""
        if not self._bounds or all(e.time_ns is not None for e in self.qc.events):
            return
        b = np.array(self._bounds, dtype=np.int64)  # (blocks, 4): first unit, t, last unit, t
        out = []
        for e in self.qc.events:
            if e.time_ns is None:
                i = int(np.searchsorted(b[:, 0], e.index, side="right")) - 1
                if i < 0:
                    t = int(b[0, 1])
                elif e.index <= b[i, 2] and b[i, 2] > b[i, 0]:
                    t = int(b[i, 1] + (e.index - b[i, 0]) * (b[i, 3] - b[i, 1]) // (b[i, 2] - b[i, 0]))
                else:
                    t = int(b[i, 3] if e.index > b[i, 2] else b[i, 1])
                e = replace(e, time_ns=t)
            out.append(e)
        self.qc.events = out

    def _time_pending(self, block: Block) -> None:
        """Time the events logged before ``block`` whose sector it reaches, exactly: a sector in
        the block -> its first sample's time; a sector skipped before it -> the last sample
        emitted before that sector. Independent of how the file was cut into batches. The start
        of an open axis-swap run is timed by the same rule as a block reaches it (its event is
        logged only when the run ends, maybe blocks later)."""
        run = self._swap_run
        if not self._untimed and (run is None or len(run) > 3):
            self._last_t = int(block.time_at(block.n - 1))
            return
        ui = block.unit_index
        first_t = block.time_at(block.unit_start)

        def sector_time(index: int) -> int:
            j = int(np.searchsorted(ui, index))
            if ui[j] == index:
                return int(first_t[j])
            if j == 0:
                return self._last_t if self._last_t is not None else int(block.time_at(0))
            return int(block.time_at(block.unit_start[j] - 1))

        keep = []
        for pos in self._untimed:
            e = self.qc.events[pos]
            if e.index > ui[-1]:
                keep.append(pos)
                continue
            self.qc.events[pos] = replace(e, time_ns=sector_time(e.index))
        self._untimed = keep
        if run is not None and len(run) == 3 and run[0] <= ui[-1]:
            run.append(sector_time(run[0]))
        self._last_t = int(block.time_at(block.n - 1))

    def _init_state(self) -> None:
        self._bounds: list = []  # per emitted Block: first sector, its time, last sector, last time
        self._untimed = []  # positions in qc.events of events still without a time
        self._last_t = None  # time of the last sample emitted
        self._seg: Optional[_Segment] = None
        self._prev: Optional[_Prev] = None
        self._n_segments = 0
        self._emitted_total = 0
        self._n_events = 0
        self._erased_run: Optional[list] = None  # [first, last] index of a run of erased sectors
        self._swap_run: Optional[list] = None  # [first, last sector, swapped seen, (first's time)]
        self._check_swap = (self.info.device_type == "AX6"
                            and self._header["firmware_revision"] < C.CWA_AX6_AXIS_SWAP_FIXED_FIRMWARE)

    def _event(self, index: int, reason: str, detail: str = "", time_ns=None, samples: int = 0):
        self._n_events += 1
        if self._n_events <= MAX_QC_EVENTS:
            if time_ns is None:
                self._untimed.append(len(self.qc.events))
            self.qc.add(QCEvent(int(index), reason, detail, None if time_ns is None else int(time_ns),
                                int(samples)))
        elif self._n_events == MAX_QC_EVENTS + 1:
            self.qc.add(QCEvent(int(index), "qc_log_truncated",
                                f"more than {MAX_QC_EVENTS} QC events; later ones are counted in "
                                "total/skipped but not listed"))

    # ------------------------------------------------------------------ bytes -> sector batches
    def _batches(self):
        """Yield (sectors view, data-sector index of the first, end of stream reached) from one
        reusable buffer."""
        self._stream = f = _open_header(self.path, self.follow, self.follow_idle_s, self.follow_done)
        _read_or_fail(self.path, f, C.CWA_HEADER_BYTES)
        size = self.batch_sectors * C.CWA_SECTOR_BYTES
        buf = np.empty(size, np.uint8)
        mv = memoryview(buf)
        have = 0
        index = 0
        while not self._closed:
            eof = False
            while have < size:
                try:
                    r = f.readinto(mv[have:])
                except (EOFError, OSError, zlib.error, gzip.BadGzipFile) as e:
                    self._event(index + have // C.CWA_SECTOR_BYTES, "read_error",
                                f"reading stopped: {e}")
                    eof = True
                    break
                if not r:
                    eof = True
                    break
                have += r
                if self.follow and have >= C.CWA_SECTOR_BYTES:
                    break
            k = have // C.CWA_SECTOR_BYTES
            if k:
                yield np.frombuffer(buf, SECTOR_DTYPE, count=k), index, eof
                index += k
                rem = have - k * C.CWA_SECTOR_BYTES
                if rem:
                    buf[:rem] = buf[k * C.CWA_SECTOR_BYTES:have]
                have = rem
            if eof:
                break
        self._flush_erased()
        why = stream_damage(f)
        if why:  # a damaged gzip stream or a follow-mode idle stop: all bytes before it were used
            reason = "follow_idle_stop" if getattr(f, "idle_stop", None) else "read_error"
            self._event(index, reason, f"reading stopped after data sector {index - 1}: {why}"
                        + (f" ({have} bytes of a partial sector follow)" if have else ""))
        if have:
            self._event(index, "truncated",
                        f"file ends {have} bytes into data sector {index}; the partial sector is ignored")

    # ------------------------------------------------------------------ one batch
    def _process(self, sec: np.ndarray, first_index: int, final: bool = False):
        k = sec.shape[0]
        self.qc.total += k
        reason = classify(sec)
        fmt = sec["num_axes_bps"]
        cap = max_samples(fmt)
        count = sec["sample_count"].astype(np.int64)
        bad = np.flatnonzero(reason)
        if bad.size:
            self._log_invalid(sec, reason, bad, first_index, cap, count)
        good = np.flatnonzero(reason == 0) if bad.size else None
        last_good = first_index + (k - 1 if good is None else (good[-1] if good.size else -1))
        if self._erased_run is not None and last_good > self._erased_run[1]:
            self._flush_erased()  # a valid sector follows the run of erased sectors
        if good is not None:
            if not good.size:
                self.qc.skipped += k
                return
            sec = sec[good]
            cap, count = cap[good], count[good]
            index = first_index + good
        else:
            index = first_index + np.arange(k, dtype=np.int64)
        over = count > cap
        if over.any():
            for i in np.flatnonzero(over):
                self._event(index[i], "bad_count",
                            f"sampleCount {count[i]} exceeds the sector capacity {cap[i]}; clamped")
            count = np.minimum(count, cap)

        # --- exact duplicates of the previous valid sector: drop
        seq = sec["sequence_id"].astype(np.int64)
        session = sec["session_id"].astype(np.int64)
        key = (sec["rate_code"].astype(np.int64) | (sec["num_axes_bps"].astype(np.int64) << 8)
               | ((sec["light_scale"].astype(np.int64) >> 10) << 16))
        prev_seq = np.empty_like(seq)
        prev_seq[1:] = seq[:-1]
        prev_seq[0] = self._prev.seq if self._prev is not None else -2
        same = np.flatnonzero(seq == prev_seq)
        if same.size:
            raw = sec.view(np.uint8).reshape(-1, 512)
            dup = np.zeros(seq.shape[0], bool)
            for i in same:
                before = raw[i - 1].tobytes() if i or self._prev is None else self._prev.raw
                if raw[i].tobytes() == before:
                    dup[i] = True
                    self._event(index[i], "duplicate",
                                f"byte-identical copy of the previous sector (sequence {seq[i]}); dropped",
                                samples=count[i])
            if dup.any():
                keep = ~dup
                self.qc.skipped += int(dup.sum())
                sec, cap, count, index = sec[keep], cap[keep], count[keep], index[keep]
                seq, session, key = seq[keep], session[keep], key[keep]
        m = sec.shape[0]
        self.qc.skipped += int(bad.size)
        if not m:
            return
        self.qc.valid += m
        aidx, at_ns, aok = sector_anchors(sec, self.tz_s)
        ls = sec["light_scale"]
        units = {
            "index": index,
            "seq": seq,
            "temp": (sec["temperature"] & 0x3FF).astype(np.int32),
            "light": (ls & 0x3FF).astype(np.int32),
            "battery": sec["battery"].copy(),  # copies: ``sec`` may view the reusable read buffer
            "events": sec["events"].copy(),
        }
        ovf = np.flatnonzero(units["events"] & (C.CWA_EVENT_FIFO_OVERFLOW | C.CWA_EVENT_BUFFER_OVERFLOW))
        for i in ovf:
            self._event(index[i], "device_overflow",
                        f"event flags 0x{units['events'][i]:02X}: the device reports lost samples")

        # --- decode samples per format run (a batch rarely holds more than one format)
        fmts = sec["num_axes_bps"]
        offsets = np.zeros(m + 1, np.int64)
        np.cumsum(count, out=offsets[1:])
        accel = gyro = None
        if self.decode:
            runs = np.flatnonzero(fmts[1:] != fmts[:-1]) + 1
            bounds = np.concatenate([[0], runs, [m]])
            parts_a, parts_g = [], []
            # a batch may mix 6-axis and 3-axis sectors (a format change, so never one segment):
            # 3-axis rows get a zero gyro placeholder that no Block ever carries
            gyro_cols = 3 if any(FORMATS[int(fmts[a])][0] == 6 for a in bounds[:-1]) else 0
            for a, b in zip(bounds[:-1], bounds[1:]):
                pa, pg = decode_samples(sec[a:b], int(fmts[a]), count[a:b], self.order)
                parts_a.append(pa)
                parts_g.append(pg if pg is not None else np.zeros((pa.shape[0], gyro_cols), np.int16))
            accel = parts_a[0] if len(parts_a) == 1 else np.concatenate(parts_a)
            gyro = parts_g[0] if len(parts_g) == 1 else np.concatenate(parts_g)
            if self._check_swap:
                self._axis_swap(index, seq, fmts, count, offsets, accel, gyro, ls)

        # --- segmentation and anchors
        rec = dict(seq=seq, session=session, key=key, count=count, aidx=aidx, at=at_ns, aok=aok,
                   fmt=fmts, ls=ls, index=index)
        plan = None if self._force_slow else self._fast_plan(rec)
        if plan is None:
            plan = self._slow_plan(rec)
        last_raw = sec[m - 1:m].tobytes()
        self._prev = _Prev(int(seq[-1]), int(session[-1]), int(key[-1]), last_raw)

        # --- attach sectors to segments and emit what is ready
        for a, b, new_seg, s0 in plan:
            if new_seg is not None:
                if self._seg is not None:
                    yield from self._close_segment()
                self._seg = new_seg
                new_seg.id = self._n_segments
                self._n_segments += 1
            seg = self._seg
            assert seg is not None  # the plan opens a segment at its first sector
            chunk = {
                "accel": None if accel is None else accel[offsets[a]:offsets[b]],
                "gyro": None if gyro is None else gyro[offsets[a]:offsets[b]],
                "j0": s0,
                "starts": offsets[a:b] - offsets[a],
                "n": int(offsets[b] - offsets[a]),
            }
            for f_ in _UNIT_FIELDS:
                chunk[f_] = units[f_][a:b]
            seg.chunks.append(chunk)
        if self._seg is not None:
            if final:  # end of the stream: the open segment ends here, emit everything at once
                yield from self._close_segment()
            else:
                yield from self._emit(self._seg, closed=False)

    # ------------------------------------------------------------------ invalid sectors
    def _log_invalid(self, sec, reason, bad, first_index, cap, count) -> None:
        for i in bad:
            r = int(reason[i])
            idx = first_index + int(i)
            if r == ERASED:
                if self._erased_run is not None and self._erased_run[1] == idx - 1:
                    self._erased_run[1] = idx
                else:
                    self._flush_erased()
                    self._erased_run = [idx, idx]
                continue
            self._flush_erased()
            s = sec[i]
            n = int(count[i]) if 0 < count[i] <= cap[i] else 0
            if r == EMPTY:
                detail = "sampleCount is 0"
            elif REASONS[r] == "checksum":
                detail = (f"16-bit word sum is {int(sec[i:i + 1].view('<u2').sum(dtype=np.uint16))}, "
                          f"not 0 (sequence field {int(s['sequence_id'])})")
            elif REASONS[r] == "bad_format":
                detail = (f"unsupported numAxesBPS 0x{int(s['num_axes_bps']):02X} / rate code "
                          f"0x{int(s['rate_code']):02X}")
            elif REASONS[r] == "bad_length":
                detail = f"packet length {int(s['length'])}, expected 508"
            else:
                detail = f"sector tag {bytes(sec[i:i + 1].view(np.uint8)[:2])!r}"
            self._event(idx, REASONS[r], detail, samples=n)

    def _flush_erased(self) -> None:
        run = self._erased_run
        if run is not None:
            self._erased_run = None
            n = run[1] - run[0] + 1
            self._event(run[0], "erased", f"{n} erased (all 0xFF) sector(s), {run[0]}..{run[1]}")

    # ------------------------------------------------------------------ segmentation
    @staticmethod
    def _new_segment(fmt: int, key: int, rate_hz: float) -> _Segment:
        return _Segment(id=-1, fmt=int(fmt), light_scale_hi=int(key >> 16), rate_hz=rate_hz)

    def _fast_plan(self, rec):
        """Vectorised plan for the common batch: continues the open segment, no anomaly at all."""
        seg, prev = self._seg, self._prev
        if seg is None or prev is None:
            return None
        seq, key = rec["seq"], rec["key"]
        if not (rec["aok"].all() and (rec["session"] == prev.session).all()
                and (key == prev.key).all() and seq[0] == prev.seq + 1
                and (np.diff(seq) == 1).all()):
            return None
        count = rec["count"]
        s0 = np.empty_like(count)
        s0[0] = seg.n
        np.cumsum(count[:-1], out=s0[1:])
        s0[1:] += seg.n
        g = s0 + rec["aidx"]
        t = rec["at"]
        if seg.n_anchors:
            g_all = np.concatenate([[seg.ag[-1]], g])
            t_all = np.concatenate([[seg.at[-1]], t])
        else:
            g_all, t_all = g, t
        dg = np.diff(g_all)
        if (dg <= 0).any():
            return None
        dt = np.diff(t_all)
        expected = dg * (_NS / seg.rate_hz)
        if ((dt <= 0) | (np.abs(dt - expected) > TIME_JUMP_REL_TOL * expected + TIME_JUMP_ABS_TOL_NS)).any():
            return None
        self._accept_anchors(seg, g.tolist(), t.tolist())
        seg.n = int(s0[-1] + count[-1])
        return [(0, seq.shape[0], None, int(s0[0]))]

    def _accept_anchors(self, seg: _Segment, g: list, t: list) -> None:
        if not g:
            return
        if seg.origin is None:
            seg.origin = t[0]
        seg.ag.extend(g)
        seg.at.extend(t)
        before = seg.n_anchors
        seg.n_anchors += len(g)
        if before < 2 <= seg.n_anchors and seg.slope_first is None:
            i0 = len(seg.ag) - seg.n_anchors  # first anchor of the segment is still retained
            o = seg.origin
            seg.slope_first = (float(seg.at[i0 + 1] - o) - float(seg.at[i0] - o)) / \
                              (float(seg.ag[i0 + 1]) - float(seg.ag[i0]))

    def _slow_plan(self, rec):
        """Reference per-sector path: segment breaks, anchor checks, QC events."""
        plan = []
        seq = rec["seq"].tolist()
        session = rec["session"].tolist()
        key = rec["key"].tolist()
        count = rec["count"].tolist()
        aidx = rec["aidx"].tolist()
        at = rec["at"].tolist()
        aok = rec["aok"].tolist()
        index = rec["index"].tolist()
        fmt = rec["fmt"].tolist()
        rc = (rec["key"] & 0xFF).tolist()
        prev = self._prev
        p_seq = prev.seq if prev else None
        p_session = prev.session if prev else None
        p_key = prev.key if prev else None
        seg = self._seg
        run_start = 0
        run_s0 = seg.n if seg is not None else 0
        new_for_run = None
        for i in range(len(seq)):
            rate = 3200.0 / (1 << (15 - (rc[i] & 0x0F)))
            reason = None
            if p_seq is None or seg is None:
                reason = "start"
            elif session[i] != p_session:
                reason, detail = "session_change", f"session {p_session} -> {session[i]}"
            elif seq[i] == 0:
                reason, detail = "restart", f"sequence id {p_seq} -> 0 (logging restarted)"
            elif key[i] != p_key:
                reason, detail = "format_change", (f"rate/format/scale 0x{p_key:06X} -> 0x{key[i]:06X}")
            elif seq[i] != p_seq + 1:
                gap = seq[i] - p_seq - 1
                detail = (f"sequence id {p_seq} -> {seq[i]} ({gap} sector(s) missing)" if gap > 0
                          else f"sequence id {p_seq} -> {seq[i]} (out of order / repeated)")
                reason = "sequence_gap"
            g = t = None
            if aok[i]:
                t = at[i]
            else:
                self._event(index[i], "bad_timestamp",
                            "timestamp is 0 or not a valid date; anchor ignored, samples timed "
                            "from neighbouring sectors")
            if reason is None and t is not None and seg.n_anchors:
                g = seg.n + aidx[i]
                dg = g - seg.ag[-1]
                if dg > 0:
                    exp = dg * (_NS / seg.rate_hz)
                    # time must move forward between anchors, and near the nominal rate
                    if (t <= seg.at[-1]
                            or abs((t - seg.at[-1]) - exp) > TIME_JUMP_REL_TOL * exp + TIME_JUMP_ABS_TOL_NS):
                        reason = "time_jump"
                        detail = (f"anchor time moved {(t - seg.at[-1]) / _NS:+.3f} s over {dg} samples "
                                  f"({exp / _NS:.3f} s expected at {seg.rate_hz:g} Hz)")
            if reason is not None:
                # close the current run, start a new segment at this sector
                if seg is not None and i > run_start:
                    plan.append((run_start, i, new_for_run, run_s0))
                if reason != "start":
                    self._event(index[i], reason, detail, time_ns=t)
                seg = self._new_segment(fmt[i], key[i], rate)
                new_for_run = seg
                run_start = i
                run_s0 = 0
            if t is not None:
                g = seg.n + aidx[i]
                if seg.n_anchors and g <= seg.ag[-1]:
                    self._event(index[i], "bad_anchor",
                                f"anchor sample index {g} is not after the previous anchor "
                                f"{seg.ag[-1]}; anchor ignored")
                else:
                    self._accept_anchors(seg, [g], [t])
            seg.n += count[i]
            p_seq, p_session, p_key = seq[i], session[i], key[i]
        if len(seq) > run_start:
            plan.append((run_start, len(seq), new_for_run, run_s0))
        return plan

    # ------------------------------------------------------------------ emission
    def _close_segment(self):
        seg = self._seg
        yield from self._emit(seg, closed=True)
        self._seg = None

    def _emit(self, seg: _Segment, closed: bool):
        if not seg.chunks:
            return
        j_begin = seg.emitted
        if seg.n_anchors == 0:
            if not closed:
                return
            n = seg.n - j_begin
            first = int(seg.chunks[0]["index"][0])
            m = sum(c["index"].shape[0] for c in seg.chunks)
            self._event(first, "untimed",
                        f"segment {seg.id} ({m} sector(s)) has no valid timestamp; samples dropped",
                        samples=n)
            self.qc.valid -= m
            self.qc.skipped += m
            seg.chunks = []
            seg.emitted = seg.n
            return
        origin = seg.origin
        assert origin is not None  # set with the segment's first anchor
        if closed:
            ready = seg.n
        else:
            if seg.n_anchors < 2:
                return
            limit = seg.ag[-1] + 1  # samples with index <= last anchor are bracketed
            ready = j_begin
            for c in seg.chunks:
                ends = c["j0"] + np.append(c["starts"][1:], c["n"])
                ok = np.flatnonzero(ends <= limit)
                if ok.size:
                    ready = int(ends[ok[-1]])
                if ok.size < ends.shape[0]:
                    break
            if ready <= j_begin:
                return
        # split chunks into the emitted part and the rest
        take, keep = [], []
        for c in seg.chunks:
            c_end = c["j0"] + c["n"]
            if c_end <= ready:
                take.append(c)
            elif c["j0"] >= ready:
                keep.append(c)
            else:
                cut = int(np.searchsorted(c["starts"], ready - c["j0"]))
                take.append(_slice_chunk(c, 0, cut))
                keep.append(_slice_chunk(c, cut, None))
        seg.chunks = keep
        g = np.asarray(seg.ag, np.int64)
        t_rel = (np.asarray(seg.at, np.int64) - origin).astype(np.float64)
        slope_first = seg.slope_first if seg.slope_first is not None else seg.nominal_slope
        if seg.n_anchors >= 2:
            slope_last = (t_rel[-1] - t_rel[-2]) / (float(g[-1]) - float(g[-2]))
        else:
            slope_last = seg.nominal_slope
        if self.sample_times:
            rel = interpolate_times(j_begin, ready, g, t_rel, slope_first, slope_last, closed)
            np.rint(rel, out=rel)
            time_ns, clock = rel.astype(np.int64), None
            time_ns += origin
        else:
            time_ns, clock = None, SampleClock(j_begin, ready - j_begin, g, t_rel, slope_first,
                                               slope_last, closed, origin)
        seg.emitted = ready
        # retain the anchors still needed: the last one at or before `ready`, and everything after
        if not closed and len(seg.ag) > 2:
            i = int(np.searchsorted(g, ready, side="right")) - 1
            i = max(0, min(i, len(seg.ag) - 2))
            if i:
                del seg.ag[:i]
                del seg.at[:i]
        yield self._block(seg, take, time_ns, clock)

    def _block(self, seg: _Segment, chunks: list, time_ns: Optional[np.ndarray],
               clock: Optional[SampleClock] = None) -> Block:
        cat = (lambda xs: xs[0]) if len(chunks) == 1 else np.concatenate
        if time_ns is not None:
            n = time_ns.shape[0]
        else:
            assert clock is not None  # a Block has times or a clock
            n = clock.n
        cpg = C.cwa_accel_counts_per_g(seg.light_scale_hi >> 3)
        six = FORMATS[seg.fmt][0] == 6
        if self.decode:
            accel = cat([c["accel"] for c in chunks])
            gyro = cat([c["gyro"] for c in chunks]) if six else None
        else:
            accel = np.zeros((n, 0), np.int16)
            gyro = None
        offs = np.cumsum([0] + [c["n"] for c in chunks[:-1]])
        temp = cat([c["temp"] for c in chunks])
        battery = cat([c["battery"] for c in chunks])
        block = Block(
            time_ns=time_ns,
            accel=accel,
            accel_counts_per_g=np.full(3, cpg),
            accel_zero=np.zeros(3),
            gyro=gyro,
            gyro_dps_per_count=(C.cwa_gyro_range_dps(seg.light_scale_hi & 7) / 32768.0) if six else None,
            unit_index=cat([c["index"] for c in chunks]).astype(np.int64),
            unit_sequence=cat([c["seq"] for c in chunks]).astype(np.int64),
            unit_start=np.concatenate([c["starts"] + o for c, o in zip(chunks, offs)]).astype(np.int64),
            temperature_c=np.where(temp == 0, np.nan, C.cwa_temperature_c(temp)),
            temperature_raw=np.where(temp == 0, -1, temp).astype(np.int32),
            light=cat([c["light"] for c in chunks]).astype(np.int32),
            battery_v=C.cwa_battery_v(battery),
            events=cat([c["events"] for c in chunks]).astype(np.uint8),
            segment=seg.id,
            first_sample=self._emitted_total,
            clock=clock,
        )
        self._emitted_total += n
        self._time_pending(block)
        t_first, t_last = block.time_at(np.array([0, n - 1])).tolist()
        self._bounds.append((int(block.unit_index[0]), t_first, int(block.unit_index[-1]), t_last))
        return block

    # ------------------------------------------------------------------ AX6 axis swap (fw < 56)
    def _axis_swap(self, index, seq, fmts, count, offsets, accel, gyro, ls) -> None:
        """Watch the start of each logging run (sequence id 0) for the AX6 fw < 56 axis swap.

        A sector looks *swapped* when the gyro triplet is a steady ~1 g vector (in accel counts)
        and the accel triplet is small; *normal* when the accel triplet is ~1 g and the gyro
        triplet is not. From a run's first sector to the first normal sector, if any swapped
        sector was seen, the stretch is reported as one ``axis_swap`` event.
        """
        six = (fmts == 0x62) & (count > 0)
        if not six.any() or (self._swap_run is None and not (seq[six] == 0).any()):
            return
        n = count.astype(np.float64)[:, None]
        cpg = (1 << (8 + (ls.astype(np.int64) >> 13))).astype(np.float64)[:, None]
        a = accel.astype(np.float64) / np.repeat(cpg, count, axis=0)
        g = gyro.astype(np.float64) / np.repeat(cpg, count, axis=0)
        ma = np.add.reduceat(a, offsets[:-1], axis=0) / n
        mg = np.add.reduceat(g, offsets[:-1], axis=0) / n
        sg = np.sqrt(np.maximum(np.add.reduceat(g * g, offsets[:-1], axis=0) / n - mg * mg, 0)).max(axis=1)
        na, ng = np.linalg.norm(ma, axis=1), np.linalg.norm(mg, axis=1)
        swapped = (np.abs(ng - 1) < 0.1) & (sg < 0.1) & (na < 0.3) & six
        normal = (np.abs(na - 1) < 0.1) & (np.abs(ng - 1) > 0.3) & six
        for i in range(index.shape[0]):
            if seq[i] == 0 and six[i]:
                self._finish_swap_run()
                self._swap_run = [int(index[i]), int(index[i]), False]
            run = self._swap_run
            if run is None:
                continue
            if normal[i]:
                self._finish_swap_run()
                continue
            run[1] = int(index[i])
            run[2] = run[2] or bool(swapped[i])

    def _finish_swap_run(self) -> None:
        run = self._swap_run
        self._swap_run = None
        if run is None or not run[2]:
            return
        self._event(run[0], "axis_swap",
                    f"data sectors {run[0]}..{run[1]} (start of a logging run): the gyro channels "
                    f"hold a steady ~1 g vector and the accel channels do not - accel/gyro triplets "
                    f"look swapped (known AX6 firmware < {C.CWA_AX6_AXIS_SWAP_FIXED_FIRMWARE} bug, "
                    f"this file has {self._header['firmware_revision']}); data left unchanged",
                    time_ns=run[3] if len(run) > 3 else None)


def _slice_chunk(c: dict, a: int, b: Optional[int]) -> dict:
    """Sectors [a, b) of a pending chunk."""
    starts = c["starts"]
    s_a = int(starts[a])
    s_b = c["n"] if b is None or b >= starts.shape[0] else int(starts[b])
    out = {
        "accel": None if c["accel"] is None else c["accel"][s_a:s_b],
        "gyro": None if c["gyro"] is None else c["gyro"][s_a:s_b],
        "j0": c["j0"] + s_a,
        "starts": starts[a:b] - s_a,
        "n": s_b - s_a,
    }
    for f_ in _UNIT_FIELDS:
        out[f_] = c[f_][a:b]
    return out
