"""The station's ledger: an SQLite database in the output folder (``stillpoint-ledger.sqlite``).

It records the devices seen (by id and type: an AX3 and an AX6 may share an id), every download
(device type and id, session, bytes, SHA-256, verified, times, clock offset, host time zone,
station id, battery, bad sectors, the ranges its verification read again and the ranges of the
copy it patched, the calibration prior its log started from), every clear and
configuration (with the device type), every state change of a device (``events``, with its USB
serial), the analysis products made from each verified download (``products``: the epoch and
day tables, the report, the calibration store entry; written, kept, skipped or failed, with the
reason), every action asked for from the dashboard (``actions``: retry, verify, clear,
configure; who asked, from which address, with what result). WAL journal, one transaction
per state change, so a crash at any moment leaves it consistent. The clear rule
(``clearing``) asks it for a verified download of the exact device type, id and session.

A second station on the same folder is refused: the station holds an exclusive ``flock`` on
``.stillpoint-station.lock`` for its lifetime (``acquire_station_lock``). A ledger, journal or
lock path that is a symbolic link is refused (the ledger would be written where it points).

A download row goes ``downloading`` -> ``completing`` (the copy's size and SHA-256 recorded, its
files not yet renamed) -> ``verified`` (renamed: ``completion``), or ``error`` / ``changed`` (the
device's data changed between reads: never cleared automatically). ``completion.reconcile``
resolves the rows a killed station left in between.

``kill_point(step)``: a station started with ``STILLPOINT_KILL_AT=<step>`` in its environment kills
itself (SIGKILL) at that step, for the kill trials (``tools/kill_station.py``); the steps are the
ledger writes and the renames between them (``KILL_STEPS``, and ``KILL_STEPS_CONFIGURE`` when
the station configures devices too).
"""

from __future__ import annotations

import json
import os
import socket
import sqlite3
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

from stillpoint.engine.core.errors import StillpointError

from ..core.times import offset_text
LEDGER_NAME = "stillpoint-ledger.sqlite"
LOCK_NAME = ".stillpoint-station.lock"
KILL_ENV = "STILLPOINT_KILL_AT"
# every step a kill trial can stop the station at, in the order a device meets them
KILL_STEPS = ("event:identifying", "download:started", "event:downloading", "download:copying",
              "event:verifying", "download:completing", "completion:raw-renamed",
              "completion:renamed", "download:verified", "event:verified", "event:clearing",
              "clear:sent", "clear:result", "event:cleared")
KILL_STEPS_CONFIGURE = ("event:configuring", "event:configured")  # with --configure-after


def kill_point(step: str) -> None:
    """SIGKILL this process if the environment names ``step`` (kill trials only)."""
    if os.environ.get(KILL_ENV) == step:
        import signal
        os.kill(os.getpid(), signal.SIGKILL)

_SCHEMA = """
CREATE TABLE IF NOT EXISTS devices (
    device_id INTEGER NOT NULL, device_type TEXT NOT NULL, serial TEXT, firmware INTEGER,
    slot TEXT, first_seen REAL, last_seen REAL, PRIMARY KEY (device_id, device_type));
CREATE TABLE IF NOT EXISTS downloads (
    id INTEGER PRIMARY KEY AUTOINCREMENT, device_id INTEGER NOT NULL, session_id INTEGER NOT NULL,
    state TEXT NOT NULL, bytes INTEGER, sha256 TEXT, verified INTEGER NOT NULL DEFAULT 0,
    started REAL, finished REAL, clock_offset_s REAL, host_tz TEXT, station_id TEXT,
    battery_pct INTEGER, bad_sectors INTEGER, cwa_path TEXT, mcap_path TEXT, reason TEXT,
    summary TEXT);
CREATE TABLE IF NOT EXISTS clears (
    id INTEGER PRIMARY KEY AUTOINCREMENT, device_id INTEGER NOT NULL, session_id INTEGER NOT NULL,
    download_id INTEGER, sha256 TEXT, time REAL, result TEXT, reason TEXT);
CREATE TABLE IF NOT EXISTS configurations (
    id INTEGER PRIMARY KEY AUTOINCREMENT, device_id INTEGER NOT NULL, session_id INTEGER,
    time REAL, settings TEXT, result TEXT, reason TEXT);
CREATE TABLE IF NOT EXISTS events (
    id INTEGER PRIMARY KEY AUTOINCREMENT, time REAL, device_id INTEGER, serial TEXT,
    state TEXT, reason TEXT);
CREATE TABLE IF NOT EXISTS products (
    id INTEGER PRIMARY KEY AUTOINCREMENT, download_id INTEGER NOT NULL, time REAL,
    product TEXT NOT NULL, path TEXT, result TEXT NOT NULL, reason TEXT);
CREATE TABLE IF NOT EXISTS actions (
    id INTEGER PRIMARY KEY AUTOINCREMENT, time REAL, device_id INTEGER, device_type TEXT,
    action TEXT, who TEXT, origin TEXT, result TEXT, reason TEXT, detail TEXT);
"""


