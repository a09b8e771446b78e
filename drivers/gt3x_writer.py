"""ActiGraph ``.gt3x`` writer (log.bin layout), for the simulator and tests: the one writer of the
format (drivers/gt3x.py is its reader; constants in drivers/constants.py [GT3X]).

The zip holds ``log.bin`` then ``info.txt`` (the order of the public wGT3X-BT file), stored
uncompressed as the devices' files are. ``log.bin`` starts with METADATA and PARAMETERS records
(ACCEL_SCALE, SAMPLE_RATE, FEATURE_ENABLE with the sleep-mode bit), then one ACTIVITY record
(12-bit, Y X Z) per second, a BATTERY record at every whole minute and, with ``idle_sleep=True``,
EVENT records around the seconds the device sleeps.

Idle sleep (a model of the device's behaviour, not a format constant): after ``idle_after_s``
consecutive seconds in which no axis moves more than ``idle_counts`` counts, the device writes
EVENT 0x08 and stops writing samples; the first second that moves again gets EVENT 0x09 and its
ACTIVITY record. The reader repeats the last sample over the skipped seconds.

Each device-clock second (UTC + ``timezone_s``, whole seconds) with samples becomes one record
of exactly ``rate`` samples, picked evenly from the samples of that second.
"""

from __future__ import annotations

import json
import struct
import zipfile
from typing import BinaryIO, Optional

import numpy as np

from . import constants as C

__all__ = ["Gt3xWriter", "record_bytes", "pack12"]

IDLE_AFTER_S = 10  # still seconds before the simulated device sleeps
IDLE_COUNTS = 10  # "still": every axis within this many counts (~40 mg) over the second


def ssp_encode(f: float) -> int:
    """The PARAMETERS float code ([GT3X] LogRecords/Parameters.md 64-102)."""
    s = abs(float(f))
    if s < 2.0 ** -23:
        return 0
    e = 0
    while s >= 1.0:
        s /= 2.0
        e += 1
    while s < 0.5:
        s *= 2.0
        e -= 1
    code = int(s * 8388608.0)
    if f < 0:
        code = (-code) & 0xFFFFFFFF
    return (code & 0x00FFFFFF) | ((e & 0xFF) << 24)


def record_bytes(typ: int, time_s: int, payload: bytes) -> bytes:
    """One log record with its checksum ([GT3X] README.md 62-100, 302-313)."""
    head = bytes([C.GT3X_SEPARATOR, typ]) + struct.pack("<IH", int(time_s) & 0xFFFFFFFF, len(payload))
    x = 0
    for b in head:
        x ^= b
    x ^= int(np.bitwise_xor.reduce(np.frombuffer(payload, np.uint8))) if payload else 0
    return head + payload + bytes([(~x) & 0xFF])


