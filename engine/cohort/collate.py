"""Status and collation of a cohort folder: reads only the markers and what they vouch for.

``status(outdir)``: done / failed by class / pending (and which pending files are being
processed right now: their lock is held).

``collate(outdir)``: ``cohort_summary.csv``, one row per finished file (device, session,
start/end, duration, samples, QC counts, calibration status, error before/after and
coefficients, ENMO mean, wear time when the run summary gives one, output paths, timings), and
``cohort_failures.csv``, one row per failed file with its class and error. Only folders with a
``_DONE.json`` for their key are read; a finished file whose outputs are missing, of the wrong
size (or, with ``verify``, the wrong SHA-256) or unreadable goes to the failure table with the
class ``unreadable_output`` instead of stopping the collation. Cells pass through
``drivers.names.csv_cell``: a header's serial such as ``=HYPERLINK(...)`` is text in a
spreadsheet, never a formula.
"""

from __future__ import annotations

import csv
import json
import os
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Optional

from stillpoint.drivers.byteio import sha256_file
from stillpoint.drivers.names import csv_cell
from stillpoint.drivers.outputs import atomic_output

from .job import DONE, FAILED, RUNNING, SUMMARY_NAME, paths
from .plan import read_plan

SUMMARY_CSV = "cohort_summary.csv"
FAILURES_CSV = "cohort_failures.csv"

SUMMARY_FIELDS = (
    "file", "key", "device_type", "device_id", "session", "rate_hz", "start_utc", "end_utc",
    "duration_h", "samples", "segments", "qc_unit", "qc_total", "qc_valid", "qc_skipped",
    "qc_events", "windows", "nonmovement_windows", "calibration_status", "calibration_applied",
    "calibration_reason", "error_before_mg", "error_after_mg", "hours_used",
    "offset_x", "offset_y", "offset_z", "scale_x", "scale_y", "scale_z",
    "tempoffset_x", "tempoffset_y", "tempoffset_z", "temperature_ref", "enmo_mean_mg",
    "wear_time_h", "mcap", "summary", "folder", "wall_s", "peak_rss_mb", "finished_utc")
FAILURE_FIELDS = ("file", "key", "class", "error", "attempts", "time_utc", "folder")


class UnreadableOutput(Exception):
    pass


def _utc_ns(ns) -> str:
    if ns is None:
        return ""
    return datetime.fromtimestamp(int(ns) / 1e9, tz=timezone.utc).strftime("%Y-%m-%dT%H:%M:%S.%fZ")


def wear_hours(summary: dict) -> Optional[float]:
    """Wear time in hours when the run summary provides it (``wear_time_s``, or ``wear_s`` in a
    ``wear`` / ``nonwear`` section); None otherwise."""
    for v in (summary.get("wear_time_s"), (summary.get("wear") or {}).get("wear_s"),
              (summary.get("nonwear") or {}).get("wear_s"),
              (summary.get("nonwear") or {}).get("wear_time_s")):
        if isinstance(v, (int, float)):
            return v / 3600.0
    return None


def summary_row(entry, final: Path, done: dict, summary: dict) -> dict:
    from stillpoint.engine.run import APPLIED_STATUSES
    dev = summary.get("device") or {}
    qc = summary.get("qc") or {}
    cal = summary["calibration"]
    row = {
        "file": entry.path, "key": entry.key, "folder": str(final),
        "device_type": dev.get("type"), "device_id": dev.get("id"), "session": dev.get("session"),
        "rate_hz": dev.get("rate_hz"),
        "start_utc": _utc_ns(summary.get("start_ns")), "end_utc": _utc_ns(summary.get("end_ns")),
        "duration_h": summary["duration_s"] / 3600.0, "samples": summary["samples"],
        "segments": summary.get("segments"),
        "qc_unit": qc.get("unit"), "qc_total": qc.get("total"), "qc_valid": qc.get("valid"),
        "qc_skipped": qc.get("skipped"), "qc_events": qc.get("events"),
        "windows": summary.get("windows"), "nonmovement_windows": summary.get("nonmovement_windows"),
        "calibration_status": cal.get("status"),
        "calibration_applied": cal.get("status") in APPLIED_STATUSES,
        "calibration_reason": cal.get("reason"),
        "error_before_mg": cal.get("error_before_mg"), "error_after_mg": cal.get("error_after_mg"),
        "hours_used": cal.get("hours_used"), "temperature_ref": cal.get("temperature_ref"),
        "enmo_mean_mg": summary.get("enmo_mean_mg"), "wear_time_h": wear_hours(summary),
        "mcap": str(final / summary["outputs"]["mcap"]), "summary": str(final / SUMMARY_NAME),
        "wall_s": (done.get("timings") or {}).get("wall_s"), "peak_rss_mb": done.get("peak_rss_mb"),
        "finished_utc": (done.get("timings") or {}).get("finished_utc"),
    }
    if summary.get("mode") == "online":  # several estimates: applied = the final one was
        row["calibration_applied"] = any(x.get("applied") for x in summary.get("estimates") or [])
    for name in ("offset", "scale", "tempoffset"):
        for axis, v in zip("xyz", cal.get(name) or [None] * 3):
            row[f"{name}_{axis}"] = v
    return row


