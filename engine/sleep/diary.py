"""Sleep logs in GGIR's two CSV formats, read for one participant.

* basic: a header, then one row per participant: the ID, then per night an onset and a wake-up
  clock time (``ID,onset,wakeup,onset,wakeup,...``); night 1 is the evening of the recording's
  first local day (``SleepLog.resolve`` turns night numbers into dates).
* advanced: a header with per day ``Dn_date``, ``Dn_wakeup`` and ``Dn_onset`` columns (other
  columns such as naps, nonwear or bed times are ignored); a night runs from a day's onset to
  the next day's wake-up, and carries that day's date.

Clock times are ``H:MM[:SS]``; an empty cell or ``NA`` is a missing night (the guider then falls
back: see engine/sleep/nights.py). Dates: ``YYYY-MM-DD``, ``YYYY/MM/DD`` or ``DD/MM/YYYY``.
Anything else is refused with one line naming the file, the row (counting the header as row 1)
and the column. A night's onset and wake-up become local date-times with GGIR's rules for
times after midnight and daysleepers (R/g.part4.R:476-481, 625-628).
"""

from __future__ import annotations

import csv
import datetime as _dt
import re
from dataclasses import dataclass
from pathlib import Path

from stillpoint.engine.core.errors import StillpointError

_CLOCK = re.compile(r"^\s*(\d{1,2}):(\d{1,2})(?::(\d{1,2}))?\s*$")
_MISSING = {"", "na", "nan", "."}


class SleepLogError(StillpointError):
    pass


@dataclass
class SleepLog:
    path: Path
    participant: str
    fmt: str  # "basic" or "advanced"
    nights: dict  # night number (basic) or date (advanced) -> (onset hours, wake hours)

    def resolve(self, first_date: _dt.date) -> dict:
        """Night date -> (onset, wake) local datetimes."""
        out = {}
        for key, (on, wk) in self.nights.items():
            d = first_date + _dt.timedelta(days=key - 1) if isinstance(key, int) else key
            out[d] = night_times(d, on, wk)
        return out


def night_times(d: _dt.date, on: float, wk: float) -> tuple:
    """GGIR's reading of a night's clock times (hours) as local date-times."""
    daysleeper = (wk > 12 and on < 12) or (wk > 12 and on > wk)
    on_day = d + _dt.timedelta(days=1) if on < 12 else d
    next_day = wk <= 12 or (daysleeper and 12 < wk < 18) or (daysleeper and 12 < wk < 21 and on > wk)
    wk_day = d + _dt.timedelta(days=1) if next_day else d
    base = _dt.datetime.combine
    return (base(on_day, _dt.time()) + _dt.timedelta(hours=on),
            base(wk_day, _dt.time()) + _dt.timedelta(hours=wk))


def _clock(cell: str, where: str) -> float | None:
    if cell.strip().lower() in _MISSING:
        return None
    m = _CLOCK.match(cell)
    if not m or int(m.group(1)) > 24 or int(m.group(2)) > 59 or int(m.group(3) or 0) > 59:
        raise SleepLogError(f"{where}: {cell!r} is not a clock time (H:MM or H:MM:SS)")
    return int(m.group(1)) + int(m.group(2)) / 60 + int(m.group(3) or 0) / 3600


def _date(cell: str, where: str) -> _dt.date | None:
    c = cell.strip()
    if c.lower() in _MISSING:
        return None
    for fmt in ("%Y-%m-%d", "%Y/%m/%d", "%d/%m/%Y"):
        try:
            return _dt.datetime.strptime(c, fmt).date()
        except ValueError:
            pass
    raise SleepLogError(f"{where}: {cell!r} is not a date (YYYY-MM-DD, YYYY/MM/DD or DD/MM/YYYY)")


