"""What the dashboard shows from the ledger, read through its own read-only connection (a
dashboard never writes the ledger's rows of record and never holds the station lock).

``Records(folder)``: ``devices()`` (one dict per device the ledger has seen, with its last
state), ``history(device_type, device_id)`` (every download, clear, configuration, action and
state change of one device, oldest first) and ``trends(history)`` (battery at return, clock drift
per day between a configuration and the next download, calibration offset and gain with their
standard errors, one point per download). Times are kept as UNIX seconds; ``local_utc(t)`` gives
the two texts the pages show.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import json
import os
import shutil
import sqlite3
import threading
import time
from pathlib import Path
from typing import Optional

from ..ledger import LEDGER_NAME, LedgerError

# a device's data file at its largest: the AX3's 512 MB of flash (Axivity AX3 data sheet,
# "512 MB memory"); used for the AX6 too, as an estimate of how many downloads fit
AX3_FULL_BYTES = 512 * 1024 * 1024


def local_utc(t: Optional[float]) -> tuple[str, str]:
    """(host local time with its zone, UTC) texts of a UNIX time; ('-', '-') for none."""
    if t is None:
        return "-", "-"
    loc = _dt.datetime.fromtimestamp(t).astimezone()
    utc = _dt.datetime.fromtimestamp(t, _dt.timezone.utc)
    return (loc.strftime("%Y-%m-%d %H:%M:%S %Z"), utc.strftime("%Y-%m-%d %H:%M:%SZ"))


def device_key(device_type: str, device_id: int) -> str:
    """``AX3-10001``: a device in the dashboard's addresses (an AX3 and an AX6 may share an id)."""
    return f"{device_type}-{device_id}"


def parse_device_key(key: str) -> Optional[tuple[str, int]]:
    kind, _, num = key.partition("-")
    if kind not in ("AX3", "AX6") or not (num.isascii() and num.isdigit()) or len(num) > 9:
        return None
    return kind, int(num)


