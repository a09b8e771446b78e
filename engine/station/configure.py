"""Configuring a device for the next wearer from a study profile (usb-protocols.md A7).

``configure_device(client, profile, *, data_file, wait_volume, session_now)``: the profile checked
against the device's type (``StudyProfile.check_device``: what it cannot record is refused before
any setting is sent); LED blue; battery at least the profile's minimum; the data file must be empty
(at most the 1024-byte header: a new recording is never appended to an old one); the clock set the
way OMGui does (``sync_time``); RATE, SESSION, MAXSAMPLES 0, DEBUG, HIBERNATE, STOP and the 14
annotation slots, each reply read back and checked; COMMIT with delayed activation; the data file's
header read back (device, session, rate code); LED magenta. Returns (settings, warnings). Each step
is retried up to ``AX_CONFIGURE_RETRIES`` times, 1 s apart, except the checks. A profile's session
"increment" counts from ``session_now`` (``clearing.session_before_clear``: a clear leaves the
device at session 0).
"""

from __future__ import annotations

import datetime as _dt
import os
import time
from pathlib import Path
from typing import Callable, Optional

from stillpoint.drivers import constants as C
from stillpoint.drivers.ax.errors import DeviceError, DeviceLocked
from stillpoint.drivers.cwa_layout import parse_header

from .profile import StudyProfile


def _retry(fn, *args, tries: int = C.AX_CONFIGURE_RETRIES, wait_s: float = 1.0):
    for i in range(tries):
        try:
            return fn(*args)
        except DeviceLocked:
            raise
        except DeviceError:
            if i == tries - 1:
                raise
            time.sleep(wait_s)


def sync_time(client, *, tolerance_s: float = C.AX_TIME_TOLERANCE_S) -> float:
    """Set the device clock to host local wall-clock time as OMGui does: wait for the host's
    second to roll over, set, read back within ``tolerance_s``, check that the clock ticks.
    Returns the offset (device - host, s) read back after setting."""
    now = time.time()
    time.sleep(1.0 - (now % 1.0))  # at the start of a host second
    target = _dt.datetime.fromtimestamp(time.time()).replace(microsecond=0)
    got = _retry(client.set_time, target)
    if abs((got - target).total_seconds()) > tolerance_s:
        raise DeviceError(client.name, f"clock set to {target} but reads back {got}")
    t1 = client.time()
    time.sleep(1.1)
    t2 = client.time()
    if t2 <= t1:
        raise DeviceError(client.name, f"the device clock does not tick ({t1} then {t2})")
    return clock_offset_s(client)


def clock_offset_s(client) -> float:
    """Device clock minus host local wall-clock time, in seconds (ms resolution: SAMPLE 4)."""
    t0 = time.time()
    dev = client.sample_time()
    t1 = time.time()
    host = _dt.datetime.fromtimestamp((t0 + t1) / 2)
    return (dev - host).total_seconds()


def configure_device(client, profile: StudyProfile, *, data_file, wait_volume: Optional[Callable],
                     session_now: int) -> tuple[dict, list[str]]:
    warnings: list[str] = []
    ax6 = client_is_ax6(client)
    profile.check_device("AX6" if ax6 else "AX3")
    client.led(1)
    batt = client.battery()
    if batt.percent < profile.min_battery_pct:
        raise DeviceError(client.name, f"battery {batt.percent} % is below the profile's minimum "
                                       f"{profile.min_battery_pct} %: charge it before configuring")
    if batt.percent < 50:
        warnings.append(f"battery low ({batt.percent} %)")
    size = os.stat(data_file).st_size if data_file and os.path.exists(data_file) else 0
    if size > C.AX_EMPTY_DATA_BYTES:
        raise DeviceError(client.name, f"the device still holds data ({size} bytes): download and "
                                       "clear it first (a new recording is never appended to an old one)")
    offset = sync_time(client)
    gyro = profile.gyro_dps if ax6 else 0
    code, hz, g = _retry(client.rate, profile.rate_code, gyro or None)
    if code != profile.rate_code or (gyro and g != gyro):
        raise DeviceError(client.name, f"RATE reads back {code},{hz},{g}; expected "
                                       f"{profile.rate_code} gyro {gyro}")
    session = profile.session_for(session_now)
    if _retry(client.session, session) != session:
        raise DeviceError(client.name, f"SESSION does not read back {session}")
    if _retry(client.maxsamples, 0) != 0:
        raise DeviceError(client.name, "MAXSAMPLES does not read back 0")
    dbg = 3 if profile.led_flash else 0
    if _retry(client.debug, dbg) != dbg:
        raise DeviceError(client.name, f"DEBUG does not read back {dbg}")
    now = _dt.datetime.now()
    start, stop, start_dt = profile.times(now)
    if start_dt is not None and start_dt < now:
        warnings.append(f"start {start_dt.isoformat(timespec='seconds')} is in the past: recording starts when unplugged")
    for cmd, want in ((client.hibernate, start), (client.stop, stop)):
        got = _retry(cmd, want)
        if got.strip() != want:
            raise DeviceError(client.name, f"{cmd.__name__.upper()} reads back {got!r}, expected {want!r}")
    for i, text in enumerate(profile.annotation_slots()):
        got = _retry(client.annotate, i, text)
        if got.rstrip() != text.rstrip():
            raise DeviceError(client.name, f"ANNOTATE{i:02d} reads back {got!r}")
    client.commit(wait_volume)
    path = Path(wait_volume()) if wait_volume else Path(data_file)
    with open(path, "rb") as f:
        h = parse_header(f.read(C.CWA_HEADER_BYTES))
    if h["session_id"] != session or h["rate_code"] != profile.rate_code:
        raise DeviceError(client.name, f"after COMMIT the header says session {h['session_id']} rate "
                                       f"code {h['rate_code']}; expected {session}, {profile.rate_code}")
    client.led(5)
    settings = {"session": session, "rate_code": profile.rate_code, "rate_hz": profile.rate_hz,
                "range_g": profile.range_g, "gyro_dps": gyro, "start": start, "stop": stop,
                "metadata": profile.metadata, "clock_offset_s": round(offset, 3),
                "battery_pct": batt.percent}
    return settings, warnings


def client_is_ax6(client) -> bool:
    kind = getattr(client, "_kind", None)
    if kind is None:
        kind = client.identify().device_type
        client._kind = kind
    return kind == "AX6"
