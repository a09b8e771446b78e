"""Epoch and day tables from a stillpoint MCAP: ``tables_from_mcap(mcap, epochs_path, ...)``.

A batch run applied one estimate from the first sample (logged as the ``calibration`` record): the
logged raw stream is corrected with it and the epoch metrics and tables are computed directly,
the raw messages gathered into blocks of up to 10 min of one segment first (every operator's
output is independent of block cuts), so the tables equal those ``process`` wrote. An online run
(estimates switched in over time) is re-run with its logged settings through ``process_file``
(replay is bit-identical), its MCAP written to a temporary file beside the output and removed.
The zone is the one the run logged (its ``clock`` record, engine/timezones.py; a log from
before that record: its ``timezone`` setting, for GENEActiv the header's zone).
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Optional

from stillpoint.drivers.errors import StillpointError
from stillpoint.drivers.outputs import check_output_path


class TablesError(StillpointError):
    pass


def days_path_for(epochs_path) -> Path:
    p = Path(epochs_path)
    name = p.name
    for suffix in (".epochs.csv.gz", ".csv.gz", ".csv"):
        if name.endswith(suffix):
            return p.with_name(name[: -len(suffix)] + ".days.csv")
    return p.with_name(name + ".days.csv")


def tables_from_mcap(mcap, epochs_path, days_path=None, *, timezone: Optional[str] = None,
                     nonwear_version: str = "2023", valid_day_hours: float = 16.0,
                     enmo_bands_mg=(40.0, 100.0, 400.0), mvpa_bout_s: float = 60.0,
                     outcomes=None) -> dict:
    from stillpoint.drivers.mcap_replay import McapRawSource
    from ..run import RunSettings, process_file
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
    if settings.mode == "batch":
        return _batch_tables(mcap, settings, ts)
    fd, tmp = tempfile.mkstemp(prefix=".tables-", suffix=".mcap", dir=str(epochs_path.parent))
    os.close(fd)
    try:
        summary = process_file(mcap, tmp, settings, tables=ts)
    finally:
        for p in (tmp, tmp + ".part"):
            try:
                os.unlink(p)
            except OSError:
                pass
    return summary["tables"]


def _batch_tables(mcap, settings, ts) -> dict:
    """Correct the logged raw stream with the run's one estimate and write the tables."""
    from stillpoint.drivers.mcap_replay import McapRawSource
    from ..calibration.estimate import CalibrationEstimate
    from ..calibration.outcome import CalibrationOutcome
    from ..operators.correction import CorrectionOperator
    from ..operators.filters import band_used
    from ..operators.extras import ExtraMetrics
    from ..operators.metrics import EpochMetrics, MetricsOperator
    from ..core.blocks import coalesce_blocks
    from ..tables.writer import TablesTap

    src = McapRawSource(mcap)
    try:
        est = src.logged_calibration()  # checked: a damaged record is one typed line
        applied = est.applied and settings.calibrate
        initial = est if applied else CalibrationEstimate.identity(est.reason)
        initial.effective_from_ns = None
        rate = float(src.info.sample_rate_nominal or 0) or 100.0
        band = band_used(rate, settings.bfen_band_hz)
        correction = CorrectionOperator(initial, rate_hz=rate)
        metrics = MetricsOperator(rate, settings.epoch_s, settings.bfen_band_hz)
        extras = ExtraMetrics(settings, rate, src.info.accel_range_g)
        tap = TablesTap(ts, rate, settings.epoch_s, band, src, src.info, extras=extras.keys)
        try:
            def step(block, batches):
                ms = [metrics.push(b) for b in batches]
                m = EpochMetrics.concat(ms) if len(ms) != 1 else ms[0]
                tap.push(block, batches, m, extras.push(batches))

            for block in coalesce_blocks(src):
                step(block, correction.push(block))
            step(None, correction.flush())
            tap.flush(metrics.flush(), extras.flush())
            return tap.close(CalibrationOutcome(est, applied).table_status)
        except BaseException:
            tap.abort()
            raise
    finally:
        src.close()