def read_sleep_log(path, participant: str) -> SleepLog:
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as e:
        raise SleepLogError(f"sleep log {path}: cannot be read ({e})") from None
    sample = text[:4096]
    delim = ";" if sample.count(";") > sample.count(",") else ("\t" if sample.count("\t") > sample.count(",") else ",")
    try:
        rows = list(csv.reader(text.splitlines(), delimiter=delim))
    except csv.Error as e:  # e.g. a cell over csv's field limit (131,072 characters)
        raise SleepLogError(f"sleep log {path}: not a readable table ({e})") from None
    if len(rows) < 2:
        raise SleepLogError(f"sleep log {path}: no header and participant rows")
    header = [h.strip() for h in rows[0]]
    advanced = any(h.lower().endswith("_date") for h in header)
    ids = []
    for r, row in enumerate(rows[1:], start=2):
        if not row or not any(c.strip() for c in row):
            continue
        pid = row[0].strip().strip('"')
        ids.append(pid)
        if pid != participant:
            continue
        where = f"sleep log {path} row {r}"
        if len(row) > len(header):
            raise SleepLogError(f"{where}: {len(row)} cells for {len(header)} columns")
        cells = dict(zip(header, row))
        nights = _advanced(cells, header, where) if advanced else _basic(row, header, where)
        return SleepLog(path, participant, "advanced" if advanced else "basic", nights)
    shown = ", ".join(ids[:5]) + (" ..." if len(ids) > 5 else "")
    raise SleepLogError(f"sleep log {path}: no row for participant {participant!r} "
                        f"(IDs in the log: {shown or 'none'}; set it with --sleep-log-id)")


def sleep_log_ids(path) -> list:
    """The participant IDs of a sleep log, every row checked (a cohort's one log for all its
    participants is refused before any work when one row is malformed)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as e:
        raise SleepLogError(f"sleep log {path}: cannot be read ({e})") from None
    sample = text[:4096]
    delim = ";" if sample.count(";") > sample.count(",") else ("\t" if sample.count("\t") > sample.count(",") else ",")
    ids = [r[0].strip().strip('"') for r in list(csv.reader(text.splitlines(), delimiter=delim))[1:]
           if r and any(c.strip() for c in r)]
    if not ids:
        raise SleepLogError(f"sleep log {path}: no header and participant rows")
    for pid in dict.fromkeys(ids):
        read_sleep_log(path, pid)
    return ids


def participant_sleep_log(path, participant: str):
    """The participant's nights from a cohort's sleep log, or None when the log has no row for
    them (their nights are then guided by HDCZA, as GGIR does for a missing log night)."""
    if participant not in sleep_log_ids(path):
        return None
    return read_sleep_log(path, participant)


def _basic(row: list, header: list, where: str) -> dict:
    cells = row[1:]
    if len(cells) % 2:
        cells = cells + [""]
    nights = {}
    for k in range(len(cells) // 2):
        col = header[1 + 2 * k] if 1 + 2 * k < len(header) else f"column {2 + 2 * k}"
        on = _clock(cells[2 * k], f"{where}, column {col!r} (night {k + 1} onset)")
        wk = _clock(cells[2 * k + 1], f"{where}, night {k + 1} wake-up")
        if on is not None and wk is not None:
            nights[k + 1] = (on, wk)
    return nights


_DAY = re.compile(r"^D(\d+)_(date|wakeup|wake|onset|sleeponset)$", re.I)


def _advanced(cells: dict, header: list, where: str) -> dict:
    days = {}
    for h in header:
        m = _DAY.match(h)
        if not m:
            continue
        kind = m.group(2).lower()
        kind = {"wake": "wakeup", "sleeponset": "onset"}.get(kind, kind)
        w = f"{where}, column {h!r}"
        cell = cells.get(h, "")
        days.setdefault(int(m.group(1)), {})[kind] = (_date(cell, w) if kind == "date" else _clock(cell, w))
    nights = {}
    for n in sorted(days):
        d, nxt = days[n], days.get(n + 1, {})
        if d.get("date") is None or d.get("onset") is None or nxt.get("wakeup") is None:
            continue
        nights[d["date"]] = (d["onset"], nxt["wakeup"])
    return nights
