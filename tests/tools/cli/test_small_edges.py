"""Small things a new user reads: an ambiguous GMT+N zone is refused, a recording a few minutes
short of the first load does not read "72.0 h (< 72 h)", the no-still-window hint names the
file's own rate, the report says the calibration's errors once, the sleep topics have named
schemas."""

from __future__ import annotations

import pytest

from stillpoint.engine.calibration.estimate import CalibrationEstimate
from stillpoint.engine.calibration.outcome import CalibrationOutcome
from stillpoint.engine.timezones import ZoneError, parse_zone


@pytest.mark.parametrize("spec", ["GMT+1", "gmt-5", "UTC+2", "UTC-10"])
def test_gmt_plus_n_is_refused_as_ambiguous(spec):
    with pytest.raises(ZoneError, match="ambiguous.*Etc/GMT\\+1 is one hour behind UTC"):
        parse_zone(spec)


def test_offsets_and_the_geneactiv_header_form_still_parse():
    assert parse_zone("+01:00").fixed_s == 3600
    assert parse_zone("GMT +01:00").fixed_s == 3600  # GENEActiv header: as the vendor writes it
    assert parse_zone("UTC").fixed_s == 0
    assert parse_zone("Etc/GMT+1").name == "Etc/GMT+1"  # the IANA name: unambiguous


def test_a_recording_just_short_of_the_first_load_says_how_short():
    from stillpoint.engine.calibration.schedule import BatchSchedule
    h = 3600 * 10**9
    est = BatchSchedule(0, first_hours=72.0).finish(int(71.98 * h))
    assert "72.0 h (" not in est.reason, est.reason
    assert "71.980 h, 1.2 min short (< 72 h first load)" in est.reason, est.reason
    est = BatchSchedule(0, first_hours=72.0).finish(int(30 * h))
    assert "recording only 30.0 h (< 72 h first load)" in est.reason, est.reason


def test_no_still_window_hint_names_the_files_rate():
    est = CalibrationEstimate.identity("no nonmovement windows")
    est.status = "no_nonmovement"
    out = CalibrationOutcome(est).explain(0.030, 0.013, 100.0)
    assert "its noise at 100 Hz exceeds the threshold" in out.estimate.reason
    assert "3,200" not in out.estimate.reason


def test_report_says_the_calibration_errors_once():
    from stillpoint.engine import report
    reason = "calibrated: error 21.21 -> 0.79 mg on 7104 windows, autocal-c1"
    rec = {"summary": {"calibration": {"status": "ok", "reason": reason, "windows": 7104,
                                       "error_before_mg": 21.21, "error_after_mg": 0.79}}}
    text = report._qc_text(rec, [])
    assert text.count("21.21 -> 0.79 mg") == 1, text
    assert "calibration: ok" in text
    rec["summary"]["calibration"]["reason"] = "ok"
    assert report._qc_text(rec, []).count("21.21 -> 0.79 mg") == 1


def test_sleep_topics_have_named_schemas(tmp_path):
    from stillpoint.engine.mcap.stream import read_channels
    from stillpoint.engine.sim.record import simulate_recording
    from stillpoint.tools.cli import main
    cwa = tmp_path / "n.cwa"
    simulate_recording(cwa, days=1.5, hz=12.5, seed=9, truth_path=False, labels_path=False)
    assert main(["process", str(cwa), "-o", str(tmp_path / "n.mcap"), "--timezone", "UTC",
                 "-q"]) == 0
    with open(tmp_path / "n.mcap", "rb") as f:
        chans = {c.topic: c for c in read_channels(f)}
    assert chans["/sleep/night"].schema_name == "stillpoint.SleepNight"
    assert chans["/sleep/sib"].schema_name == "stillpoint.SleepInactivityBout"
    assert chans["/sleep/night"].schema_encoding == "jsonschema"
