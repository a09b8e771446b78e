"""The ledger (WAL, one transaction per state change, second station refused) and the clear rule."""

from __future__ import annotations

import hashlib
import os
import sqlite3

import pytest

from stillpoint.drivers.ax.protocol import AxClient
from stillpoint.engine.station.clearing import ClearRefused, clear_verified
from stillpoint.engine.station.download import DownloadJob, run_download
from stillpoint.engine.station.ledger import Ledger, LedgerError, acquire_station_lock

from station_fixtures import emu, runtime, wait_for  # noqa: F401


def test_wal_and_reopen(tmp_path):
    lg = Ledger(tmp_path)
    dl = lg.download_started(1, 2, clock_offset_s=1.5, battery_pct=80)
    (tmp_path / "1_2.cwa").write_bytes(b"x")
    lg.download_verified(dl, bytes_=1, sha256="ab", bad_sectors=0, cwa_path=str(tmp_path / "1_2.cwa"),
                         mcap_path="m")
    assert lg.db.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    lg.close()  # a crash after the transaction: a new process sees the committed record
    lg2 = Ledger(tmp_path)
    rec = lg2.verified_download(1, 2, "ab")
    assert rec is not None and rec.bytes == 1
    assert lg2.verified_download(1, 2, "other-hash") is None
    assert lg2.verified_download(1, 3) is None
    (tmp_path / "1_2.cwa").unlink()  # a verified record whose copy is gone does not count
    assert lg2.verified_download(1, 2) is None


def test_uncommitted_change_is_not_seen(tmp_path):
    lg = Ledger(tmp_path)
    con = sqlite3.connect(lg.path, isolation_level=None)
    con.execute("BEGIN IMMEDIATE")
    con.execute("INSERT INTO downloads(device_id, session_id, state, verified, cwa_path) VALUES "
                "(5, 1, 'verified', 1, ?)", (str(lg.path),))
    con.close()  # dies before COMMIT
    assert Ledger(tmp_path).verified_download(5, 1) is None


def test_damaged_ledger_refused_at_open_and_on_read(tmp_path):
    """A ledger whose pages are damaged is refused when opened (quick_check), naming the file;
    damage met later, on a read, is a LedgerError too (one line from the CLI, the device not
    cleared), never a raw sqlite3 error."""
    lg = Ledger(tmp_path)
    for i in range(3000):
        lg.event(i, f"serial-{i}", "verified", "x" * 60)
    lg.close()  # the last connection: the WAL is checkpointed into the file
    data = bytearray(lg.path.read_bytes())
    assert len(data) > 64 * 1024
    page = 4096
    data[8 * page:9 * page] = b"\xab" * page  # a data page, not the schema's
    lg.path.write_bytes(bytes(data))
    with pytest.raises(LedgerError, match="the ledger is damaged") as e:
        Ledger(tmp_path)
    assert str(lg.path) in str(e.value)

    class Failing:
        def execute(self, *_a):
            raise sqlite3.DatabaseError("database disk image is malformed")

    (tmp_path / "fresh").mkdir()
    ok = Ledger(tmp_path / "fresh")
    ok.db = Failing()
    with pytest.raises(LedgerError, match="cannot read the ledger: database disk image is malformed"):
        ok.verified_download(1, 1)


def test_second_station_refused(tmp_path):
    fd = acquire_station_lock(tmp_path)
    try:
        with pytest.raises(LedgerError, match="another station is already using this folder"):
            acquire_station_lock(tmp_path)
    finally:
        import os
        os.close(fd)
    os.close(acquire_station_lock(tmp_path))  # released: the next station may start


def _verified(d, out, lg):
    dl = lg.download_started(d.device_id, d.session_id)
    r = run_download(DownloadJob(d.device_id, d.session_id, str(d.data_file), str(out), pipeline=False))
    assert r.ok, r.reason
    from stillpoint.engine.station.completion import complete
    complete(lg, dl, cwa_path=r.cwa_path, mcap_path=None, sha256=r.sha256, bytes_=r.bytes,
             bad_sectors=r.bad_sectors, with_log=False)
    return r


def test_clear_refused_without_verified_download(emu, tmp_path):
    d = emu(12345)
    lg = Ledger(tmp_path)
    with AxClient.open(f"axemu://{d.serial}") as c:
        with pytest.raises(ClearRefused, match="no verified download"):
            clear_verified(c, lg, 12345, 1, d.data_file, wait_for(d))
    assert d.clears == [] and lg.clears() == []


def test_clear_after_verification_and_readback(emu, tmp_path):
    d = emu(12345)
    lg = Ledger(tmp_path)
    r = _verified(d, tmp_path, lg)
    with AxClient.open(f"axemu://{d.serial}") as c:
        clear_verified(c, lg, 12345, 1, d.data_file, wait_for(d))
    assert d.clears == [(12345, 1, r.sha256)]
    assert d.data_file.stat().st_size == 1024
    assert lg.clears()[-1][:5] == (12345, 1, 1, r.sha256, "ok")