def pack12(counts: np.ndarray) -> np.ndarray:
    """(k, n, 3) X Y Z counts -> (k, ceil(4.5 n)) bytes of 12-bit Y X Z values."""
    c = np.asarray(counts)
    k, n = c.shape[0], c.shape[1]
    v = (c[..., [1, 0, 2]].astype(np.int32) & 0xFFF).reshape(k, 3 * n).astype(np.uint16)
    if v.shape[1] % 2:
        v = np.concatenate([v, np.zeros((k, 1), np.uint16)], axis=1)
    a, b = v[:, 0::2], v[:, 1::2]
    out = np.empty((k, a.shape[1], 3), np.uint8)
    out[..., 0] = a >> 4
    out[..., 1] = ((a & 0xF) << 4) | (b >> 8)
    out[..., 2] = b & 0xFF
    return out.reshape(k, -1)[:, :(9 * n + 1) // 2]


def _checksums(rows: np.ndarray) -> np.ndarray:
    return (~np.bitwise_xor.reduce(rows, axis=1)).astype(np.uint8)


class Gt3xWriter:
    """``Gt3xWriter(path, serial=..., rate_hz=30).write(time_ns, counts)`` ... ``close()``."""

    def __init__(self, path, *, serial: str = "MOS2E00000001", rate_hz: float = 30.0,
                 scale: float = 256.0, timezone_s: int = 0, idle_sleep: bool = True,
                 firmware: str = "1.9.2", device_type: str = "wGT3XBT", subject: str = "",
                 idle_after_s: int = IDLE_AFTER_S, idle_counts: int = IDLE_COUNTS):
        if float(rate_hz) != int(rate_hz) or not 1 <= int(rate_hz) <= 1000:
            raise ValueError(f"a .gt3x rate is a whole number of Hz, got {rate_hz}")
        self.rate = int(rate_hz)
        self.scale = float(scale)
        self.serial, self.firmware, self.device_type, self.subject = serial, firmware, device_type, subject
        self.tz = int(timezone_s)
        self.idle_sleep = bool(idle_sleep)
        self.idle_after_s, self.idle_counts = int(idle_after_s), int(idle_counts)
        self._f: Optional[BinaryIO] = open(path, "wb")
        self._zip = zipfile.ZipFile(self._f, "w", zipfile.ZIP_STORED, allowZip64=True)
        self._log = self._zip.open(C.GT3X_LOG_MEMBER, "w", force_zip64=True)
        self._pending = np.zeros((0, 3), np.int32)  # samples of the last second seen, not written
        self._pending_t = np.zeros(0, np.int64)
        self._next_s: Optional[int] = None  # device-clock second after the last record
        self._first_s: Optional[int] = None
        self._still = 0  # consecutive still seconds
        self._sleeping = False
        self._minute: Optional[int] = None
        self.records = 0
        self.idle_seconds = 0
        self._started = False

    # ------------------------------------------------------------------ records
    def _start(self, s: int) -> None:
        self._started = True
        self._first_s = s
        meta = {"MetadataType": "Bio", "SubjectName": self.subject, "Race": "", "Limb": "", "Side": "",
                "Dominance": "", "Parsed": False, "JSON": None}
        self._log.write(record_bytes(C.GT3X_REC_METADATA, s, json.dumps(meta, separators=(",", ":")).encode()))
        params = [(C.GT3X_PARAM_ACCEL_SCALE, ssp_encode(self.scale)),
                  ((1, 10), self.rate),  # SAMPLE_RATE (Parameters.md 289-290)
                  (C.GT3X_PARAM_FEATURE_ENABLE, (1 << C.GT3X_FEATURE_SLEEP_MODE_BIT) if self.idle_sleep else 0),
                  (C.GT3X_PARAM_UTC_OFFSET, self.tz & 0xFFFFFFFF)]
        payload = b"".join(struct.pack("<HHI", a, i, v & 0xFFFFFFFF) for (a, i), v in params)
        self._log.write(record_bytes(C.GT3X_REC_PARAMETERS, s, payload))

    def _seconds(self, secs: np.ndarray, counts: np.ndarray) -> None:
        """Write whole seconds (secs (k,) consecutive device seconds, counts (k, rate, 3))."""
        k = secs.shape[0]
        if k == 0:
            return
        if not self._started:
            self._start(int(secs[0]))
        still = (counts.max(axis=1) - counts.min(axis=1) <= self.idle_counts).all(axis=1)
        n = self.rate
        S = (9 * n + 1) // 2
        rows = np.empty((k, S + 9), np.uint8)
        rows[:, 0] = C.GT3X_SEPARATOR
        rows[:, 1] = C.GT3X_REC_ACTIVITY
        rows[:, 2:6] = secs.astype("<u4").view(np.uint8).reshape(k, 4)
        rows[:, 6:8] = np.frombuffer(struct.pack("<H", S), np.uint8)
        rows[:, 8:8 + S] = pack12(counts)
        rows[:, -1] = _checksums(rows[:, :-1])
        # idle: the seconds after idle_after_s still ones, while still (the count carries over calls)
        if self.idle_sleep:
            c = np.cumsum(still)
            pos = c - np.maximum.accumulate(np.where(~still, c, 0))
            first_run = np.cumsum(~still) == 0
            pos = pos + np.where(first_run, self._still, 0)
            idle = still & (pos > self.idle_after_s)
            self._still = int(pos[-1]) if still[-1] else 0
        else:
            idle = np.zeros(k, bool)
        prev = np.concatenate([[self._sleeping], idle[:-1]])
        enter, leave = idle & ~prev, ~idle & prev
        self._sleeping = bool(idle[-1])
        self.idle_seconds += int(idle.sum())
        self.records += int((~idle).sum())
        minute = secs // 60
        new_min = np.concatenate([[self._minute != int(minute[0])], minute[1:] != minute[:-1]])
        self._minute = int(minute[-1])
        special = np.flatnonzero(new_min | enter | leave).tolist() + [k]
        out = []
        if special[0] > 0 and not idle[0]:
            out.append(rows[:special[0]].tobytes())
        for i, j in zip(special[:-1], special[1:]):
            s = int(secs[i])
            if new_min[i]:
                out.append(record_bytes(C.GT3X_REC_BATTERY, s, struct.pack("<H", 4000)))
            if leave[i]:
                out.append(record_bytes(C.GT3X_REC_EVENT, s, bytes([C.GT3X_EVENT_IDLE_EXIT])))
            if enter[i]:
                out.append(record_bytes(C.GT3X_REC_EVENT, s, bytes([C.GT3X_EVENT_IDLE_ENTER])))
            if not idle[i]:
                out.append(rows[i:j].tobytes())
        self._log.write(b"".join(out))

    # ------------------------------------------------------------------ input
    def write(self, time_ns, counts, **_ignored) -> None:
        """Samples in time order: ``time_ns`` (n,) UTC, ``counts`` (n, 3) X Y Z in 1/scale g
        (clipped to 12 bits). Other channels (light, battery) are not written. Each device-clock
        second becomes one record of exactly ``rate`` samples (the second's samples picked
        evenly: a clock whose sample rate is off by some ppm still writes ``rate`` a second); a
        second without samples (a halt) has no record."""
        t = np.asarray(time_ns, np.int64)
        c = np.clip(np.asarray(counts, np.int32), -2048, 2047)
        if t.shape[0] == 0:
            return
        if self._pending.shape[0]:
            t = np.concatenate([self._pending_t, t])
            c = np.concatenate([self._pending, c])
        sec = (t + self.tz * 10**9) // 10**9
        last = int(sec[-1])
        done = int(np.searchsorted(sec, last, side="left"))  # the last second may continue
        self._pending_t, self._pending = t[done:], c[done:]
        self._flush(sec[:done], c[:done])

    def _flush(self, sec: np.ndarray, c: np.ndarray) -> None:
        if sec.shape[0] == 0:
            return
        starts = np.flatnonzero(np.r_[True, sec[1:] != sec[:-1]])
        counts = np.diff(np.r_[starts, sec.shape[0]])
        secs = sec[starts].astype(np.int64)
        pick = starts[:, None] + (np.arange(self.rate)[None, :] * counts[:, None]) // self.rate
        samples = c[pick]  # (k, rate, 3)
        # write runs of consecutive seconds (a gap between runs is a halt)
        cut = np.flatnonzero(np.diff(secs) != 1) + 1
        for a, b in zip(np.r_[0, cut], np.r_[cut, secs.shape[0]]):
            if self._next_s is not None and int(secs[a]) != self._next_s:
                self._still = 0  # a halt breaks the still count
            self._seconds(secs[a:b], samples[a:b])
            self._next_s = int(secs[b - 1]) + 1

    def restart(self) -> None:
        """A new stretch of logging (not simulated for this device; kept for the writer API)."""

    def close(self) -> None:
        if self._f is None:
            return
        if self._pending.shape[0]:
            self._flush((self._pending_t + self.tz * 10**9) // 10**9, self._pending)
            self._pending = self._pending[:0]
        last = self._next_s if self._next_s is not None else 0
        self._log.close()
        ticks = (lambda s: int(s) * C.GT3X_TICKS_PER_S + C.GT3X_TICKS_AT_UNIX_EPOCH)
        a = abs(self.tz)
        zone = f"{'-' if self.tz < 0 else ''}{a // 3600:02d}:{a % 3600 // 60:02d}:00"
        first = self._first_s if self._first_s is not None else 0
        info = [("Serial Number", self.serial), ("Device Type", self.device_type),
                ("Firmware", self.firmware), ("Battery Voltage", "4.00"), ("Sample Rate", str(self.rate)),
                ("Start Date", str(ticks(first))), ("Stop Date", "0"), ("Last Sample Time", str(ticks(last))),
                ("TimeZone", zone), ("Download Date", str(ticks(last))), ("Board Revision", "5"),
                ("Unexpected Resets", "0"), ("Acceleration Scale", f"{self.scale:.1f}"),
                ("Acceleration Min", f"{-2048 / self.scale:.1f}"),
                ("Acceleration Max", f"{2048 / self.scale:.1f}"), ("Subject Name", self.subject)]
        self._zip.writestr(C.GT3X_INFO_MEMBER, "".join(f"{k}: {v}\r\n" for k, v in info))
        self._zip.close()
        self._f.close()
        self._f = None
