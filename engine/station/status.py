"""A one-row summary of each attached device (``stillpoint devices``), each read with a bound so
a device that does not answer never stalls the listing, and only under the device's host-wide
lock (a device a station holds is listed ``busy``, its port untouched: ``hostlock``);
``recording_window`` says a device's start and stop settings in words."""

from __future__ import annotations

import concurrent.futures as cf
import datetime as _dt
import os

from stillpoint.drivers import constants as C
from stillpoint.drivers.ax.discovery import Attached, discover
from stillpoint.drivers.ax.protocol import AxClient, parse_time


def recording_window(start: str, stop: str) -> str:
    """The recording window a device's ``HIBERNATE`` (start) and ``STOP`` replies set, in words.

    The firmware records while start <= now < stop, and never when start >= stop ([FW]
    Firmware/AX3/Firmware/src/main.c 516-529, ``drivers/constants.py`` AX_NEVER_LOG); ``0`` is the
    earliest time and ``-1`` the latest ([USB] A4, ``drivers/ax/protocol.py`` parse_time). So
    0 .. -1 is "always", a start of -1 or a stop of 0 (the vendor's "never log") is "never",
    0 .. T is "until T", T .. -1 is "from T", and T1 .. T2 is "T1 to T2" (device-clock times)."""
    def when(text):
        t = text.strip()
        if t == C.AX_DATETIME_ALWAYS:
            return "earliest"
        if t == C.AX_DATETIME_NEVER or t.startswith("-"):
            return "latest"
        try:
            return parse_time(t)
        except ValueError:
            return None
    a, b = when(start), when(stop)
    if a is None or b is None:
        return f"{start}..{stop}"  # a reply this rule does not know: as the device said it
    if a == "latest" or b == "earliest":
        return "never"
    if a == "earliest" and b == "latest":
        return "always"
    fmt = "%Y-%m-%d %H:%M:%S"
    if a == "earliest":
        return f"until {b.strftime(fmt)}"
    if b == "latest":
        return f"from {a.strftime(fmt)}"
    return "never" if a >= b else f"{a.strftime(fmt)} to {b.strftime(fmt)}"


def device_status(att: Attached, ledger=None) -> dict:
    row = {"id": att.device_id, "type": att.device_type, "serial": att.serial, "port": att.port,
           "volume": att.volume, "slot": att.slot, "emulated": att.emulated}
    if att.problem:
        row.update(state="no drive", problem=att.problem)
    from .hostlock import DeviceBusy, DeviceLock, key_of
    lock = DeviceLock(key_of(att), None, what="device listing")
    try:  # a device a station holds is not asked anything (its port is the station's)
        lock.acquire(att.device_id)
    except DeviceBusy as e:
        row.update(state="busy", problem=e.reason)
        return row
    try:
        return _read(att, row, ledger)
    finally:
        lock.release()


def _read(att: Attached, row: dict, ledger) -> dict:
    client = AxClient.open(att.port, str(att.device_id))
    try:
        from .configure import clock_offset_s
        client.stream_stop()
        ident = client.identify()
        row.update(firmware=ident.firmware, session=ident.session_id)
        if ident.device_id != att.device_id:
            row.update(state="error", problem=f"ID names device {ident.device_id}, the USB serial "
                                              f"{att.device_id}")
            return row
        row["battery_pct"] = client.battery().percent
        row["clock_offset_s"] = round(clock_offset_s(client), 3)
        row["start"], row["stop"] = client.hibernate(), client.stop()
        row["window"] = recording_window(row["start"], row["stop"])
    finally:
        client.close()
    if att.volume:
        size = os.stat(att.data_file).st_size
        row["data_bytes"] = size
        state = "has data" if size > C.AX_EMPTY_DATA_BYTES else "empty"
        if state == "has data":
            stop = parse_time(row["stop"]) if row["stop"] not in ("-1",) else None
            if row["stop"] == "-1" or (stop is not None and stop > _dt.datetime.now()):
                state = "has data (recording window still open)"
            if ledger is not None:
                recs = [r for r in ledger.downloads(att.device_id, att.device_type)
                        if r.session_id == row["session"]]
                if ledger.verified_download(att.device_id, row["session"],
                                            device_type=att.device_type):
                    state = "verified"
                elif recs and recs[-1].state == "downloading":
                    state = "downloading"
                elif recs and recs[-1].state == "error":
                    state = f"has data (last download failed: {recs[-1].reason})"
        row.setdefault("state", state)
    return row


def list_devices(backend=None, ledger=None, timeout_s: float = 8.0, **overrides) -> list[dict]:
    atts = discover(backend, **overrides)
    rows = []
    with cf.ThreadPoolExecutor(max_workers=max(1, len(atts))) as ex:
        futs = [(a, ex.submit(device_status, a, ledger)) for a in atts]
        for a, f in futs:
            try:
                rows.append(f.result(timeout=timeout_s))
            except cf.TimeoutError:
                rows.append({"id": a.device_id, "type": a.device_type, "slot": a.slot,
                             "state": "error", "problem": f"no answer within {timeout_s:g} s"})
            except Exception as e:  # noqa: BLE001 - one row per device, never a traceback
                rows.append({"id": a.device_id, "type": a.device_type, "slot": a.slot,
                             "state": "error", "problem": str(getattr(e, "reason", e))})
    return rows
