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

from station_fixtures import emu, runtime, wait_for  # noqa: F401


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
    try:  # the option that appended over old data is gone: a usage error
        rc = main(["device", "configure", "10001", "--profile", str(prof), "--allow-data"])
    except SystemExit as e:
        rc = e.code
    assert rc == 2 and _sha(d.data_file) == before


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
    assert lg.clears(7, "AX6") == lg.clears(7, "AX3") == lg.clears()  # no type: either device type
    cid = lg.clear_attempt(7, 2, 2, "cd", erase="FORMAT QC")
    lg.clear_result(cid, "ok", None, "1024 bytes")
    assert lg.clears()[-1] == (7, 2, 2, "cd", "ok", None, "FORMAT QC", "1024 bytes")


# ----------------------------------------------------------------------------- identity as written
def _v50(header: bytes) -> bytes:
    """The header as AX3 firmware V50 writes it: low 16 bits of the id, upper word erased."""
    b = bytearray(header)
    b[11:13] = b"\xff\xff"
    return bytes(b)


def test_header_identity_as_each_firmware_writes_it():
    from stillpoint.drivers.ax.identity import header_names_device
    from stillpoint.drivers.cwa_layout import build_header
    ax3 = parse_header(_v50(build_header(hardware_type=0x00, device_id=123456, session_id=1,
                                         rate_code=74, firmware=50)))
    assert ax3["device_id"] == 123456 & 0xFFFF  # what a plain reading of the id gives
    assert header_names_device(ax3, 123456, "AX3")
    assert not header_names_device(ax3, 123456, "AX6")
    assert not header_names_device(ax3, 123457, "AX3")
    ax6 = parse_header(build_header(hardware_type=0x64, device_id=123456, session_id=1,
                                    rate_code=74, firmware=56))
    assert header_names_device(ax6, 123456, "AX6")
    assert not header_names_device(ax6, 123456 & 0xFFFF, "AX6")
    ax6_erased_upper = parse_header(_v50(build_header(hardware_type=0x64, device_id=123456,
                                                      session_id=1, rate_code=74, firmware=56)))
    assert not header_names_device(ax6_erased_upper, 123456, "AX6")  # the AX6 writes both words


def test_ax3_with_a_wide_id_is_downloaded_and_cleared(emu, tmp_path):
    """An AX3 with id > 65535 whose header holds only the low 16 bits (firmware V50): the station
    downloads it, the clear rule accepts it, and the erase happens."""
    d = emu(123456)
    data = bytearray(d.data_file.read_bytes())
    data[:1024] = _v50(bytes(data[:1024]))
    d.data_file.write_bytes(bytes(data))
    sha = hashlib.sha256(bytes(data)).hexdigest()
    out = tmp_path / "out"
    out.mkdir()
    rc, flows = _run_station(out, clear_after_verify=True)
    f = flows[123456]
    assert rc == 0 and f.state == "cleared", f.reason
    assert [c[2] for c in d.clears] == [sha]
    lg = Ledger(out)
    rec = [r for r in lg.downloads() if r.verified][-1]
    assert rec.sha256 == sha and _sha(__import__("pathlib").Path(rec.cwa_path)) == sha


# ----------------------------------------------------------------------------- the campaign's recipes
def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


def test_truncated_copy_then_verify_and_clear_are_refused(emu, tmp_path, capsys):
    """Recipe: download, truncate the raw copy to 1024 bytes, then `device verify` and `device
    clear`: verify reports the copy no longer matches, clear is refused, the device keeps its data."""
    from stillpoint.tools.cli import main
    d = emu(10001)
    before = _sha(d.data_file)
    out = tmp_path / "out"
    out.mkdir()
    assert main(["device", "download", "10001", "-o", str(out)]) == 0
    capsys.readouterr()
    [copy] = list(out.glob("*.cwa"))
    with open(copy, "r+b") as f:
        f.truncate(1024)
    assert main(["device", "verify", "10001", "-o", str(out)]) == 2
    line = _one_line_error(capsys)
    assert f"the raw copy {copy} (1024 bytes" in line and "differs from the ledger's" in line
    assert main(["device", "clear", "10001", "-o", str(out)]) == 2
    line = _one_line_error(capsys)
    assert "not cleared: the raw copy" in line
    assert d.clears == [] and _sha(d.data_file) == before


