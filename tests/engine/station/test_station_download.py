"""The verified download: copy + hash + online pipeline, verification, resume, faults."""

from __future__ import annotations

import hashlib
import os
import time

import pytest

from stillpoint.engine.station.download import DownloadJob, run_download

from station_fixtures import emu, runtime  # noqa: F401


def _job(d, out, **kw):
    return DownloadJob(d.device_id, d.session_id, str(d.data_file), str(out), d.kind,
                       tuple(sorted(d.faults)), str(d.control), **kw)


def _complete(r, out):
    """What the station does with a verified result: the ledger completes it."""
    from stillpoint.engine.station.completion import complete
    from stillpoint.engine.station.ledger import Ledger
    led = Ledger(out)
    try:
        i = led.download_started(1, 1, cwa_path=r.cwa_path, mcap_path=r.mcap_path)
        complete(led, i, cwa_path=r.cwa_path, mcap_path=r.mcap_path, sha256=r.sha256,
                 bytes_=r.bytes, bad_sectors=r.bad_sectors, with_log=r.mcap_part is not None)
    finally:
        led.close()


def test_download_verified_with_mcap(emu, tmp_path):
    d = emu(12345)
    out = tmp_path / "out"
    out.mkdir()
    want = hashlib.sha256(d.data_file.read_bytes()).hexdigest()
    r = run_download(_job(d, out, metadata={"station": {"clock_offset_s": "2.5", "station_id": "s1"}}))
    assert r.ok, r.reason
    assert r.sha256 == want and r.bytes == d.data_file.stat().st_size and r.bad_sectors == 0
    # the download never gives a file its final name: the ledger's completion does
    assert sorted(os.listdir(out)) == ["AX3-12345_1.cwa.part", "AX3-12345_1.unverified.mcap"]
    _complete(r, out)
    assert sorted(n for n in os.listdir(out) if not n.startswith("stillpoint-ledger")) == \
        ["AX3-12345_1.cwa", "AX3-12345_1.mcap"]
    assert hashlib.sha256((out / "AX3-12345_1.cwa").read_bytes()).hexdigest() == want
    # the MCAP is complete and readable by the mcap package, with the station's metadata
    from mcap.reader import make_reader
    with open(out / "AX3-12345_1.mcap", "rb") as f:
        reader = make_reader(f)
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
        topics = {ch.topic for _, ch, _ in reader.iter_messages()}
    assert meta["station"]["clock_offset_s"] == "2.5"
    assert {"/raw/accel", "/corrected/accel", "/metrics/epoch"} <= topics
    assert r.summary["samples"] > 0 and r.mcap_after_copy_s is not None


def test_existing_copy_is_never_overwritten(emu, tmp_path):
    d = emu(12345)
    (tmp_path / "AX3-12345_1.cwa").write_bytes(b"keep me")
    r = run_download(_job(d, tmp_path))
    assert not r.ok and "already exists" in r.reason
    assert (tmp_path / "AX3-12345_1.cwa").read_bytes() == b"keep me"


def test_unplug_then_resume_from_verified_prefix(emu, tmp_path):
    d = emu(12345, faults=("unplug-mid-copy",))
    job = _job(d, tmp_path, chunk_bytes=64 * 1024)
    r = run_download(job)
    assert not r.ok and "unplugged" in r.reason
    part = tmp_path / "AX3-12345_1.cwa.part"
    kept = part.stat().st_size
    assert 0 < kept < r.size
    end = time.monotonic() + 5
    while not d.plugged and time.monotonic() < end:  # the emulator re-plugs the device
        time.sleep(0.05)
    assert d.plugged
    r2 = run_download(job)
    assert r2.ok, r2.reason
    assert r2.resumed_from == kept // 512 * 512 and r2.resumed_from > 0
    _complete(r2, tmp_path)
    assert hashlib.sha256((tmp_path / "AX3-12345_1.cwa").read_bytes()).hexdigest() == \
        hashlib.sha256(d.data_file.read_bytes()).hexdigest()


def test_resume_with_a_differing_prefix_starts_over_and_keeps_it(emu, tmp_path):
    d = emu(12345)
    (tmp_path / "AX3-12345_1.cwa.part").write_bytes(b"MD" + b"\x01" * 4094)
    r = run_download(_job(d, tmp_path))
    assert r.ok and r.resumed_from == 0
    asides = [p for p in os.listdir(tmp_path) if p.startswith("AX3-12345_1.cwa.part.")]
    assert len(asides) == 1  # the old partial copy is set aside, not deleted


@pytest.mark.parametrize("fault, reason", [
    ("short-read", "short read"),
    ("io-error", "Input/output error"),
    ("change-between-reads", "the device's data changed between the copy and the verification"),
])
def test_read_faults_keep_partial_and_never_finalise(emu, tmp_path, fault, reason):
    d = emu(12345, faults=(fault,))
    r = run_download(_job(d, tmp_path))
    assert not r.ok and reason in r.reason
    assert r.changed == (fault == "change-between-reads")  # never cleared automatically
    names = os.listdir(tmp_path)
    assert "AX3-12345_1.cwa" not in names and "AX3-12345_1.mcap" not in names
    assert "AX3-12345_1.cwa.part" in names and (tmp_path / "AX3-12345_1.cwa.part").stat().st_size > 0