def _check_outputs(final: Path, done: dict, verify: bool) -> dict:
    for name, meta in (done.get("outputs") or {}).items():
        p = final / name
        try:
            size = p.stat().st_size
        except OSError as e:
            raise UnreadableOutput(f"{p}: {e.strerror or e}") from None
        if size != meta.get("bytes"):
            raise UnreadableOutput(f"{p}: {size} bytes, the marker says {meta.get('bytes')}")
        if verify and sha256_file(p) != meta.get("sha256"):
            raise UnreadableOutput(f"{p}: SHA-256 differs from the marker's")
    try:
        with open(final / SUMMARY_NAME, encoding="utf-8") as f:
            summary = json.load(f)
        if not isinstance(summary, dict):
            raise ValueError("not a JSON object")
        for k in ("calibration", "duration_s", "samples", "outputs"):
            if k not in summary:
                raise ValueError(f"no {k!r}")
        return summary
    except (OSError, ValueError) as e:
        raise UnreadableOutput(f"{final / SUMMARY_NAME}: unreadable ({e})") from None


@dataclass
class Collation:
    rows: list = field(default_factory=list)
    failures: list = field(default_factory=list)
    pending: int = 0
    summary_csv: Optional[Path] = None
    failures_csv: Optional[Path] = None


def _write_csv(path: Path, fields, rows) -> Path:
    with atomic_output(path, binary=False, what="cohort table") as f:
        w = csv.DictWriter(f, fieldnames=fields, lineterminator="\n", extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({k: ("" if r.get(k) is None else csv_cell(r.get(k))) for k in fields})
    return path


def collate(outdir, *, verify: bool = False, write: bool = True) -> Collation:
    """Read the markers of OUTDIR's plan and write the summary and failure tables."""
    outdir = Path(outdir).absolute()
    plan = read_plan(outdir)
    out = Collation()
    for e in plan.entries:
        final, _, _ = paths(outdir, e.folder)
        done = _marker(final / DONE)
        if done is not None and done.get("key") == e.key:
            try:
                out.rows.append(summary_row(e, final, done, _check_outputs(final, done, verify)))
            except (UnreadableOutput, KeyError, TypeError, ValueError) as err:
                msg = str(err) if isinstance(err, UnreadableOutput) else \
                    f"{final / SUMMARY_NAME}: missing or malformed field ({err})"
                out.failures.append({"file": e.path, "key": e.key, "class": "unreadable_output",
                                     "error": msg, "folder": str(final)})
            continue
        failed = _marker(final / FAILED)
        if failed is not None and failed.get("key") == e.key:
            out.failures.append({"file": e.path, "key": e.key, "class": failed.get("class"),
                                 "error": failed.get("error"), "attempts": failed.get("attempts"),
                                 "time_utc": failed.get("time_utc"), "folder": str(final)})
            continue
        out.pending += 1
    if write:
        out.summary_csv = _write_csv(outdir / SUMMARY_CSV, SUMMARY_FIELDS, out.rows)
        out.failures_csv = _write_csv(outdir / FAILURES_CSV, FAILURE_FIELDS, out.failures)
    return out


def _marker(path: Path):
    """A marker's content; a marker that exists but cannot be parsed counts as present and
    broken (``{}``) so the entry is reported, not silently redone."""
    try:
        with open(path, encoding="utf-8") as f:
            d = json.load(f)
        return d if isinstance(d, dict) else {}
    except FileNotFoundError:
        return None
    except (OSError, ValueError):
        return {"key": None, "broken": True}


# ---------------------------------------------------------------------------- status
@dataclass
class CohortStatus:
    total: int = 0
    done: int = 0
    failed: dict = field(default_factory=dict)  # class -> count
    pending: int = 0
    running: list = field(default_factory=list)  # (file, host, pid) being processed now
    code_version: str = ""
    settings: dict = field(default_factory=dict)

    @property
    def failed_total(self) -> int:
        return sum(self.failed.values())

    def as_dict(self) -> dict:
        return {"total": self.total, "done": self.done, "failed": dict(self.failed),
                "failed_total": self.failed_total, "pending": self.pending,
                "running": [list(r) for r in self.running], "code_version": self.code_version}


def _lock_held(lock: Path) -> bool:
    try:
        import fcntl
    except ImportError:  # pragma: no cover
        return False
    try:
        fd = os.open(lock, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0))
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        return False
    except OSError:
        return True
    finally:
        os.close(fd)


def status(outdir) -> CohortStatus:
    """Counts from the markers of OUTDIR's plan (reads no output)."""
    outdir = Path(outdir).absolute()
    plan = read_plan(outdir)
    st = CohortStatus(total=len(plan.entries), code_version=plan.code_version, settings=plan.settings)
    for e in plan.entries:
        final, tmp, lock = paths(outdir, e.folder)
        done = _marker(final / DONE)
        if done is not None and done.get("key") == e.key:
            st.done += 1
            continue
        failed = _marker(final / FAILED)
        if failed is not None and failed.get("key") == e.key:
            c = failed.get("class") or "unknown"
            st.failed[c] = st.failed.get(c, 0) + 1
            continue
        st.pending += 1
        if tmp.exists() and _lock_held(lock):
            r = _marker(tmp / RUNNING) or {}
            st.running.append((e.path, r.get("host"), r.get("pid")))
    return st
