"""Sleep inside the table writer: feeds the epoch rows through ``SleepStage``, hands them back
(with whatever extra columns they carry) with their ``spt`` and ``sib`` cells added, and at the
end writes ``<stem>.nights.csv``, the day table's night columns and the MCAP topics ``/sleep/night`` (one JSON message per night, at its
onset) and ``/sleep/sib`` (one per sustained inactivity bout, at its start)."""

from __future__ import annotations

import numpy as np

from stillpoint.engine.core.outputs import check_output_path

from ..mcap.jsonschemas import SLEEP_BOUT, SLEEP_NIGHT
from .diary import SleepLogError
from .nights import SleepStage
from .table import DAY_NIGHT_COLUMNS, day_night_values, night_record, write_nights

TOPIC_NIGHT = "/sleep/night"
TOPIC_SIB = "/sleep/sib"


def _cells(v: np.ndarray) -> list:
    return np.where(v.astype(bool), "1", "0").tolist()


class SleepTap:
    def __init__(self, ts, epoch_s: float):
        self.path = ts.nights_path
        self.zone = ts.zone
        self.epoch_ns = int(round(epoch_s * 1e9))
        self.options = ts.sleep
        self.stage = SleepStage(ts.zone, epoch_s, ts.sleep)
        self.bouts = []  # (start_ns, end_ns)
        self._run = None  # start_ns of a bout still open
        self.records = []
        self.columns = ["spt", "sib"]
        self._queue = []  # (rows, extra, counts) waiting for their sleep columns
        self._values = []  # decided (spt, sib) arrays, in row order
        self._have = 0  # decided values not yet handed out

    def feed(self, items, final: bool) -> list:
        """Take ``(rows, extra columns, step counts)`` items in order; return those whose sleep
        is decided, with the ``spt`` and ``sib`` cells added to their extra columns."""
        for rows, extra, counts in items:
            self._queue.append((rows, extra, counts))
            self._decided(self.stage.push(rows))
        if final:
            self._decided(self.stage.flush())
            if self._run is not None:
                self.bouts.append((self._run, self._end))
                self._run = None
        out = []
        while self._queue and len(self._queue[0][0]) <= self._have:
            rows, extra, counts = self._queue.pop(0)
            k = len(rows)
            spt, sib = (np.concatenate(x) if len(x) > 1 else x[0] for x in zip(*self._values))
            self._values = [(spt[k:], sib[k:])] if spt.shape[0] > k else []
            self._have -= k
            out.append((rows, list(extra) + [_cells(spt[:k]), _cells(sib[:k])], counts))
        return out

    def _decided(self, out) -> None:
        for _, spt, sib in self._bouts(out):
            self._values.append((spt, sib))
            self._have += spt.shape[0]

    def _bouts(self, out):
        """Pass the stage's output through, noting the SIB bouts (start_ns, end_ns) as they end."""
        for rows, spt, sib in out:
            t = rows.start_ns
            d = np.diff(np.concatenate([[0], sib, [0]]).astype(np.int8))
            starts, ends = np.flatnonzero(d == 1), np.flatnonzero(d == -1)
            if self._run is not None and (len(sib) == 0 or sib[0] == 0):
                self.bouts.append((self._run, self._end))
                self._run = None
            for a, b in zip(starts.tolist(), ends.tolist()):
                s0 = self._run if (a == 0 and self._run is not None) else int(t[a])
                self._run = None
                if b == len(sib):  # may go on in the next rows
                    self._run, self._end = s0, int(t[-1]) + self.epoch_ns
                else:
                    self.bouts.append((s0, int(t[b])))
            yield rows, spt, sib

    def close(self, days: list, sink, zone, cols: list) -> list:
        st = self.stage
        self.records = [night_record(n, st.first_ns, self.epoch_ns, zone) for n in st.nights] \
            if st.first_ns is not None else []
        write_nights(self.path, self.records)
        by_date = day_night_values(self.records)
        for d in days:
            d.update(by_date.get(str(d.get("date")), {}))
        if sink is not None:
            for r in self.records:
                at = r.get("onset_ns") or 0
                sink.write_json(TOPIC_NIGHT, int(at), r, schema=SLEEP_NIGHT)
            for a, b in self.bouts:
                sink.write_json(TOPIC_SIB, int(a), {"start_ns": a, "end_ns": b,
                                                     "duration_s": (b - a) / 1e9},
                                schema=SLEEP_BOUT)
        return cols + DAY_NIGHT_COLUMNS

    def summary(self) -> dict:
        return {"nights": str(self.path), "night_rows": len(self.records),
                "guiders": {g: sum(r["guider"] == g for r in self.records)
                            for g in sorted({r["guider"] for r in self.records})},
                "sib_bouts": len(self.bouts), "settings": logged_settings(self.options)}


def logged_settings(options) -> dict:
    """The sleep settings a run logs with its summary (``tables.sleep.settings``), so that a replay
    computes sleep the same way: ``SleepOptions.to_dict`` and the sleep log's participant."""
    d = options.to_dict()
    d["sleep_log_participant"] = options.sleep_log.participant if options.sleep_log else None
    return d


def logged_options(summary_tables):
    """The ``SleepOptions`` a run used, from its logged summary's ``tables`` (None when the run
    computed no sleep): the inverse of ``logged_settings``; a sleep log is read again from its
    path (a ``SleepLogError`` names it when it cannot be). A log from before the settings were
    logged: the defaults."""
    from .diary import read_sleep_log
    from .hdcza import HdczaOptions
    from .nights import SleepOptions
    sl = (summary_tables or {}).get("sleep") if isinstance(summary_tables, dict) else None
    if not isinstance(sl, dict):
        return None
    d = sl.get("settings") or {}
    h0 = HdczaOptions()
    t = d.get("HDCZA_threshold", h0.threshold)
    h = HdczaOptions(threshold=tuple(t) if isinstance(t, list) else t,
                     ignore_invalid=d.get("HASPT_ignore_invalid", h0.ignore_invalid),
                     min_block_min=float(d.get("spt_min_block_dur", h0.min_block_min)),
                     max_gap_min=float(d.get("spt_max_gap_dur", h0.max_gap_min)),
                     max_gap_ratio=float(d.get("spt_max_gap_ratio", h0.max_gap_ratio)))
    o0 = SleepOptions()
    o = SleepOptions(hdcza=h, angle_deg=float(d.get("anglethreshold", o0.angle_deg)),
                     time_min=float(d.get("timethreshold", o0.time_min)))
    if d.get("sleep_log"):
        o.sleep_log = read_sleep_log(d["sleep_log"], str(d.get("sleep_log_participant") or ""))
    return o


def check_sleep_outputs(ts) -> None:
    """Before any work: the nights table may be written, and a sleep log has local nights."""
    if ts.sleep is None:
        return
    if not ts.zone.known and ts.sleep.sleep_log is not None:
        raise SleepLogError(f"sleep log {ts.sleep.sleep_log.path}: its nights are local "
                            "times: give the participant's --timezone")
    check_output_path(ts.nights_path, what="nights table")


def open_sleep(ts, epoch_s: float):
    """The sleep part of the table writer (None when sleep is off). Without a zone the nights are
    on the device's clock, as GGIR computes them: every noon-to-noon window 24 h, no DST, times
    labelled as the tables' (device local time, zone unknown; no UTC columns)."""
    if ts.sleep is None:
        return None
    check_output_path(ts.nights_path, what="nights table")
    return SleepTap(ts, epoch_s)
