"""The nights table (``<stem>.nights.csv``), the day table's night columns and the MCAP records of
the nights and the SIBs.

Nights table columns: ``night`` (the evening's local date), ``guider`` (sleeplog, HDCZA,
HDCZA+invalid, L512 or none), ``onset_local`` / ``wake_local`` (ISO 8601 with offset),
``onset_utc`` / ``wake_utc``, ``spt_hours`` (wake - onset), ``sleep_hours`` (SIB time inside),
``waso_hours`` (spt - sleep), ``awakenings`` (wake runs between SIBs inside), ``efficiency``
(sleep / spt), ``nonwear_spt_hours`` (nonwear or gap epochs inside), ``window_hours`` (the
noon-to-noon window in the data: 23 or 25 h across a DST change, less at the recording's ends),
``dst`` (1 when the night's local noon-to-noon day is 23 or 25 h),
``daysleeper`` (the HDCZA window came from the re-run 6 h later), ``guider_onset_local`` /
``guider_wake_local`` and ``hdcza_threshold_deg``; then the night's filters:
``fraction_night_invalid`` (GGIR: nonwear, gap and missing epochs over 24 h),
``cleaningcode`` (GGIR part 4: 0 sleep log, 1 no sleep log, 2 too little valid data, 5 no SIB
overlapping the guider), ``window_cut`` (``start``, ``end`` or ``both``: the recording starts or
ends inside the night's window) and ``night_valid`` (1: cleaningcode 0 or 1 and the sleep period
not cut by the recording's start or end; participant summaries use only these nights).
"""

from __future__ import annotations

import csv
from pathlib import Path

from stillpoint.drivers.names import cell_text, csv_cell
from stillpoint.engine.core.outputs import atomic_output

from ..timezones import Zone, local_text, utc_text

NIGHT_COLUMNS = ["night", "guider", "onset_local", "wake_local", "onset_utc", "wake_utc", "spt_hours",
                 "sleep_hours", "waso_hours", "awakenings", "efficiency", "nonwear_spt_hours",
                 "window_hours", "dst", "daysleeper", "guider_onset_local", "guider_wake_local",
                 "hdcza_threshold_deg", "fraction_night_invalid", "cleaningcode", "window_cut",
                 "night_valid"]
# the day table's night summary: the night that starts on the day's evening
DAY_NIGHT_COLUMNS = ["night_guider", "night_onset", "night_wake", "night_spt_hours",
                     "night_sleep_hours", "night_waso_hours", "night_awakenings", "night_efficiency",
                     "night_valid"]


def nights_path(mcap_path) -> Path:
    p = Path(mcap_path)
    stem = p.name[:-5] if p.name.endswith(".mcap") else p.name
    return p.with_name(stem + ".nights.csv")


def _h(epochs: int, epoch_s: float) -> float:
    return round(epochs * epoch_s / 3600.0, 4)


def night_record(night, first_ns: int, epoch_ns: int, zone: Zone) -> dict:
    epoch_s = epoch_ns / 1e9
    t = lambda i: first_ns + int(i) * epoch_ns  # noqa: E731
    d = {"night": night.date.isoformat(), "guider": night.guider, "window_hours": night.window_hours,
         "dst": int(night.dst), "daysleeper": int(night.daysleeper),
         "fraction_night_invalid": round(night.fraction_invalid, 6),
         "cleaningcode": night.cleaningcode,
         "window_cut": {(True, True): "both", (True, False): "start",
                        (False, True): "end"}.get((night.cut_start, night.cut_end), ""),
         "night_valid": int(night.valid)}
    est = night.estimate
    d["hdcza_threshold_deg"] = None if est is None else round(float(est.threshold), 6)
    if night.guider_span is not None:
        d["guider_onset_local"] = local_text(t(night.guider_span[0]), zone)
        d["guider_wake_local"] = local_text(t(night.guider_span[1]), zone)
    if night.spt is not None:
        a, b = night.spt
        spt = b - a
        d.update(onset_local=local_text(t(a), zone), wake_local=local_text(t(b), zone),
                 onset_utc=utc_text(t(a), zone), wake_utc=utc_text(t(b), zone),
                 onset_ns=t(a), wake_ns=t(b),
                 spt_hours=_h(spt, epoch_s), sleep_hours=_h(night.sleep_epochs, epoch_s),
                 waso_hours=_h(spt - night.sleep_epochs, epoch_s), awakenings=night.awakenings,
                 efficiency=round(night.sleep_epochs / spt, 4) if spt else None,
                 nonwear_spt_hours=_h(night.nonwear_epochs, epoch_s))
    return d


def write_nights(path, records: list) -> None:
    with atomic_output(path, binary=False, what="nights table") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(NIGHT_COLUMNS)
        for r in records:
            w.writerow([csv_cell(cell_text(r.get(c))) for c in NIGHT_COLUMNS])


def day_night_values(records: list) -> dict:
    """Local date -> the day table's night columns."""
    out = {}
    for r in records:
        out[r["night"]] = {"night_guider": r["guider"], "night_onset": r.get("onset_local"),
                           "night_wake": r.get("wake_local"), "night_spt_hours": r.get("spt_hours"),
                           "night_sleep_hours": r.get("sleep_hours"),
                           "night_waso_hours": r.get("waso_hours"),
                           "night_awakenings": r.get("awakenings"),
                           "night_efficiency": r.get("efficiency"),
                           "night_valid": r.get("night_valid")}
    return out
