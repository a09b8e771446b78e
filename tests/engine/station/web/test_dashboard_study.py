"""Study records: the profile's file-name template, the subject id given at configure (written to
the device's annotations, the ledger and the download's file name), the setting code of a whole
device setting, and configuring from the dashboard with both."""

from __future__ import annotations

import os
import threading
import urllib.parse

import pytest

from stillpoint.engine.station.flow import StationOptions
from stillpoint.engine.station.ledger import Ledger
from stillpoint.engine.station.profile import ProfileError, StudyProfile, load_profile
from stillpoint.engine.station.station import Station
from stillpoint.engine.station.setting_code import profile_from_code, setting_code
from stillpoint.engine.station.study import StudyRecordError, check_template, download_stem, file_stem
from stillpoint.engine.station.web import Dashboard
from stillpoint.engine.station.web.records import Records

from station_fixtures import emu, request, runtime, wait  # noqa: F401

TEMPLATE = "{study}_{subject}_{device}_{session}"


def test_file_stem_fills_the_template_with_safe_parts():
    got = file_stem(TEMPLATE, device_type="AX3", device_id=10001, session=4,
                    metadata={"study": "ABC", "subject": "P-017"})
    assert got == "ABC_P-017_AX3-10001_4"
    unsafe = file_stem(TEMPLATE, device_type="AX6", device_id=7, session=1,
                       metadata={"study": "A/B", "subject": "../x y"})
    assert "/" not in unsafe and " " not in unsafe and ".." not in unsafe
    assert unsafe.endswith("_AX6-7_1")
    assert file_stem(TEMPLATE, device_type="AX3", device_id=1, session=2, metadata={}) == \
        "no-study_no-subject_AX3-1_2"
    assert file_stem(None, device_type="AX3", device_id=1, session=2) == "AX3-1_2"
    for bad in ("{study}_{subject}", "{device}", "../{device}_{session}", "{device}_{session}/x",
                "{Device}_{session}", "{device}_{session}_{"):
        with pytest.raises(StudyRecordError):
            check_template(bad)


def test_profile_file_name_checked_at_load(tmp_path):
    p = tmp_path / "p.toml"
    p.write_text(f'[device]\nrate_hz = 100\n[metadata]\nstudy = "ABC"\n'
                 f'[station]\nfile_name = "{TEMPLATE}"\n')
    assert load_profile(p).file_name == TEMPLATE
    p.write_text('[station]\nfile_name = "{study}_{subject}"\n')
    with pytest.raises(ProfileError, match=r"p\.toml.*must contain \{device\}"):
        load_profile(p)


def test_download_stem_takes_the_subject_from_the_ledger(tmp_path):
    led = Ledger(tmp_path)
    prof = StudyProfile(metadata={"study": "ABC"}, file_name=TEMPLATE)
    assert download_stem(prof, led, "AX3", 10001, 2) == "ABC_no-subject_AX3-10001_2"
    led.configured(10001, 2, {"metadata": {"study": "ABC", "subject": "P-017"}}, "ok",
                   device_type="AX3")
    led.configured(10001, 3, {"metadata": {"subject": "P-099"}}, "error", device_type="AX3")
    assert download_stem(prof, led, "AX3", 10001, 2) == "ABC_P-017_AX3-10001_2"
    assert download_stem(prof, led, "AX3", 10001, 3) == "ABC_no-subject_AX3-10001_3"  # failed config
    assert download_stem(prof, led, "AX6", 10001, 2) == "ABC_no-subject_AX6-10001_2"  # another device
    assert download_stem(StudyProfile(), led, "AX3", 10001, 2) == "AX3-10001_2"  # no template
    led.close()