def test_clear_refused_when_the_file_grew(emu, tmp_path):
    d = emu(12345)
    lg = Ledger(tmp_path)
    _verified(d, tmp_path, lg)
    with open(d.data_file, "ab") as f:
        f.write(b"\0" * 512)
    with AxClient.open(f"axemu://{d.serial}") as c:
        with pytest.raises(ClearRefused, match="is not the verified copy"):
            clear_verified(c, lg, 12345, 1, d.data_file, wait_for(d))
    assert d.clears == []


def test_clear_refused_for_another_session(emu, tmp_path):
    d = emu(12345)
    lg = Ledger(tmp_path)
    _verified(d, tmp_path, lg)
    with AxClient.open(f"axemu://{d.serial}") as c:
        c.session(2)
        with pytest.raises(ClearRefused):
            clear_verified(c, lg, 12345, 2, d.data_file, wait_for(d))
        with pytest.raises(ClearRefused, match="session is now 2"):
            clear_verified(c, lg, 12345, 1, d.data_file, wait_for(d))
    assert d.clears == []


# ---------------------------------------------------------------------- completion and restarts
def _part_ready(d, out):
    """A verified download result whose files are still unnamed (what a worker hands back)."""
    r = run_download(DownloadJob(d.device_id, d.session_id, str(d.data_file), str(out), pipeline=False))
    assert r.ok, r.reason
    return r


@pytest.mark.parametrize("left", ["part", "final", "neither"])
def test_a_download_left_completing_is_reconciled(emu, tmp_path, left):
    from stillpoint.engine.station.completion import reconcile
    d = emu(12345)
    lg = Ledger(tmp_path)
    r = _part_ready(d, tmp_path)
    dl = lg.download_started(12345, 1, cwa_path=r.cwa_path)
    lg.download_completing(dl, bytes_=r.bytes, sha256=r.sha256, bad_sectors=0, cwa_path=r.cwa_path,
                           mcap_path=None)
    part, final = tmp_path / "AX3-12345_1.cwa.part", tmp_path / "AX3-12345_1.cwa"
    if left == "final":  # killed between the rename and the 'verified' row
        os.link(part, final)
        os.unlink(part)
    elif left == "neither":
        os.unlink(part)
    lines = reconcile(lg)
    rec = lg.downloads()[-1]
    if left == "neither":
        assert rec.state == "error" and "downloaded again" in rec.reason and len(lines) == 1
    else:
        assert rec.state == "verified" and rec.verified and lines
        assert final.read_bytes() == d.data_file.read_bytes() and not part.exists()
        assert lg.verified_download(12345, 1, device_type="AX3").id == dl


def test_a_download_left_downloading_becomes_an_error_that_resumes(emu, tmp_path):
    from stillpoint.engine.station.completion import reconcile
    lg = Ledger(tmp_path)
    dl = lg.download_started(12345, 1)
    reconcile(lg)
    rec = lg.downloads()[-1]
    assert rec.id == dl and rec.state == "error" and "resumes" in rec.reason


def test_a_final_copy_without_a_ledger_row_is_adopted_only_if_it_is_the_device(emu, tmp_path):
    d = emu(12345)
    final = tmp_path / "AX3-12345_1.cwa"
    final.write_bytes(d.data_file.read_bytes())
    r = run_download(DownloadJob(12345, 1, str(d.data_file), str(tmp_path), pipeline=False))
    assert r.ok and r.adopted and r.cwa_part is None
    assert r.sha256 == hashlib.sha256(d.data_file.read_bytes()).hexdigest()
    other = bytearray(d.data_file.read_bytes())
    other[5000] ^= 1
    final.write_bytes(bytes(other))
    r = run_download(DownloadJob(12345, 1, str(d.data_file), str(tmp_path), pipeline=False))
    assert not r.ok and "not a copy of the device's data" in r.reason
    assert final.read_bytes() == bytes(other)  # nothing is overwritten


def test_a_clear_left_sent_is_settled_from_the_device(emu, tmp_path):
    from stillpoint.engine.station.completion import resolve_sent_clear
    d = emu(12345)
    lg = Ledger(tmp_path)
    r = _verified(d, tmp_path, lg)
    c1 = lg.clear_attempt(12345, 1, 1, r.sha256)  # killed before the erase took effect
    assert "not cleared" in resolve_sent_clear(lg, 12345, d.data_file)[0]
    c2 = lg.clear_attempt(12345, 1, 1, r.sha256)  # killed after it
    with open(d.data_file, "r+b") as f:
        f.truncate(1024)
    assert "only a header" in resolve_sent_clear(lg, 12345, d.data_file)[0]
    assert [c[4] for c in lg.clears()] == ["error", "ok"] and c1 < c2
    assert lg.sent_clears(12345) == []


