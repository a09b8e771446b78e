"""Status and collation of a cohort folder: reads only the markers and what they vouch for.

``status(outdir)``: done / failed by class / pending (and which pending files are being
processed right now: their lock is held).

``collate(outdir)``: ``cohort_summary.csv``, one row per finished file (participant, device,
session, start/end, duration, samples, QC counts, calibration status, error before/after and
coefficients, and from its day table: wear hours, valid days, ENMO and MAD over clean epochs,
minutes per ENMO band, MVPA bouts, M10/L5; output paths, timings), ``cohort_days.csv`` (every
file's day rows stacked, with the participant id, the file, its key and the weekday),
``cohort_participants.csv`` (one row per participant: files, valid days on weekdays and at
weekends, wear hours, clean-epoch ENMO/MAD, means over valid days), ``cohort_nights.csv`` (for
cohorts run with ``--sleep``: every file's nights table stacked) and ``cohort_failures.csv``,
one row per failed file with its class and error. Times follow engine/timezones.py:
``start_utc``/``end_utc`` only when the file's zone is known, ``start_local``/``end_local``
always (the device clock when the zone is unknown), and ``timezone`` names which. Only folders
with a ``_DONE.json`` for their key are read; a finished file whose outputs are missing, of the
wrong size (or, with ``verify``, the wrong SHA-256) or unreadable (its day table included) goes
to the failure table with the class ``unreadable_output`` instead of stopping the collation. Cells pass through
``drivers.names.csv_cell``: a header's serial such as ``=HYPERLINK(...)`` is text in a
spreadsheet, never a formula.
"""

from __future__ import annotations

import csv
import json
import os
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Optional

from stillpoint.drivers.byteio import sha256_file
from stillpoint.drivers.names import cell_text, csv_cell, recording_stem
from stillpoint.engine.core.outputs import atomic_output

from .job import DONE, FAILED, MCAP_NAME, RUNNING, SUMMARY_NAME, paths
from .plan import read_plan

SUMMARY_CSV = "cohort_summary.csv"
FAILURES_CSV = "cohort_failures.csv"
DAYS_CSV = "cohort_days.csv"
PARTICIPANTS_CSV = "cohort_participants.csv"
NIGHTS_CSV = "cohort_nights.csv"
RHYTHM_CSV = "cohort_rhythm.csv"
WINDOWS_CSV = "cohort_windows.csv"

# the day table's summaries a study reads, taken from each file's ``all`` row (band minutes,
# MVPA and M10/L5 are means over its valid days; ENMO/MAD over its clean epochs)
_BAND_PREFIX = "min_enmo_"
_ACTIVITY = ("mvpa_bout_min", "m10_mg", "l5_mg")


def _is_band(column: str) -> bool:
    """A per-day minutes/steps column taken like the ENMO bands: the ENMO bands and the activity
    outcome columns (engine.outcomes.daily.DAY_PREFIXES)."""
    from stillpoint.engine.outcomes.daily import DAY_PREFIXES
    return column.startswith(_BAND_PREFIX) or column.startswith(DAY_PREFIXES)

SUMMARY_FIELDS = (
    "participant", "file", "key", "device_type", "device_id", "session", "rate_hz", "timezone",
    "start_utc", "end_utc", "start_local", "end_local",
    "duration_h", "samples", "segments", "qc_unit", "qc_total", "qc_valid", "qc_skipped",
    "qc_events", "qc_detail", "windows", "nonmovement_windows", "calibration_status", "calibration_applied",
    "calibration_reason", "error_before_mg", "error_after_mg", "hours_used",
    "offset_x", "offset_y", "offset_z", "scale_x", "scale_y", "scale_z",
    "tempoffset_x", "tempoffset_y", "tempoffset_z", "temperature_ref",
    "wear_time_h", "nonwear_h", "valid_days", "enmo_mean_mg", "mad_mean_mg",
    "enmo_all_epochs_mg", "BANDS", "mvpa_bout_min", "m10_mg", "l5_mg",
    "mcap", "summary", "epochs", "days", "folder", "wall_s", "peak_rss_mb", "finished_utc")
