"""A one-row summary of each attached device (``stillpoint devices``), each read with a bound so
a device that does not answer never stalls the listing."""

from __future__ import annotations

import concurrent.futures as cf
import datetime as _dt
import os

from stillpoint.drivers import constants as C
from stillpoint.drivers.ax.discovery import Attached, discover
from stillpoint.drivers.ax.protocol import AxClient, parse_time


def device_status(att: Attached, ledger=None) -> dict:
    row = {"id": att.device_id, "type": att.device_type, "serial": att.serial, "port": att.port,
           "volume": att.volume, "slot": att.slot, "emulated": att.emulated}
    if att.problem:
        row.update(state="no drive", problem=att.problem)
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
