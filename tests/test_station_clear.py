"""The clear: the vendor's procedure (never log, FORMAT QC/WC, read-back) and the byte rule (the
raw copy on disk and the device both hold the ledger's verified bytes, checked just before the
erase)."""

from __future__ import annotations

import hashlib
import io
import shutil
import sqlite3

import pytest

from stillpoint.drivers.ax.discovery import EmulatedBackend
from stillpoint.drivers.ax.errors import DeviceError
from stillpoint.drivers.ax.protocol import AxClient
from stillpoint.drivers.cwa_layout import parse_header
from stillpoint.engine.station.clearing import ClearRefused, clear_verified, says_never_record
from stillpoint.engine.station.flow import StationOptions
from stillpoint.engine.station.ledger import Ledger
from stillpoint.engine.station.profile import load_profile
from stillpoint.engine.station.station import Station

from station_fixtures import emu, runtime  # noqa: F401


def _sha(path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def verified_copy(d, out, lg):
    """A raw copy of the device's file in ``out`` and a verified ledger row for it (what a
    verified download leaves); returns (copy path, SHA-256)."""
    out.mkdir(exist_ok=True)
    copy = out / f"{d.kind}-{d.device_id}_{d.session_id}.cwa"
    shutil.copyfile(d.data_file, copy)
    sha = _sha(copy)
    dl = lg.download_started(d.device_id, d.session_id)
    lg.download_verified(dl, bytes_=copy.stat().st_size, sha256=sha, bad_sectors=0,
                         cwa_path=str(copy), mcap_path="")
    return copy, sha


def _ledger(tmp_path) -> Ledger:
    (tmp_path / "out").mkdir(exist_ok=True)
    return Ledger(tmp_path / "out")


def wait_for(d):
    def w():
        if not d.data_file.exists():
            raise DeviceError(d.device_id, "the drive did not come back")
        return str(d.data_file)
    return w


def _header(d) -> dict:
    return parse_header(d.data_file.read_bytes()[:1024])


def _sent(client) -> list[str]:
    return [x[2:] for x in client.log if x.startswith("> ")]


# ----------------------------------------------------------------------------- the vendor's clear
def test_clear_sets_never_log_then_formats_and_reads_back(emu, tmp_path):
    d = emu(12345)
    assert not says_never_record(_header(d))  # as recorded: start "always", stop "never"
    lg = _ledger(tmp_path)
    _, sha = verified_copy(d, tmp_path / "out", lg)
    with AxClient.open(f"axemu://{d.serial}") as c:
        clear_verified(c, lg, 12345, 1, d.data_file, wait_for(d))
        sent = _sent(c)
    i = sent.index("FORMAT QC")
    assert sent[i - 3:i] == ["HIBERNATE -1", "STOP -1", "SESSION 0"]  # never log, then the erase
    assert not any(s.startswith("CLEAR") for s in sent)
    assert d.clears == [(12345, 1, sha)]
    assert d.data_file.stat().st_size == 1024
    h = _header(d)
    assert says_never_record(h) and h["session_id"] == 0
    row = lg.clears()[-1]
    assert row[:5] == (12345, 1, 1, sha, "ok")
    assert row[6] == "FORMAT QC" and "HIBERNATE=-1 STOP=-1" in row[7] and "1024 bytes" in row[7]


def test_wipe_erase_level(emu, tmp_path):
    d = emu(12345)
    lg = _ledger(tmp_path)
    verified_copy(d, tmp_path / "out", lg)
    with AxClient.open(f"axemu://{d.serial}") as c:
        clear_verified(c, lg, 12345, 1, d.data_file, wait_for(d), erase="wipe")
        assert "FORMAT WC" in _sent(c)
    assert lg.clears()[-1][4:7] == ("ok", None, "FORMAT WC")


def _run_station(out, profile=None, **kw):
    opts = StationOptions(str(out), profile=profile, inline=True, stall_s=5.0, remount_s=2.0, **kw)
    with Station(opts, EmulatedBackend(), tty=False, out=io.StringIO(), poll_s=0.1) as st:
        rc = st.run(once=True)
        flows = {f.att.device_id: f for f in st.flows.values()}
    return rc, flows


def test_clear_then_failed_configure_leaves_a_header_that_never_records(emu, tmp_path):
    """The battery is below the profile's minimum: configure fails after the clear. The device
    must not record again when unplugged: its header says start >= stop."""
    d = emu(10001, battery_pct=60.0)
    prof_path = tmp_path / "study.toml"
    prof_path.write_text('[device]\nrate_hz = 50\nstart = "0"\nstop = "-1"\nmin_battery_pct = 80\n')
    out = tmp_path / "out"
    out.mkdir()
    rc, flows = _run_station(out, load_profile(prof_path), clear_after_verify=True,
                             configure_after=True)
    f = flows[10001]
    assert rc == 2 and f.state == "error" and "below the profile's minimum" in f.reason
    assert len(d.clears) == 1  # it was cleared, then configure failed
    h = _header(d)
    assert d.data_file.stat().st_size == 1024
    assert says_never_record(h), (h["logging_start"], h["logging_end"])
    assert d.settings["hibernate"] == "-1" and d.settings["stop"] == "-1"


def test_configure_refuses_a_device_holding_data(emu, tmp_path, capsys):
    """Appending a new recording over an old one is refused (no --allow-data)."""
    from stillpoint.tools.cli import main
    d = emu(10001)
    before = _sha(d.data_file)
    prof = tmp_path / "study.toml"
    prof.write_text('[device]\nrate_hz = 50\n')
    assert main(["device", "configure", "10001", "--profile", str(prof)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "still holds data" in err[0]
    assert _sha(d.data_file) == before
    assert main(["device", "configure", "10001", "--profile", str(prof), "--allow-data"]) == 2


# ----------------------------------------------------------------------------- the byte rule
def test_clear_refused_when_the_copy_was_truncated(emu, tmp_path):
    d = emu(12345)
    lg = _ledger(tmp_path)
    copy, _ = verified_copy(d, tmp_path / "out", lg)
    with open(copy, "r+b") as f:
        f.truncate(1024)
    with AxClient.open(f"axemu://{d.serial}") as c:
        with pytest.raises(ClearRefused, match="the raw copy .* is not the verified download"):
            clear_verified(c, lg, 12345, 1, d.data_file, wait_for(d))
        assert not any(s.startswith(("FORMAT", "HIBERNATE", "STOP", "SESSION 0")) for s in _sent(c))
    assert d.clears == [] and lg.clears() == []


def test_clear_refused_when_a_device_bit_changed(emu, tmp_path):
    d = emu(12345)
    lg = _ledger(tmp_path)
    verified_copy(d, tmp_path / "out", lg)
    with open(d.data_file, "r+b") as f:  # same size, one bit different
        f.seek(5000)
        b = f.read(1)
        f.seek(5000)
        f.write(bytes([b[0] ^ 0x01]))
    with AxClient.open(f"axemu://{d.serial}") as c:
        with pytest.raises(ClearRefused, match="the device's data file .* is not the verified copy"):
            clear_verified(c, lg, 12345, 1, d.data_file, wait_for(d))
    assert d.clears == []


def test_clear_refused_when_the_ledger_hash_is_not_the_bytes(emu, tmp_path):
    d = emu(12345)
    lg = _ledger(tmp_path)
    verified_copy(d, tmp_path / "out", lg)
    con = sqlite3.connect(lg.path)
    con.execute("UPDATE downloads SET sha256 = ?", ("0" * 64,))
    con.commit()
    con.close()
    with AxClient.open(f"axemu://{d.serial}") as c:
        with pytest.raises(ClearRefused, match="not cleared"):
            clear_verified(c, lg, 12345, 1, d.data_file, wait_for(d))
    assert d.clears == []


def test_old_ledger_gains_the_clear_columns(tmp_path):
    """A ledger written before the erase level and read-back were recorded opens and keeps its rows."""
    con = sqlite3.connect(tmp_path / "stillpoint-ledger.sqlite")
    con.executescript(
        "CREATE TABLE clears (id INTEGER PRIMARY KEY AUTOINCREMENT, device_id INTEGER NOT NULL, "
        "session_id INTEGER NOT NULL, download_id INTEGER, sha256 TEXT, time REAL, result TEXT, "
        "reason TEXT);"
        "INSERT INTO clears(device_id, session_id, download_id, sha256, time, result) "
        "VALUES (7, 1, 1, 'ab', 0, 'ok');")
    con.commit()
    con.close()
    lg = Ledger(tmp_path)
    assert lg.clears() == [(7, 1, 1, "ab", "ok", None, None, None)]
    cid = lg.clear_attempt(7, 2, 2, "cd", erase="FORMAT QC")
    lg.clear_result(cid, "ok", None, "1024 bytes")
    assert lg.clears()[-1] == (7, 2, 2, "cd", "ok", None, "FORMAT QC", "1024 bytes")
