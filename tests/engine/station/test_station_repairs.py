"""Every repair on record: a transient misread that the verification re-reads and patches is in
the ledger (the download row and an event of its own), on the station's line, on the
dashboard's device page and in the log's ``station`` record; a clean download says it needed
none."""

from __future__ import annotations

import os
import sqlite3

from mcap.reader import make_reader

from stillpoint.engine.station.download import repairs_text
from stillpoint.engine.station.web.pages import device_page
from stillpoint.engine.station.web.records import Records
from stillpoint.tools.cli import main

from station_fixtures import emu, runtime  # noqa: F401


def _station_record(path) -> dict:
    with open(path, "rb") as f:
        return {m.name: m.metadata for m in make_reader(f).iter_metadata()}["station"]


def test_repairs_text():
    assert repairs_text(0, 0) == ""
    assert repairs_text(1, 1) == "1 range re-read, copy patched"
    assert repairs_text(1, 0) == "1 range re-read, copy confirmed"
    assert repairs_text(3, 2) == "3 ranges re-read, 2 patched"


def test_a_patched_copy_is_on_record_everywhere(emu, tmp_path, capsys):
    flipped = emu(10001, faults=("bit-flip",))
    emu(10002)
    held = flipped.data_file.read_bytes()
    out = tmp_path / "out"
    out.mkdir()
    assert main(["station", str(out), "--once", "--clear-after-verify", "--plain"]) == 0
    text = capsys.readouterr().out
    line = [x for x in text.splitlines() if "10001 [emu-1] verified:" in x]
    assert line and "1 range re-read, copy patched" in line[0], text
    clean = [x for x in text.splitlines() if "10002 [emu-2] verified:" in x]
    assert clean and "re-read" not in clean[0], text
    assert (out / "AX3-10001_1.cwa").read_bytes() == held  # the patch restored the device's bytes

    db = sqlite3.connect(out / "stillpoint-ledger.sqlite")
    try:
        rows = dict(((i, (r, p))) for i, r, p in db.execute(
            "SELECT device_id, reread_ranges, patched_ranges FROM downloads WHERE state='verified'"))
        events = db.execute("SELECT device_id, reason FROM events WHERE state='repaired'").fetchall()
    finally:
        db.close()
    assert rows == {10001: (1, 1), 10002: (0, 0)}
    assert len(events) == 1 and events[0][0] == 10001
    assert events[0][1].endswith(": 1 range re-read, copy patched")

    rec = _station_record(out / "AX3-10001_1.mcap")
    assert (rec["reread_ranges"], rec["patched_ranges"], rec["repairs"]) == \
        ("1", "1", "1 range re-read, copy patched")
    rec = _station_record(out / "AX3-10002_1.mcap")
    assert (rec["reread_ranges"], rec["patched_ranges"], rec["repairs"]) == ("0", "0", "none")

    records = Records(out)
    page = device_page(records, records.history("AX3", 10001))
    assert "<th>repairs</th>" in page and "1 range re-read, copy patched" in page
    page = device_page(records, records.history("AX3", 10002))
    assert "<td>none</td>" in page
    assert os.path.exists(out / "AX3-10002_1.cwa")
