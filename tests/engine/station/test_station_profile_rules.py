"""Study profiles refuse what a device cannot record, at load, before any device is touched
(the rules: the device rule table, drivers/constants.py AX_DEVICE_RULES)."""

from __future__ import annotations

import copy
import hashlib

import pytest

from stillpoint.engine.station.profile import ProfileError, load_profile
from stillpoint.tools.cli import main

from station_fixtures import emu, runtime  # noqa: F401


@pytest.mark.parametrize("text, msg", [
    # AX6 above 1600 Hz (the IMU has no 3200 Hz setting)
    ('[device]\ntype = "AX6"\nrate_hz = 3200\n', "not recordable by an AX6 .6.25-1600 Hz"),
    # a profile for either type must fit both: 3200 Hz is AX3 only
    ('[device]\nrate_hz = 3200\n', 'not recordable by an AX6.*type = "AX3"'),
    # AX6 gyro below 25 Hz
    ('[device]\nrate_hz = 12.5\ngyro_dps = 250\n', "gyroscope needs at least 25 Hz"),
    ('[device]\ntype = "AX6"\nrate_hz = 6.25\ngyro_dps = 2000\n', "at least 25 Hz"),
    # AX3 packed below 12.5 Hz
    ('[device]\ntype = "AX3"\nrate_hz = 6.25\n', "not recordable by an AX3 .12.5-3200 Hz, packed"),
    ('[device]\nrate_hz = 6.25\n', "not recordable by an AX3"),
    # gyro only on an AX6, only the firmware's ranges
    ('[device]\ntype = "AX3"\ngyro_dps = 500\n', "gyro_dps = 500: an AX3 has no gyroscope"),
    ('[device]\ngyro_dps = 300\n', "gyro_dps must be 0 or one of"),
    # sessions: 0 .. 2^31-1
    ('[device]\nsession = "4294967296"\n', "session 4294967296 is above 2147483647"),
    ('[device]\nsession = "2147483648"\n', "above 2147483647"),
    ('[device]\nsession = "99999999999999999999"\n', "above 2147483647"),
    ('[device]\nsession = "\u00b2"\n', "session must be 'increment', 'keep' or a whole number"),
    ('[device]\nsession = -1\n', "session must be"),
    ('[device]\nsession = 1.5\n', "session must be"),
    # times the device cannot hold
    ('[device]\nstop = "+999999999d"\n', "stop '\\+999999999d' is beyond the year 2063"),
    ('[device]\nstart = "2070-01-01T00:00"\n', "outside the years 2000-2063"),
    # annotation: 14 slots x 32
    ('[metadata]\nx = "' + "y" * 447 + '"\n', "the device holds 448 .14 slots of 32"),
    ('[metadata]\nx = [1, 2]\n', "single value"),
    # shapes and types
    ('device = [1, 2]\n', r"\[device\] must be a table"),
    ('station = "yes"\n', r"\[station\] must be a table"),
    ('[device]\nrate = 50\n', "unknown key 'rate' in \\[device\\]"),
    ('[devices]\nrate_hz = 50\n', "unknown table or key 'devices'"),
    ('[device]\nrate_hz = true\n', "rate_hz must be a number"),
    ('[device]\nrate_hz = "fast"\n', "rate_hz must be a number"),
    ('[device]\nrate_hz = inf\n', "rate_hz must be a number of Hz, not inf"),
    ('[device]\nrate_hz = nan\n', "rate_hz must be a number of Hz, not nan"),
    ('[device]\nrange_g = 8.5\n', "range_g must be a whole number"),
    ('[device]\nled_flash = "no"\n', "led_flash must be true or false"),
    ('[device]\nmin_battery_pct = 101\n', "min_battery_pct must be 0..100"),
    ('[device]\ntype = "AX9"\n', 'type must be "AX3" or "AX6"'),
    ('[station]\nerase = "delete"\n', "erase must be one of 'quick', 'wipe'"),
    ('[station]\nclear_after_verify = "true"\n', "clear_after_verify must be true or false"),
])
def test_refused_at_load_naming_the_file(tmp_path, text, msg):
    p = tmp_path / "bad.toml"
    p.write_text(text)
    with pytest.raises(ProfileError, match=msg) as e:
        load_profile(p)
    assert str(p) in str(e.value) and "\n" not in str(e.value)


