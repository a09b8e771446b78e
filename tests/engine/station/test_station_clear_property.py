"""Property: whatever damage the raw copy, the device's data file and the ledger suffer after a
verified download, nothing is ever erased that is not in a verified copy on disk, and the
erase happens exactly when all three still agree."""

from __future__ import annotations

import hashlib
import shutil
import tempfile
from pathlib import Path

import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from stillpoint.drivers.ax.emulator import EmulatedDevice
from stillpoint.engine.sim.record import device_recording
from stillpoint.drivers.ax.protocol import AxClient
from stillpoint.engine.station.clearing import ClearRefused, clear_verified
from stillpoint.engine.station.ledger import Ledger

from station_fixtures import runtime, wait_for  # noqa: F401

DEVICE = 4321


def _sha(path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    """One short simulated AX3 recording of device 4321, session 1, copied onto every drive."""
    root = tmp_path_factory.mktemp("rec")
    d = EmulatedDevice(root / "sim", DEVICE, "AX3", make_recording=device_recording, days=0.003)
    rec = root / "rec.cwa"
    shutil.copyfile(d.data_file, rec)
    d.shutdown()
    return rec


def _flip(path: Path, at: int) -> None:
    with open(path, "r+b") as f:
        f.seek(at)
        b = f.read(1)
        f.seek(at)
        f.write(bytes([b[0] ^ 0x10]))


COPY = ("none", "truncate", "flip", "delete", "append")
DEVICE_FILE = ("none", "flip", "append", "truncate")
LEDGER = ("none", "sha256", "bytes")


@settings(max_examples=30, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(copy_damage=st.sampled_from(COPY), device_damage=st.sampled_from(DEVICE_FILE),
       ledger_damage=st.sampled_from(LEDGER), at=st.integers(0, 2**31))
@example(copy_damage="none", device_damage="none", ledger_damage="none", at=0)
@example(copy_damage="truncate", device_damage="none", ledger_damage="none", at=1024)
@example(copy_damage="none", device_damage="flip", ledger_damage="none", at=5000)
def test_nothing_is_erased_that_is_not_in_a_verified_copy(runtime, recording, copy_damage,
                                                          device_damage, ledger_damage, at):
    root = Path(tempfile.mkdtemp(prefix="clearprop-", dir=runtime.parent))
    d = EmulatedDevice(root / "dev", DEVICE, "AX3", recording=recording, remount_s=0.02)
    d.plug()
    out = root / "out"
    out.mkdir()
    lg = Ledger(out)
    try:
        copy = out / "AX3-4321_1.cwa"
        shutil.copyfile(d.data_file, copy)
        size = copy.stat().st_size
        dl = lg.download_started(DEVICE, 1)
        lg.download_verified(dl, bytes_=size, sha256=_sha(copy), bad_sectors=0, cwa_path=str(copy),
                             mcap_path="")
        # damage after the verification
        if copy_damage == "truncate":
            with open(copy, "r+b") as f:
                f.truncate(at % size)
        elif copy_damage == "flip":
            _flip(copy, at % size)
        elif copy_damage == "delete":
            copy.unlink()
        elif copy_damage == "append":
            with open(copy, "ab") as f:
                f.write(b"\0" * 512)
        if device_damage == "flip":
            _flip(d.data_file, 1024 + at % (size - 1024))
        elif device_damage == "append":
            with open(d.data_file, "ab") as f:
                f.write(b"\0" * 512)
        elif device_damage == "truncate":
            with open(d.data_file, "r+b") as f:
                f.truncate(size - 512)
        if ledger_damage != "none":
            col, val = ("sha256", "f" * 64) if ledger_damage == "sha256" else ("bytes", size + 512)
            lg.db.execute(f"UPDATE downloads SET {col} = ? WHERE id = ?", (val, dl))
        try:
            with AxClient.open(f"axemu://{d.serial}") as c:
                clear_verified(c, lg, DEVICE, 1, d.data_file, wait_for(d))
            erased = True
        except ClearRefused:
            erased = False
        # what was erased is in a verified copy on disk, byte for byte
        verified = {r.sha256: r for r in lg.downloads() if r.verified}
        for _, _, sha in d.clears:
            assert sha in verified, f"erased {sha[:12]} that no verified download holds"
            assert _sha(verified[sha].cwa_path) == sha, "erased content whose copy is not on disk"
        damaged = (copy_damage, device_damage, ledger_damage) != ("none", "none", "none")
        assert erased == (not damaged) and len(d.clears) == int(erased)
    finally:
        lg.close()
        d.shutdown()
        shutil.rmtree(root, ignore_errors=True)
