"""Plain data passed between stages: Block, DeviceInfo and the per-file QC log.

A **Block** is one device's consecutive samples as plain numpy arrays. Per-sample arrays have
length ``n``; per-unit arrays (one entry per .cwa sector or .bin page that contributed samples)
have length ``m``. Readers hand over many sectors/pages per Block for speed. Within one Block:

* the accelerometer scale is constant (a reader starts a new Block when it changes);
* all samples belong to one *segment* (a continuous stretch of logging: a restart, a sequence
  break or a skipped corrupt unit starts a new segment). Operators must never let a window span
  two segments.

Times are int64 nanoseconds since the Unix epoch, UTC (the device's local clock converted with
the time-zone setting of the source). A source asked not to time every sample (``.cwa``:
``sample_times=False``) leaves ``time_ns`` None and hands a ``clock`` instead, which gives the
same times for the samples asked for (``time_at``); only consumers that use ``time_at`` (the
window features, the calibration pass) take such Blocks.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Iterable, Optional

import numpy as np

# Keys that may appear in Block.per_sample (format-specific per-sample channels).
PER_SAMPLE_LIGHT_RAW = "light_raw"  # GENEActiv: 10-bit light per sample
PER_SAMPLE_BUTTON = "button"  # GENEActiv: button bit per sample
PER_SAMPLE_IDLE_SLEEP = "idle_sleep"  # ActiGraph: 1 where the device slept (last sample repeated)


@dataclass(frozen=True)
class QCEvent:
    """One entry of a source's QC log: what happened at which sector/page."""

    index: int  # sector (.cwa data sector, 0-based) or page (.bin, 0-based) index in the file
    reason: str  # short code: "checksum", "bad_tag", "bad_timestamp", "sequence_gap", "restart", ...
    detail: str = ""  # human-readable specifics
    time_ns: Optional[int] = None  # data time near the event, when known
    samples: int = 0  # samples dropped with this unit (0 when nothing was dropped)
    end_ns: Optional[int] = None  # end of an event that lasts (ActiGraph idle sleep), exclusive

    def as_dict(self) -> dict:
        """The event as JSON-ready data (``detail`` only when there is one)."""
        d = {"index": self.index, "reason": self.reason}
        if self.detail:
            d["detail"] = self.detail
        if self.time_ns is not None:
            d["time_ns"] = self.time_ns
        if self.samples:
            d["samples"] = self.samples
        if self.end_ns is not None:
            d["end_ns"] = self.end_ns
        return d


@dataclass
class QCReport:
    """Per-file QC log (GGIRread-style): unit counts plus the list of events."""

    unit: str  # "sector" or "page"
    total: int = 0  # units seen
    valid: int = 0  # units whose samples were returned
    skipped: int = 0  # units dropped
    events: list[QCEvent] = field(default_factory=list)
    segments: int = 0  # continuous stretches of logging

    def add(self, event: QCEvent) -> None:
        """Record one event."""
        self.events.append(event)

    def as_dict(self) -> dict:
        """The report as JSON-ready data (the run summary's ``qc``)."""
        return {
            "unit": self.unit,
            "total": self.total,
            "valid": self.valid,
            "skipped": self.skipped,
            "segments": self.segments,
            "events": [e.as_dict() for e in self.events],
        }


@dataclass(frozen=True)
class DeviceInfo:
    """What a source knows about the device and the recording before reading samples."""

    device_type: str  # "AX3", "AX6" or "GENEActiv"
    device_id: str  # serial / device id as a string (GENEActiv keeps leading zeros)
    session_id: Optional[int]
    firmware: str
    sample_rate_nominal: float  # Hz, from the header (GENEActiv "85.7" is 600/7)
    accel_range_g: float
    gyro_range_dps: Optional[float] = None
    channels: tuple[str, ...] = ("accel_x", "accel_y", "accel_z")
    timezone_offset_s: int = 0  # device clock minus UTC, seconds, as applied by the source
    metadata: dict[str, str] = field(default_factory=dict)  # annotation / subject fields
    header: dict[str, Any] = field(default_factory=dict)  # format-specific raw header fields
    path: Optional[str] = None

    @property
    def device_key(self) -> str:
        """Stable per-device key (type + serial) for the calibration store."""
        return f"{self.device_type}-{self.device_id}"