PARTICIPANT_FIELDS = ("participant", "files", "shared_dates", "valid_days", "valid_weekdays",
                      "valid_weekend_days", "wear_time_h", "enmo_mean_mg", "mad_mean_mg",
                      "BANDS", "mvpa_bout_min", "m10_mg", "l5_mg", "nights", "nights_valid",
                      "spt_hours", "sleep_hours", "waso_hours", "sleep_efficiency", "is", "iv",
                      "ra_avday", "ra_day_mean", "sri", "cosinor_acrophase_h", "ext_up_mesor_h",
                      "ext_down_mesor_h", "timezones")
# the participants' sleep means (over valid nights) and rhythm means (over files)
_NIGHT_MEANS = (("spt_hours", "spt_hours"), ("sleep_hours", "sleep_hours"),
                ("waso_hours", "waso_hours"), ("sleep_efficiency", "efficiency"))
_RHYTHM_MEANS = ("is", "iv", "ra_avday", "ra_day_mean", "sri", "cosinor_acrophase_h",
                 "ext_up_mesor_h", "ext_down_mesor_h")
FAILURE_FIELDS = ("file", "key", "class", "error", "attempts", "time_utc", "folder")


class UnreadableOutput(Exception):
    pass


def _file_table(summary: dict) -> dict:
    """The day table's ``all`` row of a run (``summary["tables"]["file"]``); {} without tables."""
    return ((summary.get("tables") or {}).get("file")) or {}


def wear_hours(summary: dict) -> Optional[float]:
    """Hours of clean wear (epochs without nonwear or any other flag) from the run's day
    table; None when the run wrote no tables."""
    v = _file_table(summary).get("wear_hours")
    return float(v) if isinstance(v, (int, float)) else None


def _fields(base, bands) -> list:
    out = []
    for f in base:
        out.extend(bands if f == "BANDS" else [f])
    return out


QC_DETAIL_SHOWN = 3  # QC events described in a summary row's qc_detail (summary.json has more)


def _qc_detail(qc: dict) -> str:
    """What the reader found wrong with a file it could still read (a truncated gzip stream, a
    bad checksum), for the ``qc_detail`` cell: the first few descriptions, then how many more
    events there were."""
    details = [str(x) for x in (qc.get("details") or [])][:QC_DETAIL_SHOWN]
    more = int(qc.get("events") or 0) - len(details)
    return "; ".join(details) + (f" (+{more} more event(s), in summary.json and on /qc)"
                                 if details and more > 0 else "")


