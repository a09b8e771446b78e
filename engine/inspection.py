"""What is in a recording (AX3/AX6 .cwa, GENEActiv .bin, gzipped or not; ActiGraph .gt3x: also
its model, layout, scale, stored zone and idle-sleep time; a stillpoint log's raw stream):
``inspect_recording(path, header_only=False, timezone=None, follow_idle_s=None,
timezone_override=False) -> dict`` (the ``stillpoint inspect`` command prints it).

A full streaming pass (bounded memory) reports device, samples, nominal and measured rate, start/end
(ISO 8601 UTC with nanoseconds when the zone is known; otherwise ``start``/``end`` and
``timezone_offset_s`` are null and ``start_local``/``end_local`` give the device clock, as
engine/timezones.py rules for every output), duration, channels, sectors/pages {total, valid,
skipped}, segments, the QC log and the temperature/battery ranges. ``header_only`` reads the
header alone (fast); ``follow_idle_s`` reads a file still being written until it has not grown
for that many seconds.
"""

from __future__ import annotations

import math
from typing import Optional

import numpy as np

from stillpoint.drivers import read_header, sniff_format
from stillpoint.engine.core.errors import StillpointError
from stillpoint.engine.core.times import iso_utc as _iso_utc, offset_text

from .recordings import open_recording


def iso_utc(t_ns: Optional[int]) -> Optional[str]:
    """int ns since 1970 (UTC) -> '2013-05-30T09:12:54.500000000Z' (ISO 8601, nanoseconds)."""
    return None if t_ns is None else _iso_utc(t_ns, "ns")


def _open(path, fmt: str, opts: dict, follow_idle_s=None):
    opts = dict(opts)
    if follow_idle_s is not None:
        if fmt == "mcap":
            raise StillpointError(f"{path}: --follow reads a .cwa/.bin that is still being written, "
                                  "not an MCAP log")
        opts.update(follow=True, follow_idle_s=follow_idle_s)
    return open_recording(path, **opts)


def reader_zone(path, fmt: str, timezone, override: bool = False):
    """``(reader options, Zone)`` for the CLI's time zone ``timezone`` (an IANA name or an offset;
    None: not given): the reader's ``timezone=`` (seconds of the device clock's offset from UTC)
    when one is given, and the Zone the times are in (unknown for a .cwa without one), from one
    ``engine.timezones.reader_timezone`` (one rule for every command; a header read at most
    once). A bad zone is one line, exit 2."""
    from stillpoint.engine.timezones import reader_timezone
    tz, zone = reader_timezone(path, fmt, timezone, override)
    return ({"timezone": tz} if timezone is not None else {}), zone


def _header_info(path, fmt: str, opts: dict):
    if fmt != "mcap":
        return read_header(path, fmt, **opts)
    src = _open(path, fmt, opts)
    try:
        return src.info
    finally:
        src.close()


def _info_dict(info, fmt: str, zone=None) -> dict:
    return {
        "path": info.path,
        "format": fmt,
        "device_type": info.device_type,
        "device_id": info.device_id,
        "session_id": info.session_id,
        "firmware": info.firmware,
        "sample_rate_nominal": info.sample_rate_nominal,
        "accel_range_g": info.accel_range_g,
        "gyro_range_dps": info.gyro_range_dps,
        "timezone_offset_s": info.timezone_offset_s if zone is None or zone.known else None,
        "metadata": dict(info.metadata),
    }


class _Summary:
    """Streaming accumulator over Blocks: counts, per-segment time spans, value ranges."""

    def __init__(self):
        self.samples = 0
        self.start: Optional[int] = None
        self.end: Optional[int] = None
        self.seg_first: dict[int, int] = {}
        self.seg_last: dict[int, int] = {}
        self.seg_n: dict[int, int] = {}
        self.tmin = math.inf
        self.tmax = -math.inf
        self.bmin = math.inf
        self.bmax = -math.inf
        self.per_sample: set[str] = set()

    def add(self, b) -> None:
        if b.n == 0:
            return
        t0, t1 = int(b.time_ns[0]), int(b.time_ns[-1])
        self.samples += b.n
        self.start = t0 if self.start is None else min(self.start, t0)
        self.end = t1 if self.end is None else max(self.end, t1)
        s = int(b.segment)
        self.seg_first.setdefault(s, t0)
        self.seg_last[s] = t1
        self.seg_n[s] = self.seg_n.get(s, 0) + b.n
        if b.temperature_c.size and np.isfinite(b.temperature_c).any():
            self.tmin = min(self.tmin, float(np.nanmin(b.temperature_c)))
            self.tmax = max(self.tmax, float(np.nanmax(b.temperature_c)))
        if b.battery_v.size and np.isfinite(b.battery_v).any():
            self.bmin = min(self.bmin, float(np.nanmin(b.battery_v)))
            self.bmax = max(self.bmax, float(np.nanmax(b.battery_v)))
        self.per_sample.update(b.per_sample)

    def measured_rate(self) -> Optional[float]:
        """Sample intervals over time spans, summed within segments (gaps between segments excluded)."""
        intervals = sum(n - 1 for n in self.seg_n.values())
        span = sum(self.seg_last[s] - self.seg_first[s] for s in self.seg_n)
        return intervals / (span / 1e9) if span > 0 else None


