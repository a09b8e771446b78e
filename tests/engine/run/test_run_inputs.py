"""engine/run/inputs.py: a run sniffs its input once and resolves the zone once; process_file
leaves the settings and table options it is given as they were."""

from __future__ import annotations

import copy
from pathlib import Path

import pytest

import stillpoint.drivers as drivers
import stillpoint.drivers.geneactiv as geneactiv
from stillpoint.engine.run import ClockZone, RunSettings, open_input, process_file
from stillpoint.engine.tables import TablesSettings, table_paths
from stillpoint.engine.timezones import clock_record, reader_timezone

GENEACTIV = "geneactiv_sleeppy_test_100hz_64pages.bin"
AX3 = "ax3_ggirread_testfile_100hz_145blocks.cwa"


def _counting(monkeypatch):
    counts = {"sniff": 0, "header": 0}
    sniff, header = drivers.sniff_format, geneactiv._read_header

    def counted_sniff(*a, **k):
        counts["sniff"] += 1
        return sniff(*a, **k)

    def counted_header(*a, **k):
        counts["header"] += 1
        return header(*a, **k)

    monkeypatch.setattr(drivers, "sniff_format", counted_sniff)
    monkeypatch.setattr(geneactiv, "_read_header", counted_header)
    return counts


@pytest.mark.parametrize("mode, passes", [("batch", 2), ("online", 1)])
def test_a_run_sniffs_once_and_reads_the_header_once_for_the_zone(tmp_path, monkeypatch,
                                                                     real_file, mode, passes):
    """A GENEActiv file given an IANA zone: one sniff; the header is read once to place the zone
    (its start time; its own zone checked against the given one) and once by each pass's reader
    (before: five sniffs and the header read twice more for the zone)."""
    counts = _counting(monkeypatch)
    s = RunSettings(mode=mode, timezone="Europe/London", timezone_override=True)
    summary = process_file(real_file(GENEACTIV), tmp_path / "run.mcap", s)
    assert summary["timezone"] == "Europe/London"
    assert counts == {"sniff": 1, "header": passes + 1}
    counts.update(sniff=0, header=0)
    process_file(real_file(GENEACTIV), tmp_path / "run.mcap", RunSettings(mode=mode))
    # the header's own zone comes from the opened reader: no read for the zone
    assert counts == {"sniff": 1, "header": passes}


@pytest.mark.parametrize("name, zone", [(AX3, "Europe/Amsterdam"), (AX3, None),
                                        (GENEACTIV, None), (GENEACTIV, "+01:00")])
def test_the_clock_zone_is_the_one_rule_every_command_uses(real_file, name, zone):
    """open_input's ClockZone agrees with engine.timezones.reader_timezone (export, inspect,
    dataframes) and with what the opened reader applied."""
    from stillpoint.drivers import sniff_format
    path = real_file(name)
    opened = open_input(path, RunSettings(timezone=zone, timezone_override=True))
    try:
        tz, expected = reader_timezone(path, sniff_format(path), zone, True)
        assert isinstance(opened.clock, ClockZone)
        assert opened.clock.zone == expected
        assert opened.clock.device_offset_s == opened.source.info.timezone_offset_s
        if tz is not None:
            assert opened.source.info.timezone_offset_s == tz
        assert opened.clock.record() == clock_record(expected, opened.source.info.timezone_offset_s)
    finally:
        opened.source.close()


@pytest.mark.parametrize("mode", ["batch", "online"])
def test_process_file_changes_neither_settings_nor_table_options(tmp_path, real_file, mode):
    """The tables are given no zone; the run uses its own (a copy), the caller's stay unknown."""
    from stillpoint.engine.sleep import SleepOptions, nights_path
    out = tmp_path / "run.mcap"
    s = RunSettings(mode=mode, timezone="Europe/Amsterdam")
    ts = TablesSettings(*table_paths(out), sleep=SleepOptions(), nights_path=nights_path(out))
    s0, ts0 = copy.deepcopy(s), copy.deepcopy(ts)
    summary = process_file(real_file(AX3), out, s, tables=ts)
    assert summary["tables"]["timezone"] == "Europe/Amsterdam"
    assert s == s0
    assert ts == ts0 and not ts.zone.known
    assert Path(summary["outputs"]["days"]).is_file()