@dataclass
class Block:
    """Consecutive samples of one device (see the module docstring for the invariants)."""

    time_ns: Optional[np.ndarray]  # (n,) int64, UTC; None when ``clock`` times the samples
    accel: np.ndarray  # (n, 3) integer counts
    accel_counts_per_g: np.ndarray  # (3,) float64: g = (counts - accel_zero) / accel_counts_per_g
    accel_zero: np.ndarray  # (3,) float64 counts (0 for AX; header offset/100 for GENEActiv)
    gyro: Optional[np.ndarray] = None  # (n, 3) int16 counts (AX6)
    gyro_dps_per_count: Optional[float] = None
    # --- per unit (sector / page), length m ---
    unit_index: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))  # index in the file
    unit_sequence: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))  # device sequence id
    unit_start: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))  # first sample, in block
    temperature_c: np.ndarray = field(default_factory=lambda: np.zeros(0))  # NaN when absent
    temperature_raw: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))  # ADC code, -1 if none
    light: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))  # raw light ADC per unit
    battery_v: np.ndarray = field(default_factory=lambda: np.zeros(0))  # volts, NaN when unknown
    events: np.ndarray = field(default_factory=lambda: np.zeros(0, np.uint8))  # CWA event flags
    # --- other ---
    per_sample: dict[str, np.ndarray] = field(default_factory=dict)  # see PER_SAMPLE_* keys
    segment: int = 0  # continuous-logging stretch this block belongs to
    first_sample: int = 0  # absolute index (among valid samples of the source) of sample 0
    clock: Any = None  # with time_ns None: .n, .at(rows), .times(start, stop), .search(edges)

    # ------------------------------------------------------------------ derived views
    @property
    def n(self) -> int:
        """Number of samples."""
        return int(self.time_ns.shape[0]) if self.time_ns is not None else self.clock.n

    def time_at(self, rows) -> np.ndarray:
        """int64 times of the samples at ``rows``, from ``time_ns`` or the ``clock``."""
        if self.time_ns is not None:
            return self.time_ns[rows]
        return self.clock.at(rows)

    @property
    def m(self) -> int:
        """Number of units (sectors or pages)."""
        return int(self.unit_start.shape[0])

    def accel_g(self, dtype=np.float64) -> np.ndarray:
        """Acceleration in g, (n, 3)."""
        a = self.accel.astype(dtype)
        if np.any(self.accel_zero):
            a -= self.accel_zero.astype(dtype)
        a /= self.accel_counts_per_g.astype(dtype)
        return a

    def gyro_dps(self, dtype=np.float64) -> Optional[np.ndarray]:
        """Gyro in degrees per second, (n, 3); None without a gyro."""
        if self.gyro is None:
            return None
        return self.gyro.astype(dtype) * dtype(self.gyro_dps_per_count)

    def unit_of_sample(self) -> np.ndarray:
        """(n,) index into the per-unit arrays for every sample."""
        counts = np.diff(np.append(self.unit_start, self.n))
        return np.repeat(np.arange(self.m), counts)

    def temperature_per_sample(self) -> np.ndarray:
        """(n,) temperature, each unit's value held over its samples (no interpolation)."""
        return np.repeat(self.temperature_c, np.diff(np.append(self.unit_start, self.n)))

    # ------------------------------------------------------------------ slicing / joining
    def slice(self, start: int, stop: int) -> "Block":
        """Samples [start, stop) as a new Block; units are kept if they contribute a sample."""
        start = max(0, start)
        stop = min(self.n, stop)
        ends = np.append(self.unit_start[1:], self.n)
        keep = (ends > start) & (self.unit_start < stop)
        us = np.maximum(self.unit_start[keep], start) - start
        return replace(
            self,
            time_ns=self.time_ns[start:stop],  # type: ignore[index]  # slicing needs the times
            accel=self.accel[start:stop],
            gyro=None if self.gyro is None else self.gyro[start:stop],
            unit_index=self.unit_index[keep],
            unit_sequence=self.unit_sequence[keep],
            unit_start=us.astype(np.int64),
            temperature_c=self.temperature_c[keep],
            temperature_raw=self.temperature_raw[keep],
            light=self.light[keep],
            battery_v=self.battery_v[keep],
            events=self.events[keep],
            per_sample={k: v[start:stop] for k, v in self.per_sample.items()},
            first_sample=self.first_sample + start,
        )

    @staticmethod
    def concat(blocks: Iterable["Block"]) -> "Block":
        """Join consecutive blocks of one segment with one scale into a single Block."""
        blocks = [b for b in blocks if b.n > 0]
        if not blocks:
            raise ValueError("concat needs at least one non-empty block")
        b0 = blocks[0]
        for b in blocks[1:]:
            if not (np.array_equal(b.accel_counts_per_g, b0.accel_counts_per_g)
                    and np.array_equal(b.accel_zero, b0.accel_zero)):
                raise ValueError("cannot concat blocks with different accelerometer scales")
        offsets = np.cumsum([0] + [b.n for b in blocks[:-1]])
        cat = np.concatenate
        return replace(
            b0,
            time_ns=cat([b.time_ns for b in blocks]),
            accel=cat([b.accel for b in blocks]),
            gyro=None if b0.gyro is None else cat([b.gyro for b in blocks]),
            unit_index=cat([b.unit_index for b in blocks]),
            unit_sequence=cat([b.unit_sequence for b in blocks]),
            unit_start=cat([b.unit_start + o for b, o in zip(blocks, offsets)]).astype(np.int64),
            temperature_c=cat([b.temperature_c for b in blocks]),
            temperature_raw=cat([b.temperature_raw for b in blocks]),
            light=cat([b.light for b in blocks]),
            battery_v=cat([b.battery_v for b in blocks]),
            events=cat([b.events for b in blocks]),
            per_sample={k: cat([b.per_sample[k] for b in blocks]) for k in b0.per_sample},
        )


