"""Per-device calibration store: every estimate a device has had, as JSON files in a directory.

Layout: ``<root>/calibration/<device file>.json``, one file per device (type + serial, the
``DeviceInfo.device_key`` "AX3-39434"), holding ``{"device_key", "records": [...]}``. A record is
one estimate with its provenance: when it was stored, the source file, the data range it was
fitted on, method, status and quality (errors before/after, windows, hours), plus the full
estimate. Root: ``$STILLPOINT_HOME`` or ``~/.local/share/stillpoint``.

Writes are atomic (temp file + rename) under a per-device lock, so parallel cohort jobs can
share a store; storing the same fit twice (same source, data range, method and parameters)
replaces the record instead of duplicating it. Autocalibration writes here; a static
six-orientation calibration writes here too (``method="static-6"``).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import re
import time
from pathlib import Path
from typing import Optional

from stillpoint.engine.core.errors import StillpointError

from ..core.times import iso_utc
from .estimate import STATIC_METHOD, CalibrationEstimate
from .validate import validate_estimate

HOME_ENV = "STILLPOINT_HOME"
STORE_VERSION = 1
USABLE_STATUSES = ("ok",)  # what prior_for() will hand to online mode


class CalibrationStoreError(StillpointError):
    """The store (or a device in it) could not be read or written."""


def default_root() -> Path:
    env = os.environ.get(HOME_ENV)
    if env:
        return Path(env).expanduser()
    return Path("~/.local/share/stillpoint").expanduser()


def _iso(ns: Optional[int]) -> Optional[str]:
    return None if ns is None else iso_utc(ns, "ms")


def _now_iso() -> str:
    return iso_utc(time.time_ns())


def device_file_name(device_key: str) -> str:
    """The store file of a device key: ``drivers.names.safe_name_part`` (a GENEActiv key holds
    the header's free-text serial), ``AX3-39434`` -> ``AX3-39434.json``."""
    from stillpoint.drivers.names import safe_name_part
    return safe_name_part(device_key, fallback="device") + ".json"


def _earlier_file_name(device_key: str) -> str:
    """The name earlier versions gave a key with characters outside ``A-Za-z0-9._-`` (such a
    store file is still found)."""
    safe = re.sub(r"[^A-Za-z0-9._-]", "_", device_key).strip(".") or "device"
    if safe != device_key:
        safe += "-" + hashlib.sha1(device_key.encode()).hexdigest()[:8]
    return safe + ".json"


@contextlib.contextmanager
def _locked(path: Path):
    lock = path.with_suffix(path.suffix + ".lock")
    try:
        import fcntl
    except ImportError:  # pragma: no cover - non-POSIX: atomic rename still protects the file
        yield
        return
    try:  # a planted link is not followed (O_NOFOLLOW)
        f = os.fdopen(os.open(lock, os.O_WRONLY | os.O_APPEND | os.O_CREAT | os.O_CLOEXEC
                              | getattr(os, "O_NOFOLLOW", 0), 0o644), "a")
    except OSError as e:
        why = "is a folder" if lock.is_dir() else (
            "is a symbolic link" if lock.is_symlink() else (e.strerror or str(e)))
        raise CalibrationStoreError(f"{lock}: cannot use the store's lock file: {why}") from None
    with f:
        fcntl.flock(f, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


class CalibrationStore:
    """Estimates per device; ``root``: $STILLPOINT_HOME or ~/.local/share/stillpoint."""

    def __init__(self, root=None):
        self.root = Path(root).expanduser() if root is not None else default_root()
        self.dir = self.root / "calibration"

    # ------------------------------------------------------------------ files
    def _path(self, device_key: str) -> Path:
        p = self.dir / device_file_name(device_key)
        if not p.exists():
            earlier = self.dir / _earlier_file_name(device_key)
            if earlier != p and "/" not in earlier.name and earlier.exists():
                return earlier
        return p

    def check(self) -> None:
        """Refuse, before any work, a store that cannot be used (root or folder is a file, or
        not writable)."""
        self._check_root()
        p = self.dir
        while not p.exists() and p != p.parent:
            p = p.parent
        if not os.access(p, os.W_OK | os.X_OK):
            raise CalibrationStoreError(f"{p}: the calibration store folder is not writable")

    def _check_root(self) -> None:
        for p in (self.root, self.dir):
            if p.exists() and not p.is_dir():
                raise CalibrationStoreError(f"{p}: the calibration store must be a folder, this is a file")

    def _read(self, path: Path) -> dict:
        self._check_root()
        try:
            with open(path, encoding="utf-8") as f:
                doc = json.load(f)
        except FileNotFoundError:
            return {}
        except (OSError, ValueError, RecursionError) as e:
            why = "is a folder" if path.is_dir() else e
            raise CalibrationStoreError(f"{path}: unreadable calibration store file: {why}") from None
        if not isinstance(doc, dict) or not isinstance(doc.get("records"), list):
            raise CalibrationStoreError(f"{path}: not a calibration store file (no 'records' list)")
        for i, r in enumerate(doc["records"]):
            if not (isinstance(r, dict) and isinstance(r.get("estimate"), dict)
                    and isinstance(r.get("status", ""), str)):
                raise CalibrationStoreError(f"{path}: record {i} is malformed (expected an object "
                                            "with an 'estimate' object and a 'status')")
        return doc

    def _estimate(self, device_key: str, i: int, record: dict) -> CalibrationEstimate:
        return validate_estimate(record["estimate"], f"{self._path(device_key)} record {i}")

    def _write(self, path: Path, doc: dict) -> None:
        from stillpoint.engine.core.outputs import OutputError, atomic_output
        self._mkdir()
        text = json.dumps(doc, indent=1, sort_keys=True) + "\n"
        try:
            with atomic_output(path, binary=False, what="calibration store file",
                               updates=True) as f:
                f.write(text)
        except OutputError as e:
            raise CalibrationStoreError(str(e)) from None

    # ------------------------------------------------------------------ write
    def add(self, estimate: CalibrationEstimate, *, device_key: Optional[str] = None,
            source: Optional[str] = None, stored_at: Optional[str] = None) -> dict:
        """Store an estimate for its device; returns the record. Same fit twice -> one record."""
        key = device_key or estimate.device_key
        if not key:
            raise CalibrationStoreError("cannot store an estimate without a device key "
                                        "(device type + serial)")
        est = estimate.to_dict()
        est["device_key"] = key
        record = {
            "stored_at": stored_at or _now_iso(),
            "source": str(source) if source is not None else None,
            "data_start": _iso(estimate.fit_start_ns),
            "data_end": _iso(estimate.fit_end_ns),
            "method": estimate.method,
            "status": estimate.status,
            "reason": estimate.reason,
            "quality": {"error_before_mg": estimate.error_before_mg,
                        "error_after_mg": estimate.error_after_mg,
                        "windows": estimate.windows, "hours_used": estimate.hours_used},
            "estimate": est,
        }
        validate_estimate(est, f"estimate for {key}")  # never store what could not be loaded
        ident = self._identity(record)
        path = self._path(key)
        self._mkdir()
        with _locked(path):
            doc = self._read(path) or {"version": STORE_VERSION, "device_key": key, "records": []}
            if doc.get("device_key") != key:
                raise CalibrationStoreError(
                    f"{path}: holds device {doc.get('device_key')!r}, not {key!r}")
            doc["records"] = [r for r in doc["records"] if self._identity(r) != ident]
            doc["records"].append(record)
            doc["records"].sort(key=lambda r: (r.get("data_end") or "", r.get("stored_at") or ""))
            self._write(path, doc)
        return record

    def _mkdir(self) -> None:
        self._check_root()
        try:
            self.dir.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise CalibrationStoreError(f"{self.dir}: cannot create the calibration store folder: "
                                        f"{e.strerror or e}") from None

    @staticmethod
    def _identity(record: dict):
        e = record.get("estimate", {})
        return (record.get("source"), record.get("data_start"), record.get("data_end"),
                record.get("method"), record.get("status"),
                json.dumps([e.get("offset"), e.get("scale"), e.get("tempoffset")]))

    # ------------------------------------------------------------------ read
    def devices(self) -> list[str]:
        """Device keys that have a file in the store."""
        self._check_root()
        if not self.dir.is_dir():
            return []
        keys = []
        for p in sorted(self.dir.glob("*.json")):
            if p.name.startswith(".tmp-"):
                continue
            doc = self._read(p)
            if doc.get("device_key"):
                keys.append(doc["device_key"])
        return sorted(keys)

    def records(self, device_key: str) -> list[dict]:
        """Every record of a device, oldest data first ([] for an unknown device)."""
        return list(self._read(self._path(device_key)).get("records", []))

    def estimates(self, device_key: str) -> list[CalibrationEstimate]:
        return [self._estimate(device_key, i, r) for i, r in enumerate(self.records(device_key))]

    def latest(self, device_key: str, statuses=USABLE_STATUSES) -> Optional[CalibrationEstimate]:
        """The estimate fitted on the most recent data whose status is in ``statuses``."""
        recs = self.records(device_key)
        for i in range(len(recs) - 1, -1, -1):
            if statuses is None or recs[i].get("status") in statuses:
                return self._estimate(device_key, i, recs[i])
        return None

    def latest_static(self, device_key: str):
        """The device's latest usable six-orientation static calibration (method ``static-6``)
        as a CalibrationEstimate (the static result in ``extra["static"]``), or None."""
        recs = self.records(device_key)
        for i in range(len(recs) - 1, -1, -1):
            if recs[i].get("method") == STATIC_METHOD and recs[i].get("status") in USABLE_STATUSES:
                return self._estimate(device_key, i, recs[i])
        return None

    def prior_for(self, device_key: str) -> Optional[CalibrationEstimate]:
        """The prior for online mode: the device's latest good estimate, or None (identity)."""
        est = self.latest(device_key)
        if est is not None:
            est.extra = dict(est.extra, prior_from_store=True)
        return est

    def summary(self) -> list[dict]:
        """One row per device for ``stillpoint calibration list``."""
        rows = []
        for key in self.devices():
            recs = self.records(key)
            last = recs[-1] if recs else {}
            good = [r for r in recs if r.get("status") in USABLE_STATUSES]
            rows.append({"device_key": key, "records": len(recs), "good": len(good),
                         "last_data_end": last.get("data_end"), "last_status": last.get("status"),
                         "last_method": last.get("method"),
                         "last_error_after_mg": (last.get("quality") or {}).get("error_after_mg")})
        return rows

    def export(self) -> dict:
        """The whole store as one JSON-able document."""
        return {"version": STORE_VERSION, "exported_at": _now_iso(),
                "devices": {k: self.records(k) for k in self.devices()}}
