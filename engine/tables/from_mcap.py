"""Epoch and day tables from a stillpoint MCAP: ``tables_from_mcap(mcap, epochs_path, ...)``.

The logged raw stream is re-run with the logged settings (replay is bit-identical, so the tables
equal those ``process`` wrote); the MCAP that re-run produces goes to a temporary file beside the
output and is removed. The zone is the one the run used (its ``timezone`` setting; GENEActiv
times were already converted with the header's zone).
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
                     enmo_bands_mg=(40.0, 100.0, 400.0), mvpa_bout_s: float = 60.0) -> dict:
    from stillpoint.drivers.mcap_replay import McapRawSource
    from ..run import RunSettings, process_file
    from ..timezones import parse_zone
    from .writer import TablesSettings

    epochs_path = check_output_path(epochs_path, what="epoch table")
    days_path = check_output_path(days_path or days_path_for(epochs_path), what="day table")
    src = McapRawSource(mcap)
    logged = dict(src.settings or {})
    info = src.info
    src.close()
    zone_spec = logged.get("timezone")
    if timezone is not None:
        if zone_spec is None and info.device_type != "GENEActiv":
            raise TablesError(f"{mcap}: this run had no time zone (device local time); run "
                              f"`stillpoint process` on the recording with --timezone instead")
        zone_spec = timezone
    zone = parse_zone(zone_spec)
    if not zone.known and info.device_type == "GENEActiv":
        from ..timezones import fixed_zone
        zone = fixed_zone(info.timezone_offset_s)
    settings = RunSettings.from_dict(logged)
    ts = TablesSettings(epochs_path, days_path, zone=zone, nonwear_version=nonwear_version,
                        valid_day_hours=valid_day_hours, enmo_bands_mg=tuple(enmo_bands_mg),
                        mvpa_bout_s=mvpa_bout_s)
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
