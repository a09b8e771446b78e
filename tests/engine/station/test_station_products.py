"""The station's products from the best estimate, in the study's zone: two emulated devices with
sensor errors of tens of mg, one day each, a station with an empty calibration store. The live
log applies the identity until its first 12 h refit; the day table the station writes must be
that of the recording's final estimate from the first sample: every day's ENMO within 3 % of
`process` (batch) on the station's own verified raw copy, the estimate named
(``calibration_source``), the nights table written, all in the profile's ``timezone``."""

from __future__ import annotations

import csv
import io
import json

import pytest

from stillpoint.drivers.ax.discovery import EmulatedBackend
from stillpoint.engine.calibration.estimate import SOURCE_RECORDING
from stillpoint.engine.mcap.stream import read_metadata
from stillpoint.engine.sim.record import simulate_recording
from stillpoint.engine.station.flow import StationOptions, station_timezone
from stillpoint.engine.station.profile import ProfileError, load_profile
from stillpoint.engine.station.station import Station
from stillpoint.engine.timezones import host_zone
from stillpoint.tools.cli import main

from station_fixtures import emu, runtime  # noqa: F401
from synthetic_recording import SENSOR_ERRORS

ZONE = "Europe/London"


def _days(path) -> dict:
    with open(path) as f:
        return {r["date"]: r for r in csv.DictReader(f)}


def test_station_day_tables_are_those_of_the_final_estimate(emu, tmp_path):
    devices = (10001, 10002)
    for k, dev in enumerate(devices):
        rec = tmp_path / f"rec{dev}.cwa"
        simulate_recording(rec, days=1.0, hz=12.5, seed=31 + k, effects=SENSOR_ERRORS,
                           truth_path=False, labels_path=False, device_id=dev, session_id=1)
        emu(dev, recording=rec)
    prof = tmp_path / "study.toml"
    prof.write_text(f'[station]\ntimezone = "{ZONE}"\n')
    out = tmp_path / "out"
    out.mkdir()
    buf = io.StringIO()
    with Station(StationOptions(str(out), inline=True, profile=load_profile(prof)),
                 EmulatedBackend(), tty=False, out=buf, poll_s=0.05) as st:
        assert st.run(once=True) == 0, buf.getvalue()
    for dev in devices:
        stem = f"AX3-{dev}_1"
        station_days = _days(out / f"{stem}.days.csv")
        assert (out / f"{stem}.nights.csv").read_text().startswith("night,")
        batch = tmp_path / f"batch{dev}.mcap"
        assert main(["process", str(out / f"{stem}.cwa"), "-o", str(batch), "--timezone", ZONE,
                     "-q"]) == 0
        batch_days = _days(tmp_path / f"batch{dev}.days.csv")
        assert list(station_days) == list(batch_days) and len(batch_days) >= 2
        for date, row in station_days.items():
            es, eb = float(row["enmo_mean_mg"]), float(batch_days[date]["enmo_mean_mg"])
            assert abs(es - eb) <= 0.03 * eb, (dev, date, es, eb)
            assert row["calibration_source"] == SOURCE_RECORDING
            assert row["timezone"] == ZONE
        # the station's log is the online one: what it applied live is far from the final estimate
        with open(out / f"{stem}.mcap", "rb") as f:
            summary = read_metadata(f)["summary"]
        live = json.loads(summary["enmo_mean_mg"])
        best = float(station_days["all"]["enmo_mean_mg"])
        assert abs(live - best) > 0.2 * best, (dev, live, best)
        print(f"AX3 {dev}: day ENMO station/batch (mg) " + ", ".join(
            f"{d} {station_days[d]['enmo_mean_mg']}/{batch_days[d]['enmo_mean_mg']}"
            for d in station_days) + f"; live log mean {live:.2f} mg")


def test_profile_timezone_and_its_default(tmp_path):
    p = tmp_path / "p.toml"
    p.write_text('[station]\ntimezone = "Nowhere/Land"\n')
    with pytest.raises(ProfileError, match="timezone"):
        load_profile(p)
    p.write_text('[station]\ntimezone = "+05:30"\n')
    assert station_timezone(load_profile(p)) == "+05:30"
    assert station_timezone(None) == host_zone().name  # the zone the device clocks are set in