# Columns tables gained after their first release (an older ledger gets them when opened; its
# rows keep NULL there, and a NULL device type matches any type): the clear's erase level and
# what was read back after the erase; the device type of downloads, clears and configurations
# (an AX3 and an AX6 may share an id); the calibration prior a download's log was corrected with
# from its first sample; the ranges the verification read again and the ranges of the copy it
# patched (a misread resolved: every repair is on record).
_ADDED_COLUMNS = (("clears", "erase", "TEXT"), ("clears", "readback", "TEXT"),
                  ("clears", "device_type", "TEXT"), ("downloads", "device_type", "TEXT"),
                  ("configurations", "device_type", "TEXT"), ("downloads", "prior", "TEXT"),
                  ("downloads", "reread_ranges", "INTEGER"), ("downloads", "patched_ranges", "INTEGER"))
# a row of the device type asked for, or of a ledger older than the type column
_OF_TYPE = "(? IS NULL OR device_type IS NULL OR device_type=?)"


def _add_columns(db) -> None:
    for table, name, kind in _ADDED_COLUMNS:
        have = {r[1] for r in db.execute(f"PRAGMA table_info({table})").fetchall()}
        if name not in have:
            db.execute(f"ALTER TABLE {table} ADD COLUMN {name} {kind}")
    # the devices table was keyed by the id alone (an AX6 replaced the AX3 of the same id): rebuilt
    # keyed by id and type, its rows kept
    key = [r[1] for r in sorted(db.execute("PRAGMA table_info(devices)").fetchall(),
                                key=lambda r: r[5]) if r[5]]
    if key == ["device_id"]:
        db.executescript(
            "BEGIN IMMEDIATE; ALTER TABLE devices RENAME TO devices_by_id;"
            + _SCHEMA[_SCHEMA.index("CREATE TABLE IF NOT EXISTS devices"):
                      _SCHEMA.index("CREATE TABLE IF NOT EXISTS downloads")]
            + "INSERT INTO devices SELECT device_id, COALESCE(device_type, ''), serial, firmware, "
              "slot, first_seen, last_seen FROM devices_by_id; DROP TABLE devices_by_id; COMMIT;")


def _refuse_links(folder: Path) -> None:
    for name in (LEDGER_NAME, LEDGER_NAME + "-wal", LEDGER_NAME + "-shm", LOCK_NAME):
        if os.path.islink(folder / name):
            raise LedgerError(f"{folder / name}: is a symbolic link; the ledger is only written "
                              "in the output folder itself (remove the link)")


class LedgerError(StillpointError):
    """The ledger cannot be opened or a second station wants the same folder."""


@dataclass
class DownloadRecord:
    id: int
    device_id: int
    session_id: int
    state: str
    bytes: Optional[int]
    sha256: Optional[str]
    verified: bool
    cwa_path: Optional[str]
    mcap_path: Optional[str]
    reason: Optional[str]
    device_type: Optional[str] = None  # None: a row older than the type column
    bad_sectors: Optional[int] = None


def station_id() -> str:
    return f"{socket.gethostname()}:{os.getpid()}"