# ---------------------------------------------------------------------- links in the output folder
def test_a_planted_part_link_never_receives_the_download(emu, tmp_path):
    d = emu(12345)
    out = tmp_path / "out"
    out.mkdir()
    victim = tmp_path / "victim"
    victim.write_bytes(b"precious")
    (out / "AX3-12345_1.cwa.part").symlink_to(victim)
    r = run_download(DownloadJob(12345, 1, str(d.data_file), str(out), pipeline=False))
    assert not r.ok and "link" in r.reason
    os.unlink(out / "AX3-12345_1.cwa.part")
    os.link(victim, out / "AX3-12345_1.cwa.part")  # a hard link: another name of the same file
    r = run_download(DownloadJob(12345, 1, str(d.data_file), str(out), pipeline=False))
    assert not r.ok and "link" in r.reason
    assert victim.read_bytes() == b"precious"


def test_a_planted_final_link_is_not_adopted_or_written(emu, tmp_path):
    d = emu(12345)
    out = tmp_path / "out"
    out.mkdir()
    victim = tmp_path / "victim"
    victim.write_bytes(d.data_file.read_bytes())  # even the same bytes: a link is not a copy
    (out / "AX3-12345_1.cwa").symlink_to(victim)
    r = run_download(DownloadJob(12345, 1, str(d.data_file), str(out), pipeline=False))
    assert not r.ok and "already exists" in r.reason
    assert (out / "AX3-12345_1.cwa").is_symlink()


def test_a_ledger_that_is_a_link_is_refused(tmp_path):
    elsewhere = tmp_path / "elsewhere.sqlite"
    out = tmp_path / "out"
    out.mkdir()
    (out / "stillpoint-ledger.sqlite").symlink_to(elsewhere)
    with pytest.raises(LedgerError, match="symbolic link"):
        Ledger(out)
    with pytest.raises(LedgerError, match="symbolic link"):
        acquire_station_lock(out)
    assert not elsewhere.exists()


def test_a_ledger_from_before_device_types_still_finds_its_downloads(tmp_path):
    """Rows written before the device type column (and their old names, ``<id>_<session>.cwa``)
    are still found, for either device type; rows with a type only for their own."""
    db = sqlite3.connect(tmp_path / "stillpoint-ledger.sqlite")
    db.executescript(
        "CREATE TABLE downloads (id INTEGER PRIMARY KEY AUTOINCREMENT, device_id INTEGER NOT NULL, "
        "session_id INTEGER NOT NULL, state TEXT NOT NULL, bytes INTEGER, sha256 TEXT, verified "
        "INTEGER NOT NULL DEFAULT 0, started REAL, finished REAL, clock_offset_s REAL, host_tz "
        "TEXT, station_id TEXT, battery_pct INTEGER, bad_sectors INTEGER, cwa_path TEXT, mcap_path "
        "TEXT, reason TEXT, summary TEXT);")
    old = tmp_path / "10001_1.cwa"
    old.write_bytes(b"MD")
    db.execute("INSERT INTO downloads(device_id, session_id, state, verified, sha256, bytes, "
               "cwa_path) VALUES (10001, 1, 'verified', 1, 'aa', 2, ?)", (str(old),))
    db.commit()
    db.close()
    lg = Ledger(tmp_path)
    assert lg.verified_download(10001, 1, device_type="AX6").cwa_path == str(old)
    i = lg.download_started(10002, 1, device_type="AX3", cwa_path=str(old))
    lg.download_verified(i, bytes_=2, sha256="bb", bad_sectors=0, cwa_path=str(old), mcap_path=None)
    assert lg.verified_download(10002, 1, device_type="AX6") is None
    assert lg.verified_download(10002, 1, device_type="AX3").id == i


def test_devices_are_kept_per_type_also_in_an_older_ledger(tmp_path):
    """An AX3 and an AX6 with one id are two devices; a ledger whose devices table was keyed by
    the id alone is rebuilt keyed by id and type, its rows kept."""
    db = sqlite3.connect(tmp_path / "stillpoint-ledger.sqlite")
    db.executescript(
        "CREATE TABLE devices (device_id INTEGER PRIMARY KEY, device_type TEXT, serial TEXT, "
        "firmware INTEGER, slot TEXT, first_seen REAL, last_seen REAL);"
        "INSERT INTO devices VALUES (10001, 'AX3', 'CWA17_10001', 50, 'emu-1', 1.0, 2.0);")
    db.commit()
    db.close()
    lg = Ledger(tmp_path)
    lg.device_seen(10001, "AX6", "AX6_10001", 1, "emu-2")
    lg.device_seen(10001, "AX3", "CWA17_10001", 51, "emu-1")
    rows = lg.db.execute("SELECT device_id, device_type, serial, firmware, first_seen FROM devices "
                         "ORDER BY device_type").fetchall()
    assert rows[0] == (10001, "AX3", "CWA17_10001", 51, 1.0)
    assert rows[1][:4] == (10001, "AX6", "AX6_10001", 1) and len(rows) == 2
    lg.close()
    assert len(Ledger(tmp_path).db.execute("SELECT * FROM devices").fetchall()) == 2  # reopened
