"""The ledger (WAL, one transaction per state change, second station refused) and the clear rule."""

from __future__ import annotations

import sqlite3

import pytest

from stillpoint.drivers.ax.errors import DeviceError
from stillpoint.drivers.ax.protocol import AxClient
from stillpoint.engine.station.clearing import ClearRefused, clear_verified
from stillpoint.engine.station.download import DownloadJob, run_download
from stillpoint.engine.station.ledger import Ledger, LedgerError, acquire_station_lock

from station_fixtures import emu, runtime  # noqa: F401


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


def _wait(d):
    def w(timeout_s=5.0):
        import time
        end = time.monotonic() + timeout_s
        while not d.data_file.exists():  # the drive comes back after COMMIT/FORMAT
            if time.monotonic() > end:
                raise DeviceError(d.device_id, "the drive did not come back")
            time.sleep(0.02)
        return str(d.data_file)
    return w


def test_clear_refused_without_verified_download(emu, tmp_path):
    d = emu(12345)
    lg = Ledger(tmp_path)
    with AxClient.open(f"axemu://{d.serial}") as c:
        with pytest.raises(ClearRefused, match="no verified download"):
            clear_verified(c, lg, 12345, 1, d.data_file, _wait(d))
    assert d.clears == [] and lg.clears() == []


def test_clear_after_verification_and_readback(emu, tmp_path):
    d = emu(12345)
    lg = Ledger(tmp_path)
    r = _verified(d, tmp_path, lg)
    with AxClient.open(f"axemu://{d.serial}") as c:
        clear_verified(c, lg, 12345, 1, d.data_file, _wait(d))
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
            clear_verified(c, lg, 12345, 1, d.data_file, _wait(d))
    assert d.clears == []


def test_clear_refused_for_another_session(emu, tmp_path):
    d = emu(12345)
    lg = Ledger(tmp_path)
    _verified(d, tmp_path, lg)
    with AxClient.open(f"axemu://{d.serial}") as c:
        c.session(2)
        with pytest.raises(ClearRefused):
            clear_verified(c, lg, 12345, 2, d.data_file, _wait(d))
        with pytest.raises(ClearRefused, match="session is now 2"):
            clear_verified(c, lg, 12345, 1, d.data_file, _wait(d))
    assert d.clears == []