def test_setting_code_round_trip_and_refusals():
    prof = StudyProfile(rate_hz=50, range_g=4, start="+2h", stop="+7d", min_battery_pct=80,
                        metadata={"study": "ABC"}, led_flash=True)
    code = setting_code(prof)
    assert code == "SP1_50_4_0_+2h_+7d_inc_80_F"
    back = profile_from_code(code, StudyProfile(metadata={"study": "ABC"}))
    for k in ("rate_hz", "range_g", "gyro_dps", "start", "stop", "session", "min_battery_pct",
              "led_flash", "metadata"):
        assert getattr(back, k) == getattr(prof, k), k
    assert profile_from_code("SP1_100_8_0_0_-1_keep_0").session == "keep"
    for bad, why in (("SP2_100_8_0_0_-1_inc_80", "expected SP1"),
                     ("SP1_100_8_0_0_-1_inc", "expected SP1"),
                     ("SP1_100_8_0_0_-1_inc_80_X", "expected SP1"),
                     ("SP1_abc_8_0_0_-1_inc_80", "numbers"),
                     ("SP1_99_8_0_0_-1_inc_80", "rate"),
                     ("SP1_100_3_0_0_-1_inc_80", "range"),
                     ("SP1_100_8_0_0_-1_inc_101", "min_battery"),
                     ("SP1_100_8_0_+2q_-1_inc_80", "start")):
        with pytest.raises(StudyRecordError, match=why):
            profile_from_code(bad)


def _post(dash, action, key, **form):
    return request(dash, "POST", f"/action/{action}/{key}", dict(form, token=dash.token,
                                                                 confirm="yes"))


def test_configure_from_the_dashboard_with_subject_and_code(emu, tmp_path):
    d = emu(10001)
    out = tmp_path / "out"
    out.mkdir()
    prof = StudyProfile(rate_hz=50, range_g=4, start="+2h", stop="+7d",
                        metadata={"study": "ABC"}, file_name=TEMPLATE)
    # the download before any configuration: the template, no subject yet
    st = Station(StationOptions(str(out), profile=prof, clear_after_verify=True, inline=True),
                 tty=False, out=open(os.devnull, "w"))
    dash = Dashboard(out, st)
    dash.start()
    stop = threading.Event()
    t = threading.Thread(target=st.run, kwargs={"stop": stop}, daemon=True)
    t.start()
    try:
        def flow():
            return next(iter(st.flows.values()), None)
        wait(lambda: flow() and flow().finished.is_set(), what="the first flow")
        assert flow().state == "cleared"
        assert (out / "ABC_no-subject_AX3-10001_1.cwa").is_file()
        assert (out / "ABC_no-subject_AX3-10001_1.mcap").is_file()
        s, _, body = request(dash, "GET", f"/?token={dash.token}")
        assert "SP1_50_4_0_+2h_+7d_inc_0" in body and "/action/configure/AX3-10001" in body

        # refused: an unsafe subject id, a code the device type cannot record
        before = dict(d.settings)
        s, _, body = _post(dash, "configure", "AX3-10001", subject="P 017/..")
        assert s == 400 and "subject id" in body
        s, _, body = _post(dash, "configure", "AX3-10001", code="SP1_100_8_250_0_-1_inc_0")
        assert s == 400 and "gyro" in body.lower()
        assert d.settings == before  # refused before the device is touched

        s, h, _ = _post(dash, "configure", "AX3-10001", subject="P-017",
                        code="SP1_25_8_0_+1h_+8d_inc_10", who="AB")
        assert s == 303, h
        wait(lambda: flow().finished.is_set() and flow().state in ("configured", "error"),
             timeout=30, what="the configuration")
        assert flow().state == "configured", flow().reason
        assert d.settings != before
        notes = "".join(d.settings["annotate"]).strip()
        assert "subject=P-017" in urllib.parse.unquote(notes) and "study=ABC" in notes
        cfg = Records(out).history("AX3", 10001)["configurations"]
        assert [c["result"] for c in cfg] == ["ok"]
        settings = st.ledger.configuration_of(10001, cfg[0]["session_id"], "AX3")
        assert settings["metadata"]["subject"] == "P-017" and settings["rate_hz"] == 25
        assert settings["session"] == 2  # "inc": the session after the one the clear erased
        # the next download of that session is named with the subject
        assert download_stem(prof, st.ledger, "AX3", 10001, settings["session"]) == \
            f"ABC_P-017_AX3-10001_{settings['session']}"

        s, _, body = request(dash, "GET", "/device/AX3-10001")
        assert "P-017" in body and "Configurations" in body
        s, _, sheet = request(dash, "GET", "/device/AX3-10001/sheet")
        assert s == 200 and "P-017" in sheet and "25 Hz" in sheet and "±8 g" in sheet
        assert f"ABC_P-017_AX3-10001_{settings['session']}.cwa" in sheet
        assert "yes (FORMAT QC)" in sheet
    finally:
        stop.set()
        t.join(20)
        dash.close()
        st.close()