def without_idle_sleep(block: Block) -> Block:
    """The block without its idle-sleep samples (an ActiGraph repeats its last sample while it
    sleeps: a flat stretch that was never measured). The block itself when it has none."""
    idle = block.per_sample.get(PER_SAMPLE_IDLE_SLEEP)
    if idle is None or not idle.any():
        return block
    edge = np.diff(np.concatenate([[0], (idle == 0).astype(np.int8), [0]]))
    runs = list(zip(np.flatnonzero(edge == 1).tolist(), np.flatnonzero(edge == -1).tolist()))
    if not runs:
        return block.slice(0, 0)
    parts = [block.slice(a, b) for a, b in runs]
    return parts[0] if len(parts) == 1 else Block.concat(parts)


COALESCE_S = 600.0  # the longest run of blocks joined by coalesce_blocks (10 min of data)


def coalesce_blocks(src, max_s: float = COALESCE_S):
    """The source's Blocks joined into runs of one segment and scale, up to ``max_s`` of data
    (every operator's output is independent of block cuts, so this only saves per-block work)."""
    run: list[Block] = []
    t0 = 0  # the first block's start, set with it
    for b in src:
        if b.n == 0:
            continue
        if run:
            r0 = run[0]
            same = (b.segment == r0.segment and np.array_equal(b.accel_counts_per_g, r0.accel_counts_per_g)
                    and np.array_equal(b.accel_zero, r0.accel_zero)
                    and (b.gyro is None) == (r0.gyro is None)
                    and set(b.per_sample) == set(r0.per_sample))
            if not same or (int(b.time_ns[-1]) - t0) > max_s * 1e9:
                yield Block.concat(run) if len(run) > 1 else run[0]
                run = []
        if not run:
            t0 = int(b.time_ns[0])
        run.append(b)
    if run:
        yield Block.concat(run) if len(run) > 1 else run[0]
