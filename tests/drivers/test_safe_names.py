"""Names and CSV cells made from recording metadata: a header's serial is never a path and never
a spreadsheet formula (drivers.names; the station inbox, the cohort summary, the day table)."""

from __future__ import annotations

import csv
import time
from pathlib import Path

import pytest

from stillpoint.drivers.names import MAX_NAME_PART, csv_cell, safe_child, safe_name_part

DATA = Path(__file__).parents[1] / "data" / "hostile_names"

HOSTILE = ["../escaped", "/tmp/stillpoint_escaped", "..", ".", "", "a/../../b", "..\\..\\x",
           "x\x00y", "line\nbreak", "tab\there", "-rf", ".hidden", "~/x", "C:\\Windows",
           "é/ü", "²", "=HYPERLINK(\"http://x\")", "a" * 5000, "../" * 100, " ", "...",
           "\ud800", "con", "a..b"]


@pytest.mark.parametrize("text", HOSTILE)
def test_a_name_part_is_one_plain_component(text, tmp_path):
    s = safe_name_part(text)
    assert s and len(s) <= MAX_NAME_PART
    assert "/" not in s and "\\" not in s and ".." not in s
    assert not s.startswith((".", "-"))
    assert all(c.isascii() and (c.isalnum() or c in "._-") for c in s)
    p = safe_child(tmp_path, s + ".bin")
    assert p.parent == tmp_path
    p.write_bytes(b"")  # a name the file system takes


def test_clean_names_are_unchanged_and_changed_names_stay_distinct():
    for clean in ("10001", "AX3-39434", "p01", "GENEActiv_012345", "rec.v2"):
        assert safe_name_part(clean) == clean
    assert safe_name_part("a/b") != safe_name_part("a_b")
    assert safe_name_part("../x") != safe_name_part("x")
    assert safe_name_part(None) == "unknown" and safe_name_part("", fallback="recording") == "recording"
    assert safe_name_part("a" * 5000) != safe_name_part("a" * 4999)


@pytest.mark.parametrize("part", ["", ".", "..", "a/b", "../x", "/abs", "x\x00"])
def test_safe_child_refuses_anything_but_a_file_name(part, tmp_path):
    with pytest.raises(ValueError):
        safe_child(tmp_path, part)


@pytest.mark.parametrize("text", ["=1+2", "+cmd|' /C calc'!A0", "-2+3", "@SUM(A1)", "\tx", "\rx",
                                  "=HYPERLINK(\"http://evil\",\"x\")", "-x", "+"])
def test_formula_text_is_neutralised(text):
    assert csv_cell(text) == "'" + text


@pytest.mark.parametrize("value", [-12.5, -3, 0, 2.5e-3, "-12.5", "+3e-2", "-0", ".5", "+01:00",
                                   "-05:30", "AX3", "2025-03-03", "", None, True, "a=b"])
def test_numbers_and_plain_text_stay_as_they_are(value):
    assert csv_cell(value) is value or csv_cell(value) == value


# ---------------------------------------------------------------------------- the station inbox
def _ingest(tmp_path, src: Path, name: str):
    from stillpoint.engine.station.inbox import Inbox
    from stillpoint.engine.station.ledger import Ledger
    inbox, out = tmp_path / "inbox", tmp_path / "deep" / "out"
    inbox.mkdir()
    out.mkdir(parents=True)
    (inbox / name).write_bytes(src.read_bytes())
    lg = Ledger(out)
    ib = Inbox(inbox, out, stable_s=0.0, ledger=lg)
    end = time.monotonic() + 60
    while time.monotonic() < end and not ib.idle():
        time.sleep(0.05)
    return out, lg, ib


@pytest.mark.parametrize("repro, escaped", [
    ("geneactiv_serial_dotdot.bin", "escaped_rel"),
    ("geneactiv_serial_absolute.bin", "/tmp/stillpoint_escaped_abs"),
])
def test_a_header_serial_never_writes_outside_the_output_folder(tmp_path, repro, escaped):
    name = "rel.bin" if "dotdot" in repro else "abs.bin"
    out, lg, ib = _ingest(tmp_path, DATA / repro, name)
    outside = (out.parent / escaped) if not escaped.startswith("/") else Path(escaped)
    assert not any(Path(str(outside) + ext).exists() for ext in (".bin", ".mcap"))
    assert sorted(p.name for p in out.parent.iterdir()) == ["out"]
    made = sorted(p.name for p in out.iterdir() if not p.name.startswith("stillpoint-ledger"))
    assert [n for n in made if n.endswith(".bin")] and [n for n in made if n.endswith(".mcap")]
    assert all(n.startswith(("GENEActiv-escaped-", "GENEActiv-tmp_stillpoint_escaped-"))
               for n in made), made
    rec = lg.downloads()[0]
    for p in (rec.cwa_path, rec.mcap_path):
        assert Path(p).parent == out and Path(p).is_file()


# ---------------------------------------------------------------------------- CSV tables
def _hyperlink_bin(tmp_path) -> Path:
    """The reproducer with its 10-character serial ``../escaped`` replaced by ``=HYPERLINK``."""
    data = (DATA / "geneactiv_serial_dotdot.bin").read_bytes()
    assert data.count(b"Serial Code:../escaped\r\n") >= 1  # the header and every page
    p = tmp_path / "formula.bin"
    p.write_bytes(data.replace(b"Serial Code:../escaped", b"Serial Code:=HYPERLINK"))
    return p