def test_device_bit_flipped_after_download_is_not_cleared_by_the_station(emu, tmp_path, capsys):
    """Recipe: download, flip one bit of the device's file (same size), then `station --once
    --clear-after-verify`: the "already downloaded" path goes through the byte rule and the
    device is not cleared; `device verify` names the device file as the one that differs."""
    from stillpoint.tools.cli import main
    d = emu(10001)
    out = tmp_path / "out"
    out.mkdir()
    assert main(["device", "download", "10001", "-o", str(out)]) == 0
    with open(d.data_file, "r+b") as f:
        f.seek(20000)
        b = f.read(1)
        f.seek(20000)
        f.write(bytes([b[0] ^ 0x02]))
    flipped = _sha(d.data_file)
    capsys.readouterr()
    assert main(["station", str(out), "--once", "--clear-after-verify", "--plain"]) == 2
    text = capsys.readouterr()
    assert "not cleared: the device's data file" in text.out + text.err
    assert d.clears == [] and _sha(d.data_file) == flipped
    assert main(["device", "verify", "10001", "-o", str(out)]) == 2
    assert "the device file" in _one_line_error(capsys)


def test_station_refuses_a_profile_for_another_type_before_clearing(emu, tmp_path):
    """The profile is for AX6s (gyro on): an AX3 is downloaded but neither cleared nor configured."""
    d = emu(10001)
    prof_path = tmp_path / "ax6.toml"
    prof_path.write_text('[device]\nrate_hz = 100\ngyro_dps = 500\n')
    out = tmp_path / "out"
    out.mkdir()
    rc, flows = _run_station(out, load_profile(prof_path), clear_after_verify=True,
                             configure_after=True)
    f = flows[10001]
    assert rc == 2 and f.state == "error" and "cannot configure an AX3" in f.reason
    assert d.clears == [] and d.data_file.stat().st_size > 1024


def test_station_erase_option_wipes(emu, tmp_path):
    from stillpoint.tools.cli import main
    d = emu(10001)
    out = tmp_path / "out"
    out.mkdir()  # the station never creates its output folder
    assert main(["station", str(out), "--once", "--clear-after-verify", "--erase", "wipe",
                 "--plain"]) == 0
    assert len(d.clears) == 1
    lg = Ledger(out)
    assert lg.clears()[-1][4] == "ok" and lg.clears()[-1][6] == "FORMAT WC"


def test_a_verified_ax6_does_not_clear_an_ax3_with_the_same_id(emu, tmp_path):
    ax6 = emu(10001, "AX6", plug=False)
    lg = _ledger(tmp_path)
    copy = tmp_path / "out" / "AX6-10001_1.cwa"
    shutil.copyfile(ax6.data_file, copy)
    dl = lg.download_started(10001, 1, device_type="AX6")
    lg.download_verified(dl, bytes_=copy.stat().st_size, sha256=_sha(copy), bad_sectors=0,
                         cwa_path=str(copy), mcap_path="")
    ax3 = emu(10001, "AX3")
    with AxClient.open(f"axemu://{ax3.serial}") as c:
        with pytest.raises(ClearRefused, match="no verified download"):
            clear_verified(c, lg, 10001, 1, ax3.data_file, wait_for(ax3), device_type="AX3")
    assert ax3.clears == []