def follow_format(path) -> str:
    """The format of a file that may still be empty (a download that has just started): by its
    first bytes when there are some, else by its name."""
    import os

    from stillpoint.drivers.byteio import check_recording_path
    check_recording_path(path, allow_empty=True)
    if os.path.getsize(path) >= 16:
        return sniff_format(path)
    return "geneactiv" if str(path).lower().endswith(".bin") else "cwa"


def inspect_recording(path, *, header_only: bool = False, timezone=None,
                      follow_idle_s: Optional[float] = None, timezone_override: bool = False) -> dict:
    """Summary of a recording as a plain dict (see the module docstring). ``follow_idle_s``:
    read a file that is still being written until it has not grown for that many seconds."""
    from stillpoint.engine.timezones import local_text
    fmt = follow_format(path) if follow_idle_s is not None else sniff_format(path)
    opts, zone = reader_zone(path, fmt, timezone, timezone_override)
    if header_only:
        info = _header_info(path, fmt, opts)
        out = _info_dict(info, fmt, zone)
        out["header"] = dict(info.header)
        if zone is not None:
            out["timezone"] = zone.label
        if fmt == "gt3x":
            out["actigraph"] = _actigraph(info, None)
        return out
    src = _open(path, fmt, opts, follow_idle_s)
    acc = _Summary()
    try:
        for block in src:
            acc.add(block)
    finally:
        src.close()
    info, qc = src.info, src.qc
    out = _info_dict(info, fmt, zone)
    aux = ["temperature", "light", "battery"] + sorted(k for k in acc.per_sample
                                                        if k in ("button", "idle_sleep"))
    unit = f"{qc.unit}s"  # "pages" (.bin), "sectors" (.cwa)
    rate = acc.measured_rate()
    out.update({
        "samples": acc.samples,
        "sample_rate_measured": rate,
        "start": iso_utc(acc.start) if zone is None or zone.known else None,
        "end": iso_utc(acc.end) if zone is None or zone.known else None,
        "start_local": local_text(acc.start, zone, "ns") if zone is not None else None,
        "end_local": local_text(acc.end, zone, "ns") if zone is not None else None,
        "start_ns": acc.start,
        "end_ns": acc.end,
        "duration_s": (acc.end - acc.start) / 1e9 if acc.start is not None else 0.0,
        "channels": list(info.channels) + aux,
        unit: {"total": qc.total, "valid": qc.valid, "skipped": qc.skipped},
        "segments": qc.segments,
        "qc": [e.as_dict() for e in qc.events],
        "temperature_range_c": [acc.tmin, acc.tmax] if acc.tmin <= acc.tmax else None,
        "battery_range_v": [acc.bmin, acc.bmax] if acc.bmin <= acc.bmax else None,
    })
    if zone is not None:
        out["timezone"] = zone.label
    if fmt == "gt3x":
        out["actigraph"] = _actigraph(info, src)
    warnings = info.header.get("warnings") if isinstance(info.header, dict) else None
    if warnings:
        out["header_warnings"] = list(warnings)
    return out


def _actigraph(info, src) -> dict:
    """What an ActiGraph .gt3x adds: model, layout, scale and its source, the stored zone, idle
    sleep (set up, and the seconds slept, after a full read)."""
    h = info.header
    stored = h.get("timezone_stored_s")
    d = {"model": h.get("model"), "layout": h.get("layout"), "scale_lsb_per_g": h.get("scale"),
         "scale_source": h.get("scale_source"),
         "timezone_stored": None if stored is None else offset_text(stored),
         "idle_sleep_enabled": h.get("idle_sleep_enabled"),
         "axis_swap_fixed": h.get("axis_swap_fixed")}
    if src is not None:
        d.update({"idle_sleep_s": src.idle_sleep_s,
                  "idle_sleep_periods": len(src.idle_periods),
                  "usb_connections": len(src.usb_connections)})
    return d