def host_timezone() -> str:
    off = time.localtime().tm_gmtoff
    return f"{time.strftime('%Z')} (UTC{offset_text(off)})"


def check_station_folder(folder) -> Path:
    """The output folder of ``station`` and of ``device download/verify/clear``: it must exist
    and be writable. It is never created: a mistyped path, or the mount point of a disk that is
    not mounted, would otherwise receive a study's downloads unnoticed."""
    from stillpoint.engine.core.outputs import check_output_folder
    p = Path(folder)
    if not os.path.lexists(p):
        raise LedgerError(f"{p}: the output folder does not exist; it is never created for you "
                          "(a mistyped path or an unmounted disk would receive the downloads): "
                          "create it first (mkdir)")
    return check_output_folder(p)


def acquire_station_lock(folder) -> int:
    """Hold the folder's station lock (returns the fd; close it to release)."""
    import fcntl
    p = Path(folder) / LOCK_NAME
    _refuse_links(Path(folder))
    try:
        fd = os.open(p, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW, 0o644)
    except OSError as e:
        raise LedgerError(f"{folder}: cannot create the station lock: {e.strerror}") from None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        other = ""
        try:
            other = os.pread(fd, 200, 0).decode(errors="replace").strip()
        except OSError:
            pass
        os.close(fd)
        raise LedgerError(f"{folder}: another station is already using this folder"
                          + (f" ({other})" if other else "")) from None
    os.ftruncate(fd, 0)
    os.pwrite(fd, station_id().encode(), 0)
    return fd