@pytest.mark.parametrize("text, types, rate_code", [
    ('[device]\ntype = "AX3"\nrate_hz = 3200\n', ("AX3",), 0x40 | 15),
    ('[device]\ntype = "ax6"\nrate_hz = 25\ngyro_dps = 2000\n', ("AX6",), 0x40 | 8),
    ('[device]\nrate_hz = 1600\ngyro_dps = 125\n', ("AX6",), 0x40 | 14),
    ('[device]\nrate_hz = 12.5\nsession = "2147483647"\n', ("AX3", "AX6"), 0x40 | 7),
    ('[device]\ntype = "AX6"\nrate_hz = 6.25\nsession = 0\n[station]\nerase = "wipe"\n', ("AX6",), 0x40 | 6),
])
def test_recordable_settings_load(tmp_path, text, types, rate_code):
    p = tmp_path / "ok.toml"
    p.write_text(text)
    prof = load_profile(p)
    assert prof.device_types == types and prof.rate_code == rate_code
    for kind in types:
        prof.check_device(kind)


def test_check_device_refuses_the_other_type(tmp_path):
    p = tmp_path / "ax6.toml"
    p.write_text('[device]\nrate_hz = 100\ngyro_dps = 500\n')
    prof = load_profile(p)
    with pytest.raises(ProfileError, match="cannot configure an AX3: gyro_dps = 500 needs an AX6"):
        prof.check_device("AX3")


# the campaign's reproducers (../shared/data/fuzz3/profile_*.toml) and the list-valued [device]
REPRODUCERS = {
    "profile_session_2p32.toml": ('[device]\nsession = "4294967296"\n', "above 2147483647"),
    "profile_session_superscript.toml": ('[device]\nsession = "\\u00b2"\n', "whole number"),
    "profile_session_20_digits.toml": ('[device]\nsession = "99999999999999999999"\n', "above"),
    "profile_stop_overflow.toml": ('[device]\nstop = "+999999999d"\n', "beyond the year 2063"),
    "profile_device_list.toml": ('device = [1, 2]\n', "must be a table"),
    "profile_ax6_3200.toml": ('[device]\ntype = "AX6"\nrate_hz = 3200\n', "not recordable"),
}


def _untouched(d):
    return (hashlib.sha256(d.data_file.read_bytes()).hexdigest(), d.session_id,
            copy.deepcopy(d.settings), len(d.clears))


@pytest.mark.parametrize("name", sorted(REPRODUCERS))
def test_station_refuses_the_profile_before_any_device_is_touched(emu, tmp_path, capsys, name):
    d = emu(10001)
    before = _untouched(d)
    text, msg = REPRODUCERS[name]
    prof = tmp_path / name
    prof.write_text(text)
    out = tmp_path / "out"
    rc = main(["station", str(out), "--once", "--clear-after-verify", "--configure-after",
               "--profile", str(prof), "--plain"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and msg in err[0] and str(prof) in err[0], err
    assert _untouched(d) == before
    assert not (out / "stillpoint-ledger.sqlite").exists()


@pytest.mark.parametrize("name", sorted(REPRODUCERS))
def test_device_configure_refuses_the_profile_before_touching(emu, tmp_path, capsys, name):
    d = emu(10001)
    before = _untouched(d)
    text, msg = REPRODUCERS[name]
    prof = tmp_path / name
    prof.write_text(text)
    assert main(["device", "configure", "10001", "--profile", str(prof)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and msg in err[0], err
    assert _untouched(d) == before


def test_device_configure_refuses_a_gyro_profile_for_an_ax3(emu, tmp_path, capsys):
    d = emu(10001)
    before = _untouched(d)
    prof = tmp_path / "gyro.toml"
    prof.write_text('[device]\nrate_hz = 100\ngyro_dps = 500\n')
    assert main(["device", "configure", "10001", "--profile", str(prof)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cannot configure an AX3: gyro_dps = 500 needs an AX6" in err[0]
    assert _untouched(d) == before


@pytest.mark.parametrize("name", ["profile_session_2p32.toml", "profile_session_superscript.toml",
                                  "profile_stop_overflow.toml"])
def test_the_shared_reproducers_are_the_ones_restated_here(fuzz3, name):
    """The reproducer files themselves (../shared/data/fuzz3) are refused with the same reason as
    their restatement above."""
    with pytest.raises(ProfileError, match=REPRODUCERS[name][1]):
        load_profile(fuzz3(name))
