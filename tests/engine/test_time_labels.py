"""One rule for time labels (engine/timezones.py): a time is called UTC (``...Z``, ``*_utc``,
``timezone_offset_s``) only when the zone is known; otherwise the outputs give the device clock
in ``*_local`` columns and say "zone unknown", and the MCAP log carries that in its ``clock``
record to everything read from it. A GENEActiv header zone that ``--timezone`` contradicts is
refused unless overridden, and the override is recorded."""

from __future__ import annotations

import csv
import gzip
import json

import pytest

from stillpoint.engine.mcap.stream import read_metadata
from stillpoint.engine.sim.record import simulate_recording
from stillpoint.engine.timezones import UNKNOWN_LABEL
from stillpoint.tools.cli import main
from stillpoint.engine.inspection import inspect_recording


@pytest.fixture(scope="module")
def cwa(tmp_path_factory):
    d = tmp_path_factory.mktemp("labels")
    p = d / "r.cwa"
    simulate_recording(p, days=0.05, hz=12.5, seed=4, truth_path=False, labels_path=False)
    return p


def _meta(mcap):
    with open(mcap, "rb") as f:
        return read_metadata(f)


def _run(args, capsys):
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def test_a_cwa_without_a_zone_is_never_labelled_utc(cwa, tmp_path, capsys):
    d = inspect_recording(cwa)
    assert d["start"] is None and d["end"] is None and d["timezone_offset_s"] is None
    assert d["timezone"] == UNKNOWN_LABEL and not d["start_local"].endswith("Z")
    code, out, _ = _run(["inspect", cwa], capsys)
    assert code == 0 and "Z" not in out.split("start")[1].splitlines()[0]
    out_csv = tmp_path / "x.csv"
    code, out, _ = _run(["export", cwa, "-o", out_csv], capsys)
    assert code == 0 and "device clock" in out
    with open(out_csv) as f:
        head, first = next(csv.reader(f)), next(csv.reader(f))
    assert head[0] == "time_local" and not first[0].endswith("Z")
    # the log says so, and what reads it keeps saying so
    mcap = tmp_path / "r.mcap"
    assert _run(["process", cwa, "-o", mcap, "-q"], capsys)[0] == 0
    assert _meta(mcap)["clock"]["known"] == "false"
    d = inspect_recording(mcap)
    assert d["start"] is None and d["timezone_offset_s"] is None and d["timezone"] == UNKNOWN_LABEL
    with gzip.open(tmp_path / "r.epochs.csv.gz", "rt") as f:
        assert next(csv.reader(f))[0] == "time_local"  # no UTC column at all
    topic = tmp_path / "m.csv"
    assert _run(["export", mcap, "--topic", "/metrics/epoch", "-o", topic], capsys)[0] == 0
    assert topic.read_text().startswith("time_local,time_local_ns,")
    again = tmp_path / "again.mcap"
    assert _run(["replay", mcap, "-o", again, "-q"], capsys)[0] == 0
    assert _meta(again)["clock"] == _meta(mcap)["clock"]


def test_a_known_zone_gives_utc_labels(cwa, tmp_path, capsys):
    d = inspect_recording(cwa, timezone="Europe/London")
    assert d["start"].endswith("Z") and d["timezone_offset_s"] == 0
    mcap = tmp_path / "z.mcap"
    assert _run(["process", cwa, "-o", mcap, "-q", "--timezone", "Europe/London"], capsys)[0] == 0
    clock = _meta(mcap)["clock"]
    assert clock["known"] == "true" and clock["zone"] == "Europe/London"
    d = inspect_recording(mcap)
    assert d["start"].endswith("Z") and d["timezone"] == "Europe/London"
    with gzip.open(tmp_path / "z.epochs.csv.gz", "rt") as f:
        assert next(csv.reader(f))[:2] == ["time_utc", "time_local"]


def test_a_log_without_the_clock_record_reads_as_before(cwa, tmp_path, capsys, monkeypatch):
    """A log written before the ``clock`` record existed: its times are read as UTC shifted by
    the device record's offset, as every reader did then."""
    from stillpoint.engine.mcap.log import McapLog
    write = McapLog.write_metadata
    monkeypatch.setattr(McapLog, "write_metadata",
                        lambda self, name, values: None if name == "clock" else write(self, name, values))
    mcap = tmp_path / "old.mcap"
    assert _run(["process", cwa, "-o", mcap, "-q", "--no-tables"], capsys)[0] == 0
    monkeypatch.undo()
    assert "clock" not in _meta(mcap)
    d = inspect_recording(mcap)
    assert d["start"].endswith("Z") and d["timezone_offset_s"] == 0


def test_a_geneactiv_header_zone_is_not_silently_replaced(tmp_path, capsys):
    rec = tmp_path / "g.bin"
    simulate_recording(rec, days=0.02, hz=25, seed=6, device="geneactiv", truth_path=False,
                       labels_path=False)
    assert inspect_recording(rec)["timezone_offset_s"] == 0  # the header says +00:00
    mcap = tmp_path / "g.mcap"
    code, out, err = _run(["process", rec, "-o", mcap, "-q", "--timezone", "America/New_York"],
                          capsys)
    assert code == 2 and err.count("\n") == 1 and str(rec) in err and "--timezone-override" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["g.bin"]
    # the zone the header gives is no conflict
    assert _run(["process", rec, "-o", mcap, "-q", "--timezone", "UTC"], capsys)[0] == 0
    over = tmp_path / "o.mcap"
    summ = tmp_path / "o.json"
    assert _run(["process", rec, "-o", over, "-q", "--timezone", "America/New_York",
                 "--timezone-override", "--summary", summ], capsys)[0] == 0
    settings = json.loads(_meta(over)["settings"]["json"])
    assert settings["timezone"] == "America/New_York" and settings["timezone_override"] is True
    assert json.loads(summ.read_text())["timezone_override"] is True
    assert _meta(over)["clock"]["zone"] == "America/New_York"
