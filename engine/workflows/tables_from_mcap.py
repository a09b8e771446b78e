"""Epoch and day tables from a stillpoint MCAP: ``tables_from_mcap(mcap, epochs_path, ...)``.

The logged raw stream is corrected with the run's estimate (the ``calibration`` record: a batch
run's one estimate, an online run's final one) from the first sample, and the epoch metrics and
tables are computed directly (``engine.tables.estimate_pass``), so the tables equal those
``process`` wrote in either mode: an online log's tables are those of its best estimate, not of
the identity or prior in force until its first accepted refit. Sleep (the spt/sib columns, the
day table's night columns and the nights table at ``nights_path``, default beside the day table)
is computed as the run did, with the settings it logged (``sleep=None``), or with the
``SleepOptions`` given, or not at all (``sleep=False``). The zone is the one the run logged (its ``clock`` record, engine/timezones.py; a log from
before that record: its ``timezone`` setting, for GENEActiv the header's zone).
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

from stillpoint.engine.core.errors import StillpointError
from stillpoint.engine.core.outputs import check_output_path


class TablesError(StillpointError):
    pass


def days_path_for(epochs_path) -> Path:
    p = Path(epochs_path)
    name = p.name
    for suffix in (".epochs.csv.gz", ".csv.gz", ".csv"):
        if name.endswith(suffix):
            return p.with_name(name[: -len(suffix)] + ".days.csv")
    return p.with_name(name + ".days.csv")


def _beside(p: Path, suffix: str, new: str) -> Path:
    name = p.name[: -len(suffix)] if p.name.endswith(suffix) else p.name
    return p.with_name(name + new)


def tables_from_mcap(mcap, epochs_path, days_path=None, *, timezone: Optional[str] = None,
                     nonwear_version: str = "2023", valid_day_hours: float = 16.0,
                     enmo_bands_mg=(40.0, 100.0, 400.0), mvpa_bout_s: float = 60.0,
                     outcomes=None, sleep=None, nights_path=None) -> dict:
    from stillpoint.engine.mcap.replay import McapRawSource
    from ..settings import RunSettings
    from ..timezones import parse_zone
    from ..tables.writer import TablesSettings

    epochs_path = check_output_path(epochs_path, what="epoch table")
    days_path = check_output_path(days_path or days_path_for(epochs_path), what="day table")
    from ..timezones import CLOCK_RECORD, fixed_zone, zone_of_log
    src = McapRawSource(mcap)
    logged = dict(src.settings or {})
    info = src.info
    meta = dict(src.metadata)
    src.close()
    if CLOCK_RECORD in meta:  # the zone the run logged its times in
        logged_zone = zone_of_log(meta, info.timezone_offset_s)
    else:  # a log from before the clock record: the run's setting, the header's for GENEActiv
        logged_zone = parse_zone(logged.get("timezone"))
        if not logged_zone.known and info.device_type == "GENEActiv":
            logged_zone = fixed_zone(info.timezone_offset_s)
    zone = logged_zone
    if timezone is not None:
        if not logged_zone.known:
            raise TablesError(f"{mcap}: this run had no time zone (device local time); run "
                              f"`stillpoint process` on the recording with --timezone instead")
        zone = parse_zone(timezone)
    settings = RunSettings.from_dict(logged)
    ts = TablesSettings(epochs_path, days_path, zone=zone, nonwear_version=nonwear_version,
                        valid_day_hours=valid_day_hours, enmo_bands_mg=tuple(enmo_bands_mg),
                        mvpa_bout_s=mvpa_bout_s)
    if outcomes is not None:  # engine.outcomes.daily.OutcomeSettings: --cutpoints, --steps, ...
        ts.outcomes = outcomes
    if sleep is None:  # as the run did, with its logged settings
        import json
        from ..sleep.tap import logged_options
        try:
            logged_tables = json.loads((meta.get("summary") or {}).get("tables") or "null")
        except (TypeError, ValueError, RecursionError):
            logged_tables = None
        sleep = logged_options(logged_tables)
    if sleep:
        from ..sleep.tap import check_sleep_outputs
        ts.sleep = sleep
        ts.nights_path = Path(nights_path or _beside(days_path, ".days.csv", ".nights.csv"))
        check_sleep_outputs(ts)
    return _logged_tables(mcap, settings, ts)


def _logged_tables(mcap, settings, ts) -> dict:
    """Correct the logged raw stream with the run's estimate (its ``calibration`` record: a batch
    run's one estimate, an online run's final one) from the first sample and write the tables."""
    from stillpoint.engine.mcap.replay import McapRawSource
    from ..tables.estimate_pass import tables_with_estimate

    src = McapRawSource(mcap)
    try:
        est = src.logged_calibration()  # checked: a damaged record is one typed line
        return tables_with_estimate(src, est, settings, ts)
    finally:
        src.close()