def test_a_misread_range_is_read_again_and_patched(emu, tmp_path):
    """One bit flipped in the copy read (a transient read error): the differing range is read
    again, two reads agree, the copy's damaged sector fails its checks and the agreed one passes:
    the copy is patched, byte-identical to the device, and its corrected log rebuilt."""
    d = emu(12345, faults=("bit-flip",))
    want = d.data_file.read_bytes()
    r = run_download(_job(d, tmp_path, chunk_bytes=64 * 1024))
    assert r.ok, r.reason
    assert (r.reread_ranges, r.patched_ranges, r.bad_sectors) == (1, 1, 0)
    assert r.sha256 == hashlib.sha256(want).hexdigest()
    assert (tmp_path / "AX3-12345_1.cwa.part").read_bytes() == want
    _complete(r, tmp_path)
    assert (tmp_path / "AX3-12345_1.cwa").read_bytes() == want
    assert (tmp_path / "AX3-12345_1.mcap").exists()


def test_a_change_with_valid_sectors_is_not_a_misread(emu, tmp_path, monkeypatch):
    """Two reads agree on bytes other than the copy's, but the copy's sector was a valid one: the
    device's data changed (a device writes whole, valid sectors); nothing is patched."""
    import stillpoint.engine.station.device_read as device_read
    import stillpoint.engine.station.download as dl
    d = emu(12345)
    good = d.data_file.read_bytes()
    # the device now holds another valid recording's sector 20 (a rewrite, not damage)
    other = bytearray(good)
    s20 = 1024 + 20 * 512
    other[s20:s20 + 512] = good[s20 + 512:s20 + 1024]
    real = dl.open_data_file
    calls = {"n": 0}

    def later_reads_see_other(path, *, verify=False, faults=(), control=None):
        f = real(path, verify=verify, faults=faults, control=control)
        if verify:  # the verification read and the re-reads see the rewritten device
            calls["n"] += 1
            d.data_file.write_bytes(bytes(other))
        return f

    monkeypatch.setattr(dl, "open_data_file", later_reads_see_other)
    monkeypatch.setattr(device_read, "open_data_file", later_reads_see_other)
    r = run_download(_job(d, tmp_path, pipeline=False))
    assert not r.ok and r.changed and "complete sector in both reads" in r.reason
    assert (tmp_path / "AX3-12345_1.cwa.part").read_bytes() == good  # the copy is not patched


def test_session_mismatch_with_header_is_refused(emu, tmp_path):
    d = emu(12345)
    job = _job(d, tmp_path)
    job.session_id = 2  # what SESSION said; the header says 1
    r = run_download(job)
    assert not r.ok and "session mismatch" in r.reason
    assert not (tmp_path / "AX3-12345_2.cwa").exists()


def test_missing_output_folder_is_a_clear_error(emu, tmp_path):
    d = emu(12345)
    r = run_download(_job(d, tmp_path / "missing"))
    assert not r.ok and "cannot create" in r.reason and "folder does not exist" in r.reason


def test_bad_sectors_are_counted_not_blocking(emu, tmp_path):
    from stillpoint.drivers.cwa_writer import corrupt_sector
    d = emu(12345)
    corrupt_sector(d.data_file, 5, "checksum")
    corrupt_sector(d.data_file, 9, "checksum")
    r = run_download(_job(d, tmp_path))
    assert r.ok, r.reason
    assert r.bad_sectors == 2


def test_disk_full_stops_keeps_partial_and_touches_nothing(emu, tmp_path, monkeypatch):
    import errno
    import stillpoint.engine.station.download as dl
    d = emu(12345)
    before = hashlib.sha256(d.data_file.read_bytes()).hexdigest()
    real_write = os.write
    calls = {"n": 0}

    def full_after_two(fd, data):
        calls["n"] += 1
        if calls["n"] > 2:
            raise OSError(errno.ENOSPC, "No space left on device")
        return real_write(fd, data)

    monkeypatch.setattr(dl.os, "write", full_after_two)
    r = run_download(_job(d, tmp_path, chunk_bytes=64 * 1024))
    monkeypatch.undo()
    assert not r.ok and "no space left on device" in r.reason and "partial copy is kept" in r.reason
    assert (tmp_path / "AX3-12345_1.cwa.part").stat().st_size == 2 * 64 * 1024
    assert not (tmp_path / "AX3-12345_1.cwa").exists()
    assert hashlib.sha256(d.data_file.read_bytes()).hexdigest() == before and d.clears == []


def test_a_rerun_reuses_only_the_verified_prefix_of_a_damaged_partial_copy(emu, tmp_path):
    """A partial copy left by a failed run with one damaged byte in the middle: the next run keeps
    the bytes before the damage (compared with the device), sets the old copy aside whole, and
    copies the rest from the device again."""
    d = emu(12345)
    good = d.data_file.read_bytes()
    bad = bytearray(good)
    at = 1024 + 40 * 512 + 77
    bad[at] ^= 0x10
    (tmp_path / "AX3-12345_1.cwa.part").write_bytes(bytes(bad))
    r = run_download(_job(d, tmp_path, pipeline=False))
    assert r.ok, r.reason
    assert r.resumed_from == (at // 512) * 512 and r.reread_ranges == 0
    assert (tmp_path / "AX3-12345_1.cwa.part").read_bytes() == good
    assert r.set_aside and open(r.set_aside, "rb").read() == bytes(bad)  # kept, never deleted