def test_clears_and_the_device_list_keep_an_ax3_and_an_ax6_with_one_id_apart(emu, tmp_path):
    """The AX6's clear left at 'sent' is not settled from an AX3 with the same id, its erased
    session does not count for the AX3's "increment", and `stillpoint devices` does not show the
    AX3 as verified because the AX6 of that id and session is."""
    from stillpoint.drivers.ax.discovery import EmulatedBackend
    from stillpoint.engine.station.clearing import session_before_clear
    from stillpoint.engine.station.completion import resolve_sent_clear
    from stillpoint.engine.station.status import list_devices
    lg = _ledger(tmp_path)
    copy = tmp_path / "out" / "AX6-10001_1.cwa"
    copy.write_bytes(b"MD" * 600)  # the AX6's verified copy (not plugged in)
    dl = lg.download_started(10001, 1, device_type="AX6")
    lg.download_verified(dl, bytes_=copy.stat().st_size, sha256=_sha(copy), bad_sectors=0,
                         cwa_path=str(copy), mcap_path="")
    lg.clear_result(lg.clear_attempt(10001, 41, dl, "aa", device_type="AX6"), "ok")
    sent = lg.clear_attempt(10001, 1, dl, _sha(copy), device_type="AX6")
    ax3 = emu(10001, "AX3")
    assert resolve_sent_clear(lg, 10001, ax3.data_file, device_type="AX3") == []
    assert lg.sent_clears(10001, "AX6")[0][0] == sent
    assert session_before_clear(lg, 10001, 1, "AX3") == 1
    assert session_before_clear(lg, 10001, 1, "AX6") == 41
    rows = list_devices(EmulatedBackend(), ledger=lg)
    assert [(r["type"], r["state"]) for r in rows] == [("AX3", "has data (recording window still open)")]


def test_increment_counts_from_the_erased_session_on_a_later_run(emu, tmp_path):
    """Run 1 clears (the device is left at session 0); run 2 finds it empty and configures it:
    "increment" gives the erased session + 1, not 1."""
    d = emu(10001, session_id=41)
    out = tmp_path / "out"
    out.mkdir()
    rc, flows = _run_station(out, clear_after_verify=True)
    assert rc == 0 and flows[10001].state == "cleared" and d.session_id == 0
    prof_path = tmp_path / "study.toml"
    prof_path.write_text('[device]\nrate_hz = 50\nsession = "increment"\n')
    rc, flows = _run_station(out, load_profile(prof_path), configure_after=True)
    assert rc == 0 and flows[10001].state == "configured", flows[10001].reason
    assert _header(d)["session_id"] == 42
    lg = Ledger(out)
    assert lg.db.execute("SELECT device_id, device_type, session_id, result FROM "
                         "configurations").fetchall() == [(10001, "AX3", 42, "ok")]
    lg.close()


def test_a_read_back_that_hangs_after_the_erase_is_an_error_not_a_hang(emu, tmp_path, monkeypatch):
    """The drive is pulled just after the erase: the read-back of the new header hangs. It runs
    with the stall bound, so the clear ends in error (recorded), and the caller is not hung."""
    import threading
    import time

    from stillpoint.engine.station import clearing, device_read

    d = emu(12345)
    lg = _ledger(tmp_path)
    _, sha = verified_copy(d, tmp_path / "out", lg)
    release = threading.Event()
    real_read = device_read.read_device

    def hangs_after_the_erase(path, **kw):
        if d.clears:  # the erase has happened: this is the read-back
            release.wait(60)
            raise OSError(5, "released")
        return real_read(path, **kw)

    monkeypatch.setattr(device_read, "read_device", hangs_after_the_erase)
    monkeypatch.setattr(clearing, "DEFAULT_STALL_S", 1.0)
    t0 = time.monotonic()
    try:
        with AxClient.open(f"axemu://{d.serial}") as c:
            with pytest.raises(DeviceError) as e:
                clear_verified(c, lg, 12345, 1, d.data_file, wait_for(d),
                               reread=lambda p: real_read(p))
    finally:
        release.set()
    assert time.monotonic() - t0 < 30
    assert "clear did not complete" in str(e.value) and "stalled" in str(e.value), str(e.value)
    assert d.clears == [(12345, 1, sha)]  # erased; the outcome is recorded as not confirmed
    assert lg.clears()[-1][4] == "error"