def summary_row(entry, final: Path, done: dict, summary: dict) -> dict:
    from stillpoint.engine.calibration.estimate import status_applied
    from stillpoint.engine.timezones import ZoneError, local_text, utc_text, zone_from_label
    dev = summary.get("device") or {}
    qc = summary.get("qc") or {}
    cal = summary["calibration"]
    try:
        zone = zone_from_label(summary.get("timezone"))
    except ZoneError:
        zone = zone_from_label(None)
    day = _file_table(summary)
    outs = summary.get("outputs") or {}
    row = {
        "participant": summary.get("participant") or entry.participant or recording_stem(entry.path),
        "file": entry.path, "key": entry.key, "folder": str(final),
        "device_type": dev.get("type"), "device_id": dev.get("id"), "session": dev.get("session"),
        "rate_hz": dev.get("rate_hz"), "timezone": zone.label,
        "start_utc": utc_text(summary.get("start_ns"), zone, "us"),
        "end_utc": utc_text(summary.get("end_ns"), zone, "us"),
        "start_local": local_text(summary.get("start_ns"), zone, "us"),
        "end_local": local_text(summary.get("end_ns"), zone, "us"),
        "duration_h": summary["duration_s"] / 3600.0, "samples": summary["samples"],
        "segments": summary.get("segments"),
        "qc_unit": qc.get("unit"), "qc_total": qc.get("total"), "qc_valid": qc.get("valid"),
        "qc_skipped": qc.get("skipped"), "qc_events": qc.get("events"),
        "qc_detail": _qc_detail(qc),
        "windows": summary.get("windows"), "nonmovement_windows": summary.get("nonmovement_windows"),
        "calibration_status": cal.get("status"),
        "calibration_applied": status_applied(cal.get("status")),
        "calibration_reason": cal.get("reason"),
        "error_before_mg": cal.get("error_before_mg"), "error_after_mg": cal.get("error_after_mg"),
        "hours_used": cal.get("hours_used"), "temperature_ref": cal.get("temperature_ref"),
        "wear_time_h": wear_hours(summary), "nonwear_h": day.get("nonwear_hours"),
        "valid_days": day.get("valid_day"), "enmo_mean_mg": day.get("enmo_mean_mg"),
        "mad_mean_mg": day.get("mad_mean_mg"), "enmo_all_epochs_mg": summary.get("enmo_mean_mg"),
        **{k: day.get(k) for k in _ACTIVITY},
        **{k: v for k, v in day.items() if _is_band(k)},
        "mcap": str(final / summary["outputs"]["mcap"]), "summary": str(final / SUMMARY_NAME),
        "epochs": str(final / outs["epochs"]) if outs.get("epochs") else None,
        "days": str(final / outs["days"]) if outs.get("days") else None,
        "wall_s": (done.get("timings") or {}).get("wall_s"), "peak_rss_mb": done.get("peak_rss_mb"),
        "finished_utc": (done.get("timings") or {}).get("finished_utc"),
        "_span_ns": (summary.get("start_ns"), summary.get("end_ns")),  # not a column
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
    days_csv: Optional[Path] = None
    participants_csv: Optional[Path] = None
    participants: list = field(default_factory=list)
    nights_csv: Optional[Path] = None
    nights: list = field(default_factory=list)
    warnings: list = field(default_factory=list)  # one line each, for the user


_WEEKDAYS = ("Mon", "Tue", "Wed", "Thu", "Fri", "Sat", "Sun")


def _day_rows(row: dict) -> tuple[list, list]:
    """(columns, rows) of one file's day table, each row led by the participant, file and key
    and given its weekday; the ``all`` row is left out (it is the file's summary row)."""
    path = row.get("days")
    if not path:
        return [], []
    try:
        with open(path, encoding="utf-8", newline="") as f:
            rd = csv.DictReader(f)
            cols = list(rd.fieldnames or [])
            rows = [r for r in rd if r.get("date") != "all"]
    except (OSError, UnicodeError, csv.Error) as e:
        raise UnreadableOutput(f"{path}: unreadable day table ({e})") from None
    for r in rows:
        try:
            wd = datetime.strptime(r["date"], "%Y-%m-%d").weekday()
        except (KeyError, ValueError):
            raise UnreadableOutput(f"{path}: a day row without a date") from None
        r.update(participant=row["participant"], file=row["file"], key=row["key"],
                 weekday=_WEEKDAYS[wd])
    return cols, rows


def _num(v) -> Optional[float]:
    try:
        x = float(v)
    except (TypeError, ValueError):
        return None
    return x if x == x else None


def _one_row_per_date(days: list) -> tuple[list, list]:
    """(rows, dates in several files) of one participant's day rows: a date that more than one
    file covers (overlapping files, or one file ending the day another starts) is taken once,
    from the file with the most clean wear that day (a valid day before an invalid one)."""
    best: dict = {}
    files: dict = {}
    for d in days:
        k = d.get("date")
        files.setdefault(k, set()).add(d.get("file"))
        rank = (d.get("valid_day") == "1", _num(d.get("wear_hours")) or 0.0)
        if k not in best or rank > best[k][0]:
            best[k] = (rank, d)
    return [best[k][1] for k in sorted(best)], sorted(k for k, f in files.items() if len(f) > 1)


def _overlapping(files: list) -> list:
    """Pairs of a participant's files whose recordings overlap in time (the same device and
    session downloaded twice, or two devices worn together)."""
    spans = sorted((r["_span_ns"], r["file"]) for r in files
                   if all(isinstance(x, int) for x in r.get("_span_ns") or (None,)))
    return [(a[1], b[1]) for i, a in enumerate(spans) for b in spans[i + 1:]
            if b[0][0] < a[0][1]]


def participant_rows(rows: list, days: list, bands: list, warnings: Optional[list] = None,
                     nights: Optional[list] = None, rhythm: Optional[list] = None) -> list:
    """One row per participant from the file rows and the stacked day rows: valid days (also
    split into weekdays and weekend days, by the local date), wear hours, ENMO/MAD over every
    clean epoch of their files (wear-weighted means of the files'), and the band minutes, MVPA
    and M10/L5 averaged over their valid days. Each date counts once (``_one_row_per_date``);
    files that overlap in time add a line to ``warnings``. With the stacked nights: the nights,
    the valid ones (``night_valid``: GGIR's cleaned nights not cut by a recording's edge) and the
    sleep means over the valid nights; with the stacked rhythm rows: their means over the files."""
    out = []
    for who in sorted({r["participant"] for r in rows}):
        files = [r for r in rows if r["participant"] == who]
        own, shared = _one_row_per_date([d for d in days if d["participant"] == who])
        valid = [d for d in own if d.get("valid_day") == "1"]
        wear = (sum(_num(d.get("wear_hours")) or 0.0 for d in own) if own else
                sum(_num(r.get("wear_time_h")) or 0.0 for r in files))
        pairs = _overlapping(files)
        if warnings is not None and pairs:
            warnings.append(
                f"participant {who}: " + "; ".join(f"{a} and {b} overlap in time" for a, b in pairs)
                + f": each of the {len(shared)} shared date(s) is counted once, from the file "
                  "with the most wear that day")
        p = {"participant": who, "files": len(files), "shared_dates": len(shared),
             "valid_days": len(valid),
             "valid_weekdays": sum(d["weekday"] not in ("Sat", "Sun") for d in valid),
             "valid_weekend_days": sum(d["weekday"] in ("Sat", "Sun") for d in valid),
             "wear_time_h": wear,
             "timezones": ";".join(sorted({str(r.get("timezone")) for r in files}))}
        for k in ("enmo_mean_mg", "mad_mean_mg"):
            pairs = [(_num(r.get(k)), _num(r.get("wear_time_h")) or 0.0) for r in files]
            pairs = [(v, w) for v, w in pairs if v is not None and w > 0]
            w = sum(w for _, w in pairs)
            p[k] = sum(v * w for v, w in pairs) / w if w else None
        for k in list(bands) + list(_ACTIVITY):
            v = [_num(d.get(k)) for d in valid]
            v = [x for x in v if x is not None]
            p[k] = sum(v) / len(v) if v else None
        own_nights = [n for n in (nights or []) if n.get("participant") == who]
        good = [n for n in own_nights if n.get("night_valid", "1") == "1" and n.get("spt_hours")]
        p["nights"], p["nights_valid"] = len(own_nights), len(good)
        for k, col in _NIGHT_MEANS:
            v = [x for x in (_num(n.get(col)) for n in good) if x is not None]
            p[k] = sum(v) / len(v) if v else None
        own_rhythm = [r for r in (rhythm or []) if r.get("participant") == who]
        for k in _RHYTHM_MEANS:
            v = [x for x in (_num(r.get(k)) for r in own_rhythm) if x is not None]
            p[k] = sum(v) / len(v) if v else None
        out.append(p)
    return out


# Decimals of the cohort tables' numbers: the day table's 4 (``cell_text``: 0.0001 h, mg, min),
# more for the calibration parameters, whose digits matter below that: offset in g and scale to
# 1e-7 (0.1 ug, 0.00001 %), temperature offset in g/degC to 1e-8. The run's summary.json keeps
# every digit.
_CAL_DECIMALS = (("offset_", 7), ("scale_", 7), ("tempoffset_", 8))


def _cell(field: str, v):
    """A cohort table cell: floats rounded (``_CAL_DECIMALS``, else 4 decimals, trailing zeros
    dropped), non-finite and None empty, text made safe for spreadsheets."""
    if isinstance(v, float):
        d = next((d for prefix, d in _CAL_DECIMALS if field.startswith(prefix)), 4)
        return cell_text(v, d)
    return "" if v is None else csv_cell(v)


def _write_csv(path: Path, fields, rows) -> Path:
    with atomic_output(path, binary=False, what="cohort table") as f:
        w = csv.DictWriter(f, fieldnames=fields, lineterminator="\n", extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({k: _cell(k, r.get(k)) for k in fields})
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
    days, day_cols, kept = [], [], []
    for r in out.rows:  # a file whose day table cannot be read is a failure, not a hole
        try:
            cols, rows = _day_rows(r)
        except UnreadableOutput as err:
            out.failures.append({"file": r["file"], "key": r["key"], "class": "unreadable_output",
                                 "error": str(err), "folder": r["folder"]})
            continue
        kept.append(r)
        days.extend(rows)
        day_cols.extend(c for c in cols if c not in day_cols)
    out.rows = kept
    night_cols, out.nights = _stacked(out, ".nights.csv", "nights table")
    bands = [c for c in day_cols if _is_band(c)]
    if not bands:
        bands = sorted({k for r in kept for k in r if _is_band(k)})
    rhythm_cols, rhythm_rows = _stacked(out, ".rhythm.csv", "rhythm table")
    windows_cols, windows_rows = _stacked(out, ".windows.csv", "windows table")
    out.participants = participant_rows(kept, days, bands, out.warnings, out.nights, rhythm_rows)
    if write:
        out.summary_csv = _write_csv(outdir / SUMMARY_CSV, _fields(SUMMARY_FIELDS, bands), out.rows)
        out.days_csv = _write_csv(outdir / DAYS_CSV,
                                  ["participant", "file", "key", "date", "weekday"] +
                                  [c for c in day_cols if c != "date"], days)
        out.participants_csv = _write_csv(outdir / PARTICIPANTS_CSV,
                                          _fields(PARTICIPANT_FIELDS, bands), out.participants)
        out.failures_csv = _write_csv(outdir / FAILURES_CSV, FAILURE_FIELDS, out.failures)
        if night_cols:  # cohorts run with sleep
            out.nights_csv = _write_csv(outdir / NIGHTS_CSV,
                                        ["participant", "file", "key"] + night_cols, out.nights)
        if rhythm_cols:
            _write_csv(outdir / RHYTHM_CSV, ["participant", "file", "key"] + rhythm_cols, rhythm_rows)
        if windows_cols:
            _write_csv(outdir / WINDOWS_CSV, ["participant", "file", "key"] + windows_cols,
                       windows_rows)
    return out


def _stacked(out: Collation, suffix: str, what: str) -> tuple:
    """Every finished file's ``<stem><suffix>`` table stacked, each row led by the participant,
    file and key: (columns, rows); a table that cannot be read is a failure of its file."""
    cols: list = []
    rows: list = []
    for r in out.rows:
        path = Path(r["folder"]) / (MCAP_NAME[:-len(".mcap")] + suffix)
        if not path.exists():
            continue
        try:
            with open(path, encoding="utf-8", newline="") as f:
                rd = csv.DictReader(f)
                cols.extend(c for c in (rd.fieldnames or []) if c not in cols)
                for x in rd:
                    x.update(participant=r["participant"], file=r["file"], key=r["key"])
                    rows.append(x)
        except (OSError, UnicodeError, csv.Error) as e:
            out.failures.append({"file": r["file"], "key": r["key"], "class": "unreadable_output",
                                 "error": f"{path}: unreadable {what} ({e})", "folder": r["folder"]})
    return cols, rows


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