class Ledger:
    """The ledger of one output folder (see module docstring). Thread-safe: one connection per
    call site is not needed; every method runs one short transaction under a lock."""

    def __init__(self, folder):
        import threading
        self.folder = Path(folder)
        self.path = self.folder / LEDGER_NAME
        _refuse_links(self.folder)
        try:
            self.db = sqlite3.connect(self.path, timeout=10.0, isolation_level=None,
                                      check_same_thread=False)
            self.db.execute("PRAGMA journal_mode=WAL")
            self.db.execute("PRAGMA synchronous=FULL")
            self.db.executescript(_SCHEMA)
        except sqlite3.Error as e:
            raise LedgerError(f"{self.path}: cannot open the ledger: {e}") from None
        try:  # every page read once: damage is refused at the start, not at a device's clear
            check = self.db.execute("PRAGMA quick_check").fetchall()
        except sqlite3.DatabaseError as e:
            check = [(str(e),)]
        if check != [("ok",)]:
            self.db.close()
            raise LedgerError(f"{self.path}: the ledger is damaged ({check[0][0]}); move it "
                              "aside or restore it from a backup (no device is cleared "
                              "without it)")
        try:
            _add_columns(self.db)
        except sqlite3.Error as e:
            self.db.close()
            raise LedgerError(f"{self.path}: cannot open the ledger: {e}") from None
        self._lock = threading.Lock()

    def close(self) -> None:
        self.db.close()

    def _tx(self, sql: str, args=()) -> int:
        with self._lock:
            try:
                self.db.execute("BEGIN IMMEDIATE")
                cur = self.db.execute(sql, args)
                self.db.execute("COMMIT")
            except sqlite3.Error as e:
                try:
                    self.db.execute("ROLLBACK")
                except sqlite3.Error:
                    pass
                raise LedgerError(f"{self.path}: cannot write the ledger: {e}") from None
            return cur.lastrowid

    def _q(self, sql: str, args=()) -> list:
        with self._lock:
            try:
                return self.db.execute(sql, args).fetchall()
            except sqlite3.Error as e:  # a damaged file: no verified record can be trusted
                raise LedgerError(f"{self.path}: cannot read the ledger: {e}") from None

    # ------------------------------------------------------------------ writes
    def event(self, device_id, serial, state: str, reason: Optional[str] = None) -> None:
        self._tx("INSERT INTO events(time, device_id, serial, state, reason) VALUES (?,?,?,?,?)",
                 (time.time(), device_id, serial, state, reason))
        kill_point(f"event:{state}")

    def device_seen(self, device_id: int, device_type: str, serial: str, firmware, slot) -> None:
        now = time.time()
        self._tx("INSERT INTO devices VALUES (?,?,?,?,?,?,?) ON CONFLICT(device_id, device_type) DO "
                 "UPDATE SET serial=excluded.serial, firmware=excluded.firmware, "
                 "slot=excluded.slot, last_seen=excluded.last_seen",
                 (device_id, device_type, serial, firmware, slot, now, now))

    def download_started(self, device_id: int, session_id: int, *, clock_offset_s=None,
                         battery_pct=None, cwa_path=None, mcap_path=None,
                         device_type: Optional[str] = None, prior: Optional[dict] = None) -> int:
        """``prior``: the calibration the log is corrected with from its first sample (where it
        came from), None for a ledger user that does not say."""
        i = self._tx(
            "INSERT INTO downloads(device_id, session_id, state, started, clock_offset_s, host_tz, "
            "station_id, battery_pct, cwa_path, mcap_path, device_type, prior) "
            "VALUES (?,?,?,?,?,?,?,?,?,?,?,?)",
            (device_id, session_id, "downloading", time.time(), clock_offset_s, host_timezone(),
             station_id(), battery_pct, cwa_path, mcap_path, device_type,
             json.dumps(prior, sort_keys=True) if prior is not None else None))
        kill_point("download:started")
        return i

    def download_failed(self, download_id: int, reason: str, bytes_=None, *,
                        state: str = "error") -> None:
        """``state``: ``error``, or ``changed`` when the device's data changed between reads."""
        self._tx("UPDATE downloads SET state=?, verified=0, reason=?, bytes=?, finished=? "
                 "WHERE id=?", (state, reason, bytes_, time.time(), download_id))

    def download_completing(self, download_id: int, *, bytes_: int, sha256: str,
                            bad_sectors: int, cwa_path: str, mcap_path: Optional[str],
                            summary: Optional[dict] = None, reread_ranges: int = 0,
                            patched_ranges: int = 0) -> None:
        """The copy is verified (size and SHA-256 recorded, and the ranges the verification read
        again and patched), its files not yet renamed."""
        self._tx("UPDATE downloads SET state='completing', verified=0, bytes=?, sha256=?, "
                 "bad_sectors=?, cwa_path=?, mcap_path=?, summary=?, reason=NULL, "
                 "reread_ranges=?, patched_ranges=? WHERE id=?",
                 (bytes_, sha256, bad_sectors, cwa_path, mcap_path,
                  json.dumps(summary, default=str) if summary else None, int(reread_ranges),
                  int(patched_ranges), download_id))
        kill_point("download:completing")

    def download_verified(self, download_id: int, *, bytes_: int, sha256: str, bad_sectors: int,
                          cwa_path: str, mcap_path: str, summary: Optional[dict] = None,
                          reason: Optional[str] = None) -> None:
        self._tx("UPDATE downloads SET state='verified', verified=1, bytes=?, sha256=?, "
                 "bad_sectors=?, cwa_path=?, mcap_path=?, finished=?, "
                 "summary=COALESCE(?, summary), reason=? WHERE id=?",
                 (bytes_, sha256, bad_sectors, cwa_path, mcap_path, time.time(),
                  json.dumps(summary, default=str) if summary else None, reason, download_id))
        kill_point("download:verified")

    def clear_attempt(self, device_id: int, session_id: int, download_id: int, sha256: str,
                      erase: Optional[str] = None, device_type: Optional[str] = None) -> int:
        i = self._tx("INSERT INTO clears(device_id, session_id, download_id, sha256, time, result, "
                     "erase, device_type) VALUES (?,?,?,?,?,?,?,?)",
                     (device_id, session_id, download_id, sha256, time.time(), "sent", erase,
                      device_type))
        kill_point("clear:sent")
        return i

    def clear_result(self, clear_id: int, result: str, reason: Optional[str] = None,
                     readback: Optional[str] = None) -> None:
        kill_point("clear:result")  # before the write: the clear is done, the row still 'sent'
        self._tx("UPDATE clears SET result=?, reason=?, readback=? WHERE id=?",
                 (result, reason, readback, clear_id))

    def configured(self, device_id: int, session_id, settings: dict, result: str,
                   reason: Optional[str] = None, device_type: Optional[str] = None) -> None:
        self._tx("INSERT INTO configurations(device_id, session_id, time, settings, result, reason, "
                 "device_type) VALUES (?,?,?,?,?,?,?)",
                 (device_id, session_id, time.time(), json.dumps(settings, default=str), result,
                  reason, device_type))

    def product(self, download_id: int, product: str, path: Optional[str], result: str,
                reason: Optional[str] = None) -> None:
        """One analysis product of a verified download: ``result`` is ``written``, ``kept``
        (already there, not replaced), ``skipped`` or ``failed`` (``reason`` says why)."""
        self._tx("INSERT INTO products(download_id, time, product, path, result, reason) "
                 "VALUES (?,?,?,?,?,?)", (download_id, time.time(), product, path, result, reason))

    def action_asked(self, device_id: int, device_type: str, action: str, *, who: str,
                     origin: str, detail: Optional[dict] = None) -> int:
        """An action asked for from the dashboard (``result`` 'asked' until ``action_result``)."""
        return self._tx("INSERT INTO actions(time, device_id, device_type, action, who, origin, "
                        "result, detail) VALUES (?,?,?,?,?,?,?,?)",
                        (time.time(), device_id, device_type, action, who, origin, "asked",
                         json.dumps(detail, default=str) if detail else None))

    def action_result(self, action_id: int, result: str, reason: Optional[str] = None) -> None:
        """``result``: 'started' (a flow runs it), 'ok', 'refused' or 'error' (with the reason)."""
        self._tx("UPDATE actions SET result=?, reason=? WHERE id=?", (result, reason, action_id))

    # ------------------------------------------------------------------ reads
    def products(self, download_id: Optional[int] = None) -> list[tuple]:
        """(download id, product, path, result, reason) per product row (this download's)."""
        return self._q("SELECT download_id, product, path, result, reason FROM products WHERE "
                       "(? IS NULL OR download_id=?) ORDER BY id", (download_id, download_id))

    def repairs_of(self, download_id: int) -> tuple[int, int]:
        """(ranges re-read, ranges of the copy patched) of a download (0, 0 when not recorded)."""
        rows = self._q("SELECT reread_ranges, patched_ranges FROM downloads WHERE id=?",
                       (download_id,))
        return (int(rows[0][0] or 0), int(rows[0][1] or 0)) if rows else (0, 0)

    def prior_of(self, download_id: int) -> Optional[dict]:
        """The calibration prior recorded for a download (None: not recorded)."""
        rows = self._q("SELECT prior FROM downloads WHERE id=?", (download_id,))
        return json.loads(rows[0][0]) if rows and rows[0][0] else None

    def _rec(self, row) -> DownloadRecord:
        return DownloadRecord(row[0], row[1], row[2], row[3], row[4], row[5], bool(row[6]),
                              row[7], row[8], row[9], row[10], row[11])

    _COLS = ("id, device_id, session_id, state, bytes, sha256, verified, cwa_path, mcap_path, "
             "reason, device_type, bad_sectors")

    def verified_download(self, device_id: int, session_id: int,
                          sha256: Optional[str] = None,
                          device_type: Optional[str] = None) -> Optional[DownloadRecord]:
        """The latest verified download of this device and session (and hash, and device type,
        if given: rows older than the type column match any type) whose raw copy is still
        where the ledger says."""
        rows = self._q(f"SELECT {self._COLS} FROM downloads WHERE device_id=? AND session_id=? "
                       f"AND verified=1 AND state='verified' AND {_OF_TYPE} ORDER BY id DESC",
                       (device_id, session_id, device_type, device_type))
        for r in rows:
            rec = self._rec(r)
            if sha256 is not None and rec.sha256 != sha256:
                continue
            if rec.cwa_path and os.path.isfile(rec.cwa_path):
                return rec
        return None

    def verified_by_sha256(self, sha256: str) -> Optional[DownloadRecord]:
        """The latest verified download with these bytes whose raw copy is still where the
        ledger says (the inbox ingests each file's content once)."""
        rows = self._q(f"SELECT {self._COLS} FROM downloads WHERE sha256=? AND verified=1 "
                       "AND state='verified' ORDER BY id DESC", (sha256,))
        for r in rows:
            rec = self._rec(r)
            if rec.cwa_path and os.path.isfile(rec.cwa_path):
                return rec
        return None

    def data_changed(self, device_id: int, session_id: int,
                     device_type: Optional[str] = None) -> Optional[DownloadRecord]:
        """The latest download of this device and session whose data changed between reads."""
        rows = self._q(f"SELECT {self._COLS} FROM downloads WHERE device_id=? AND session_id=? "
                       f"AND state='changed' AND {_OF_TYPE} ORDER BY id DESC LIMIT 1", (device_id, session_id, device_type, device_type))
        return self._rec(rows[0]) if rows else None

    def downloads_in(self, state: str) -> list[DownloadRecord]:
        return [self._rec(r) for r in self._q(f"SELECT {self._COLS} FROM downloads WHERE state=? "
                                              "ORDER BY id", (state,))]

    def sent_clears(self, device_id: int, device_type: Optional[str] = None) -> list[tuple]:
        """(clear id, session, download id, SHA-256) of this device's clears left at ``sent``."""
        return self._q("SELECT id, session_id, download_id, sha256 FROM clears WHERE device_id=? "
                       f"AND result='sent' AND {_OF_TYPE} ORDER BY id",
                       (device_id, device_type, device_type))

    def downloads(self, device_id: Optional[int] = None,
                  device_type: Optional[str] = None) -> list[DownloadRecord]:
        """Every download, or this device's (of this type, if given)."""
        rows = self._q(f"SELECT {self._COLS} FROM downloads WHERE (? IS NULL OR device_id=?) "
                       f"AND {_OF_TYPE} ORDER BY id", (device_id, device_id, device_type, device_type))
        return [self._rec(r) for r in rows]

    def clears(self, device_id: Optional[int] = None,
               device_type: Optional[str] = None) -> list[tuple]:
        """(device, session, download id, SHA-256, result, reason, erase level, read-back) per clear
        (this device's, of this type, if given)."""
        return self._q("SELECT device_id, session_id, download_id, sha256, result, reason, erase, "
                       f"readback FROM clears WHERE (? IS NULL OR device_id=?) AND {_OF_TYPE} "
                       "ORDER BY id", (device_id, device_id, device_type, device_type))

    def configuration_of(self, device_id: int, session_id: int,
                         device_type: Optional[str] = None) -> Optional[dict]:
        """The settings of the latest successful configuration of this device and session."""
        rows = self._q("SELECT settings FROM configurations WHERE device_id=? AND session_id=? "
                       f"AND result='ok' AND {_OF_TYPE} ORDER BY id DESC LIMIT 1",
                       (device_id, session_id, device_type, device_type))
        try:
            return json.loads(rows[0][0]) if rows and rows[0][0] else None
        except ValueError:
            return None

    def configured_since_clear(self, device_id: int, session_id: int,
                               device_type: Optional[str] = None) -> Optional[tuple]:
        """(time, settings) of the latest successful configuration of this device for
        ``session_id`` that no completed clear of the device followed, or None."""
        rows = self._q("SELECT time, settings FROM configurations WHERE device_id=? AND "
                       f"session_id=? AND result='ok' AND {_OF_TYPE} AND time > COALESCE((SELECT "
                       "MAX(time) FROM clears WHERE device_id=? AND result='ok' AND "
                       f"{_OF_TYPE}), 0) ORDER BY id DESC LIMIT 1",
                       (device_id, session_id, device_type, device_type, device_id, device_type,
                        device_type))
        return tuple(rows[0]) if rows else None

    def events(self, device_id: Optional[int] = None) -> list[tuple]:
        if device_id is None:
            return self._q("SELECT device_id, state, reason FROM events ORDER BY id")
        return self._q("SELECT device_id, state, reason FROM events WHERE device_id=? ORDER BY id",
                       (device_id,))
