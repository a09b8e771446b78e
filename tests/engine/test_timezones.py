"""The zone rules of engine/timezones.py, each on its own: what ``parse_zone`` accepts and refuses,
the offset in force at every instant (DST changes found to the second, local days of 23 and 25
hours), the offset of a device clock set to a zone's wall-clock time, the UTC/local labels, the
``clock`` record of a log and its reading (old logs included), a header zone that a given zone
contradicts, and the host's zone. Expected offsets come from the standard library's zoneinfo,
instant by instant, and from the published EU rule (summer time from 01:00 UTC on the last
Sunday of March to 01:00 UTC on the last Sunday of October)."""

from __future__ import annotations

import datetime as dt
import zoneinfo

import numpy as np
import pytest

from stillpoint.engine.sim.record import simulate_recording
from stillpoint.engine.timezones import (UNKNOWN_LABEL, Zone, ZoneError, check_header_zone,
                                         clock_record, fixed_zone, host_zone, local_text,
                                         parse_zone, reader_timezone, time_column, utc_text,
                                         zone_from_label, zone_of_log)

LONDON = "Europe/London"
UTC = dt.timezone.utc
SPRING_2026 = dt.datetime(2026, 3, 29, 1, 0, tzinfo=UTC)  # last Sunday of March, 01:00 UTC
AUTUMN_2026 = dt.datetime(2026, 10, 25, 1, 0, tzinfo=UTC)  # last Sunday of October


def _ns(d: dt.datetime) -> int:
    return int(d.timestamp()) * 10**9


def _day(d: dt.date) -> int:
    return (d - dt.date(1970, 1, 1)).days


@pytest.mark.parametrize("spec,name,fixed_s", [
    ("+01:00", "+01:00", 3600), ("-0530", "-05:30", -19800), ("GMT +01:00", "+01:00", 3600),
    ("UTC", "+00:00", 0), (" +02:00 ", "+02:00", 7200), (3600, "+01:00", 3600),
    (np.int64(-3600), "-01:00", -3600)])
def test_fixed_offsets_in_every_spelling(spec, name, fixed_s):
    z = parse_zone(spec)
    assert (z.name, z.fixed_s, z.known, z.iana, z.label) == (name, fixed_s, True, False, name)
    assert z == fixed_zone(fixed_s)


def test_iana_names_and_unknown():
    z = parse_zone(LONDON)
    assert (z.name, z.fixed_s, z.known, z.iana, z.label) == (LONDON, None, True, True, LONDON)
    for spec in (None, "", "   "):
        u = parse_zone(spec)
        assert not u.known and not u.iana and u.label == UNKNOWN_LABEL
    assert parse_zone(z) is z


@pytest.mark.parametrize("spec", ["GMT+1", "UTC-5", "gmt-11"])
def test_gmt_plus_without_a_space_is_refused_as_ambiguous(spec):
    with pytest.raises(ZoneError, match="ambiguous"):
        parse_zone(spec)


@pytest.mark.parametrize("spec", ["Mars/Olympus", "+25:00", "Europe/" + "x" * 300, "soon"])
def test_a_zone_that_is_neither_a_name_nor_an_offset_is_refused_in_one_line(spec):
    with pytest.raises(ZoneError) as e:
        parse_zone(spec)
    text = str(e.value)
    assert "neither an IANA name" in text and "\n" not in text and len(text) < 250