def test_cohort_summary_cells_are_never_formulas(tmp_path):
    from stillpoint.tools.cli import main
    rec = _hyperlink_bin(tmp_path)
    out = tmp_path / "co"
    assert main(["cohort", "run", str(rec), "-o", str(out), "--scheduler", "serial", "-q"]) == 0
    with open(out / "cohort_summary.csv", newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    assert rows[0]["device_id"] == "'=HYPERLINK"
    from stillpoint.drivers.names import _PLAIN_VALUE  # numbers and UTC offsets (+00:00) are data
    assert all(not v.startswith(("=", "+", "@", "\t", "\r")) or _PLAIN_VALUE.fullmatch(v)
               for r in rows for v in r.values())
    assert rows[0]["timezone"] == "+00:00"  # the header's zone, a plain offset
    assert float(rows[0]["offset_x"]) == float(rows[0]["offset_x"])  # numbers stay numbers
    negative = [v for r in rows for k, v in r.items() if k.startswith("offset_") and v.startswith("-")]
    assert all(float(v) < 0 for v in negative)



def test_exported_message_text_is_never_a_formula(tmp_path):
    """A /qc message of a (hostile or damaged) log exported as CSV: text, not a formula."""
    from mcap.writer import Writer

    from stillpoint.tools.cli import main
    log = tmp_path / "hostile.mcap"
    with open(log, "wb") as f:
        w = Writer(f)
        w.start()
        w.add_metadata("device", {"device_type": "AX3", "device_id": "1"})
        sid = w.register_schema("qc", "jsonschema", b"{}")
        cid = w.register_channel("/qc", "json", sid)
        for i, text in enumerate(['=HYPERLINK("http://evil","x")', "+cmd|' /C calc'!A0",
                                  '{"reason": "ok"}']):
            w.add_message(cid, log_time=i, publish_time=i, data=text.encode(), sequence=i)
        w.finish()
    out = tmp_path / "qc.csv"
    assert main(["export", str(log), "-o", str(out), "--topic", "/qc"]) == 0
    with open(out, newline="", encoding="utf-8") as f:
        cells = [r["json"] for r in csv.DictReader(f)]
    assert len(cells) == 3 and cells[2].startswith("{")
    assert cells[0].startswith("'=") and cells[1].startswith("'+")


def test_calibration_store_files_of_hostile_keys_stay_in_the_store(tmp_path):
    """A GENEActiv key carries the header's serial: its store file is one bounded name; a file
    an earlier version named for an odd key is still found."""
    from stillpoint.engine.calibration.store import (CalibrationStore, _earlier_file_name,
                                                     device_file_name)
    for key in ("GENEActiv-../../x", "GENEActiv-" + "a" * 400, "GENEActiv-..", "AX3-39434"):
        name = device_file_name(key)
        assert "/" not in name and ".." not in name and len(name) <= 64 + len(".json")
    assert device_file_name("AX3-39434") == "AX3-39434.json"
    store = CalibrationStore(tmp_path)
    store.dir.mkdir(parents=True)
    old = store.dir / _earlier_file_name("GENEActiv-..x")
    old.write_text("{}")
    assert old.name != device_file_name("GENEActiv-..x")
    assert store._path("GENEActiv-..x") == old


def test_calibration_store_lock_link_is_not_followed(tmp_path):
    from stillpoint.engine.calibration.store import CalibrationStoreError, _locked
    store_file = tmp_path / "AX3-1.json"
    outside = tmp_path / "elsewhere" / "created.lock"
    outside.parent.mkdir()
    (tmp_path / "AX3-1.json.lock").symlink_to(outside)
    with pytest.raises(CalibrationStoreError, match="symbolic link"):
        with _locked(store_file):
            pass
    assert not outside.exists()


def test_a_geneactiv_serial_equal_to_an_ax_id_does_not_share_output_names(tmp_path):
    """p01.bin (GENEActiv serial 123456) and p01.cwa (AX3 id 123456): two raw copies and two
    MCAP logs (the second MCAP used to replace the first)."""
    from stillpoint.engine.sim.record import simulate_recording
    from stillpoint.engine.station.inbox import Inbox
    from stillpoint.engine.station.ledger import Ledger
    inbox, out = tmp_path / "inbox", tmp_path / "out"
    inbox.mkdir()
    out.mkdir()
    for dev, ext in (("geneactiv", ".bin"), ("ax3", ".cwa")):
        simulate_recording(inbox / f"p01{ext}", device=dev, days=0.01, truth_path=False,
                           device_id=123456)
    lg = Ledger(out)
    ib = Inbox(inbox, out, stable_s=0.0, ledger=lg)
    end = time.monotonic() + 60
    while time.monotonic() < end and not ib.idle():
        time.sleep(0.05)
    recs = lg.downloads()
    assert len(recs) == 2 and all(r.verified for r in recs), ib.errors
    assert len({r.mcap_path for r in recs}) == 2
    assert all(Path(r.mcap_path).is_file() and Path(r.cwa_path).is_file() for r in recs)