class Records:
    """Read-only views of one output folder's ledger (module docstring)."""

    def __init__(self, folder):
        self.folder = Path(folder)
        self.path = self.folder / LEDGER_NAME
        self._local = threading.local()

    def _db(self) -> Optional[sqlite3.Connection]:
        if not self.path.is_file():
            return None
        try:
            db = sqlite3.connect(f"file:{self.path}?mode=ro", uri=True, timeout=5.0)
        except sqlite3.Error as e:
            raise LedgerError(f"{self.path}: cannot open the ledger: {e}") from None
        db.row_factory = sqlite3.Row
        return db

    def _rows(self, sql: str, args=()) -> list[dict]:
        db = getattr(self._local, "db", None)
        own = db is None
        if own:
            db = self._db()
        if db is None:
            return []
        try:
            return [dict(r) for r in db.execute(sql, args).fetchall()]
        except sqlite3.OperationalError as e:
            if "no such table" in str(e) or "no such column" in str(e):
                return []  # a ledger older than the table: nothing of that kind recorded
            raise LedgerError(f"{self.path}: cannot read the ledger: {e}") from None
        except sqlite3.Error as e:
            raise LedgerError(f"{self.path}: cannot read the ledger: {e}") from None
        finally:
            if own:
                db.close()

    @contextlib.contextmanager
    def reading(self):
        """One connection (one snapshot) for the reads of one page, on this thread."""
        if getattr(self._local, "db", None) is not None:
            yield
            return
        db = self._db()
        self._local.db = db
        try:
            if db is not None:
                db.execute("BEGIN")  # one consistent snapshot of the ledger for the page
            yield
        finally:
            self._local.db = None
            if db is not None:
                db.close()

    # ------------------------------------------------------------------ the dock
    def devices(self) -> list[dict]:
        """Every device seen, with its last state and reason and its latest download's facts."""
        devs = self._rows("SELECT device_id, device_type, serial, firmware, slot, last_seen "
                          "FROM devices ORDER BY device_type, device_id")
        events = self._rows("SELECT e.device_id, e.serial, e.state, e.reason, e.time FROM events e "
                            "JOIN (SELECT serial, MAX(id) AS id FROM events GROUP BY serial) last "
                            "ON e.id = last.id")
        by_serial = {e["serial"]: e for e in events}
        for d in devs:
            e = by_serial.get(d["serial"]) or {}
            d.update(state=e.get("state", "seen"), reason=e.get("reason"), state_time=e.get("time"))
            d.update(self.latest(d["device_type"], d["device_id"]))
        return devs

    def latest(self, device_type: str, device_id: int) -> dict:
        """Battery, clock offset and calibration of the device's latest download."""
        rows = self._rows("SELECT battery_pct, clock_offset_s, summary, state, reason FROM downloads "
                          "WHERE device_id=? AND (device_type IS NULL OR device_type=?) "
                          "ORDER BY id DESC LIMIT 1", (device_id, device_type))
        if not rows:
            return {"battery_pct": None, "clock_offset_s": None, "calibration": None}
        r = rows[0]
        return {"battery_pct": r["battery_pct"], "clock_offset_s": r["clock_offset_s"],
                "calibration": _calibration(r["summary"])}

    def disk(self) -> dict:
        """Free bytes in the output folder and about how many more downloads fit (the mean size
        of the verified ones; a full 512 MB drive when none is)."""
        free = shutil.disk_usage(self.folder).free
        sizes = [r["bytes"] for r in self._rows("SELECT bytes FROM downloads WHERE verified=1 "
                                                 "AND bytes IS NOT NULL")]
        # the raw copy plus its corrected log: about twice the raw size
        each = 2 * (sum(sizes) / len(sizes) if sizes else AX3_FULL_BYTES)
        return {"free_bytes": free, "per_download_bytes": int(each),
                "downloads_fit": int(free // each) if each else None, "from_ledger": bool(sizes)}

    # ------------------------------------------------------------------ one device
    def history(self, device_type: str, device_id: int) -> dict:
        of = "device_id=? AND (device_type IS NULL OR device_type=?)"
        a = (device_id, device_type)
        downloads = self._rows(f"SELECT * FROM downloads WHERE {of} ORDER BY id", a)
        for d in downloads:
            d["calibration"] = _calibration(d.pop("summary", None))
        clears = self._rows(f"SELECT * FROM clears WHERE {of} ORDER BY id", a)
        configs = self._rows(f"SELECT * FROM configurations WHERE {of} ORDER BY id", a)
        for c in configs:
            try:
                c["settings"] = json.loads(c["settings"]) if c["settings"] else {}
            except ValueError:
                c["settings"] = {}
        actions = self._rows(f"SELECT * FROM actions WHERE {of} ORDER BY id", a)
        serials = [r["serial"] for r in self._rows(
            "SELECT serial FROM devices WHERE device_id=? AND device_type=?", a)]
        events = self._rows("SELECT time, state, reason FROM events WHERE serial=? ORDER BY id",
                            (serials[0],)) if serials else []
        return {"device_type": device_type, "device_id": device_id, "downloads": downloads,
                "clears": clears, "configurations": configs, "actions": actions,
                "events": events, "known": bool(serials or downloads)}

    def inside(self, path: Optional[str]) -> Optional[Path]:
        """``path`` if it is an existing regular file inside the output folder (links resolved),
        else None: the only files the dashboard links to or serves."""
        if not path:
            return None
        try:
            real = Path(os.path.realpath(path))
            root = Path(os.path.realpath(self.folder))
        except (OSError, ValueError):
            return None
        if root not in real.parents or not real.is_file():
            return None
        return real


def _calibration(summary: Optional[str]) -> Optional[dict]:
    if not summary:
        return None
    try:
        return (json.loads(summary) or {}).get("calibration")
    except (ValueError, AttributeError):
        return None


def trends(hist: dict) -> dict:
    """One point per verified download: (session, battery %), (session, clock drift s/day since
    the configuration before it), (session, offset mg with SE, per axis), (session, gain % with
    SE, per axis)."""
    battery, drift, offset, gain = [], [], [], []
    configs = [c for c in hist["configurations"] if c.get("result") == "ok"]
    for d in hist["downloads"]:
        if d.get("state") != "verified":
            continue
        s = d["session_id"]
        if d.get("battery_pct") is not None:
            battery.append((s, float(d["battery_pct"]), None))
        before = [c for c in configs if c["time"] is not None and d["started"] is not None
                  and c["time"] < d["started"]]
        if before and d.get("clock_offset_s") is not None:
            c = before[-1]
            days = (d["started"] - c["time"]) / 86400.0
            set_off = c["settings"].get("clock_offset_s") or 0.0
            if days > 0:
                drift.append((s, (d["clock_offset_s"] - float(set_off)) / days, None))
        cal = d.get("calibration") or {}
        if cal.get("status") not in (None, "identity") and cal.get("offset") and cal.get("scale"):
            unc = cal.get("uncertainty") or {}
            for axis in range(3):
                se_o = (unc.get("offset") or [None] * 3)[axis]
                se_g = (unc.get("scale") or [None] * 3)[axis]
                offset.append((s, 1000.0 * cal["offset"][axis],
                               None if se_o is None else 1000.0 * se_o, "xyz"[axis]))
                gain.append((s, 100.0 * (cal["scale"][axis] - 1.0),
                             None if se_g is None else 100.0 * se_g, "xyz"[axis]))
    return {"battery": battery, "drift": drift, "offset": offset, "gain": gain,
            "now": time.time()}