def test_offsets_follow_the_zone_database_at_every_instant():
    rng = np.random.default_rng(7)
    t_s = rng.integers(_ns(dt.datetime(2025, 1, 1, tzinfo=UTC)) // 10**9,
                       _ns(dt.datetime(2027, 1, 1, tzinfo=UTC)) // 10**9, 3000)
    tz = zoneinfo.ZoneInfo(LONDON)
    want = [int(dt.datetime.fromtimestamp(int(s), tz=UTC).astimezone(tz).utcoffset()
                .total_seconds()) for s in t_s]
    z = parse_zone(LONDON)
    got = z.offsets_s(t_s * 10**9)
    assert got.dtype == np.int64 and got.tolist() == want
    assert [z.offset_at_s(int(s)) for s in t_s[:50]] == want[:50]


@pytest.mark.parametrize("change,before,after", [(SPRING_2026, 0, 3600), (AUTUMN_2026, 3600, 0)])
def test_a_dst_change_is_placed_to_the_second(change, before, after):
    z = parse_zone(LONDON)
    t = _ns(change)
    got = z.offsets_s(np.array([t - 3600 * 10**9, t - 10**9, t - 1, t, t + 1, t + 3599 * 10**9]))
    assert got.tolist() == [before, before, before, after, after, after]
    assert z.local_ns(np.array([t - 10**9, t])).tolist() == [t - 10**9 + before * 10**9,
                                                             t + after * 10**9]


def test_a_fixed_offset_never_changes():
    z = parse_zone("+01:00")
    t = np.array([_ns(SPRING_2026) - 1, _ns(SPRING_2026), _ns(AUTUMN_2026)])
    assert z.offsets_s(t).tolist() == [3600] * 3
    assert parse_zone(None).offsets_s(t).tolist() == [0] * 3


def test_local_days_have_23_and_25_hours_at_the_changes_with_a_name_only():
    z, f = parse_zone(LONDON), parse_zone("+01:00")

    def hours(zone, d):
        return (zone.utc_of_local_midnight_ns(_day(d) + 1)
                - zone.utc_of_local_midnight_ns(_day(d))) / 3600e9
    assert hours(z, dt.date(2026, 3, 29)) == 23 and hours(z, dt.date(2026, 10, 25)) == 25
    assert hours(z, dt.date(2026, 6, 1)) == 24
    assert {hours(f, d) for d in (dt.date(2026, 3, 29), dt.date(2026, 10, 25))} == {24}
    # local midnight of 1 July 2026 in London is 23:00 UTC the day before
    assert z.utc_of_local_midnight_ns(_day(dt.date(2026, 7, 1))) == \
        _ns(dt.datetime(2026, 6, 30, 23, tzinfo=UTC))
    assert f.utc_of_local_midnight_ns(0) == -3600 * 10**9


def test_a_device_clock_set_to_local_time_gets_the_offset_in_force_then():
    z = parse_zone(LONDON)
    summer = dt.datetime(2026, 7, 1, 12, tzinfo=UTC).timestamp()  # a device clock reading
    winter = dt.datetime(2026, 1, 15, 12, tzinfo=UTC).timestamp()
    assert z.device_offset_s(summer) == 3600 and z.device_offset_s(winter) == 0
    assert parse_zone("-05:00").device_offset_s(summer) == -18000
    assert parse_zone(None).device_offset_s(summer) == 0


def test_times_are_called_utc_only_when_the_zone_is_known():
    t = _ns(SPRING_2026)
    z, u = parse_zone(LONDON), parse_zone(None)
    assert utc_text(t, z) == "2026-03-29T01:00:00Z" and utc_text(t, u) == ""
    assert local_text(t, z) == "2026-03-29T02:00:00+01:00"
    assert local_text(t - 10**9, z) == "2026-03-29T00:59:59+00:00"
    assert local_text(t, u) == "2026-03-29T01:00:00"  # the device clock, no offset claimed
    assert utc_text(None, z) == "" and local_text(None, z) == ""
    assert time_column(z) == "time" and time_column(u) == "time_local"
    assert z.to_dict() == {"zone": LONDON, "known": True, "iana": True, "fixed_offset_s": None}
    assert u.to_dict()["zone"] == UNKNOWN_LABEL


def test_an_output_label_names_its_zone_back():
    for label in (None, "", UNKNOWN_LABEL, "unknown"):
        assert not zone_from_label(label).known
    assert zone_from_label(LONDON) == parse_zone(LONDON)
    assert zone_from_label("+02:00") == fixed_zone(7200)
    assert zone_from_label(parse_zone(LONDON).label) == parse_zone(LONDON)


def test_the_clock_record_of_a_log_reads_back():
    for zone, offset in ((parse_zone(LONDON), 3600), (fixed_zone(-18000), -18000),
                         (parse_zone(None), 0)):
        rec = clock_record(zone, offset)
        assert rec["device_offset_s"] == str(offset) and rec["label"] == zone.label
        assert all(isinstance(v, str) for v in rec.values())
        assert zone_of_log({"clock": rec}, offset) == zone
    # a log written before the clock record: UTC shifted by the device record's offset
    assert zone_of_log({}, 7200) == fixed_zone(7200) and zone_of_log(None) == fixed_zone(0)
    # a record naming a zone this system cannot use: the device offset stands in
    bad = {"zone": "Mars/Olympus", "known": "true", "label": "Mars/Olympus",
           "device_offset_s": "3600"}
    assert zone_of_log({"clock": bad}, 3600) == fixed_zone(3600)


def test_a_given_zone_that_contradicts_the_header_is_refused_unless_overridden():
    summer_start = dt.datetime(2026, 7, 1, 9, tzinfo=UTC).timestamp()
    z = parse_zone(LONDON)
    check_header_zone("r.bin", 3600, z, summer_start, override=False)  # agrees: summer time
    with pytest.raises(ZoneError) as e:
        check_header_zone("r.bin", 0, z, summer_start, override=False)
    text = str(e.value)
    assert text.startswith("r.bin: ") and "+00:00" in text and "+01:00" in text
    assert "--timezone-override" in text
    check_header_zone("r.bin", 0, z, summer_start, override=True)
    check_header_zone("r.bin", 0, parse_zone(None), summer_start, override=False)
    with pytest.raises(ZoneError):
        check_header_zone("r.bin", 0, parse_zone("+02:00"), None, override=False)


@pytest.fixture(scope="module")
def summer_cwa(tmp_path_factory):
    p = tmp_path_factory.mktemp("zones") / "summer.cwa"
    simulate_recording(p, days=0.0005, hz=12.5, seed=3, truth_path=False, labels_path=False,
                       start="2026-07-01T09:00:00+00:00")
    return p


def test_a_cwa_clock_takes_the_offset_in_force_at_its_first_sample(summer_cwa):
    assert reader_timezone(summer_cwa, "cwa", None) == (0, parse_zone(None))
    assert reader_timezone(summer_cwa, "cwa", "-03:00") == (-10800, fixed_zone(-10800))
    assert reader_timezone(summer_cwa, "cwa", LONDON) == (3600, parse_zone(LONDON))
    assert reader_timezone(summer_cwa, "cwa", "Europe/Paris") == (7200, parse_zone("Europe/Paris"))


def test_the_host_zone_is_tz_when_it_names_one(monkeypatch):
    monkeypatch.setenv("TZ", "America/New_York")
    assert host_zone() == Zone("America/New_York")
    monkeypatch.setenv("TZ", ":Asia/Tokyo")
    assert host_zone() == Zone("Asia/Tokyo")
    monkeypatch.setenv("TZ", "Not/AZone")
    assert host_zone().known  # falls through to the system's zone or the offset in force
