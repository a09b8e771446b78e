"""Every emulated fault ends in a clear per-device state (ERROR with the reason in the ledger and
the table), never in a clear without a verified download, never a lost file, never stalling the
other devices."""

from __future__ import annotations

import io
import os

import pytest

from stillpoint.drivers.ax.discovery import EmulatedBackend
from stillpoint.engine.station.download import DownloadJob
from stillpoint.engine.station.flow import StationOptions
from stillpoint.engine.station.station import Station, table_lines
from stillpoint.engine.station.download import DownloadWorker

from station_fixtures import emu, runtime  # noqa: F401

CASES = {
    "unplug-mid-copy": "unplugged during the copy",
    "short-read": "short read",
    "io-error": "Input/output error",
    "hang": "stalled",
    "hang-before-clear": "not cleared: cannot re-read the data file",
    "bit-flip": None,  # a transient misread: read again, patched, verified and cleared
    "change-between-reads": "verification failed",
    "swap-before-clear": "not cleared",
    "id-mismatch": "ID names device",
    "session-mismatch": "session mismatch",
    "commit-no-remount": "did not come back",
    "locked": "Locked",
    "stream-left-running": None,  # handled: the stream is stopped and the device processed
}


def _station(tmp_path, **kw):
    out = tmp_path / "out"
    out.mkdir(exist_ok=True)
    kw = {"inline": True, "stall_s": 1.5, **kw}
    opts = StationOptions(str(out), clear_after_verify=True, remount_s=1.0, **kw)
    return out, Station(opts, EmulatedBackend(), tty=False, out=io.StringIO(), poll_s=0.1)


@pytest.mark.parametrize("fault", sorted(CASES))
def test_fault_ends_in_a_clear_state(emu, tmp_path, fault):
    bad = emu(10001, faults=(fault,))
    good = emu(10002)
    out, st = _station(tmp_path)
    with st:
        rc = st.run(once=True)
        flows = {f.att.device_id: f for f in st.flows.values()}
        text = st.out.getvalue()
        events = st.ledger.events(10001)
        verified = {(r.device_id, r.session_id, r.sha256) for r in st.ledger.downloads() if r.verified}
    # the healthy device beside it is never stalled and is cleared
    assert flows[10002].state == "cleared", flows[10002].reason
    assert (out / "AX3-10002_1.cwa").exists() and (out / "AX3-10002_1.mcap").exists()
    f = flows[10001]
    if CASES[fault] is None:
        assert f.state == "cleared" and rc == 0
    else:
        assert rc == 2
        assert f.state == "error" and CASES[fault] in f.reason
        assert events[-1][1] == "error" and CASES[fault] in events[-1][2]  # in the ledger
        assert "10001 [emu-1] error: " in text  # in the plain line log
        assert any(CASES[fault] in line for line in table_lines([f]))
    # a clear only ever follows a verified download of the same device, session and content
    for c in bad.clears + good.clears:
        assert c in verified
    if fault not in ("stream-left-running", "commit-no-remount", "locked", "swap-before-clear",
                     "bit-flip"):
        assert bad.clears == []
    # nothing is lost: either the verified copy or the partial copy is there
    names = os.listdir(out)
    assert any(n.startswith("AX3-10001_") for n in names) or fault in ("id-mismatch", "session-mismatch")


def test_hung_read_is_cancelled_in_bounded_time(emu, tmp_path):
    """A read stuck on the device (the worker process never returns) is stopped by the stall
    bound; the partial copy stays."""
    import time
    d = emu(12345, faults=("hang",))
    job = DownloadJob(12345, 1, str(d.data_file), str(tmp_path), faults=("hang",),
                      control=str(d.control), pipeline=False)
    t0 = time.monotonic()
    w = DownloadWorker(job, stall_s=2.0).start()
    r = w.wait()
    assert not r.ok and "stalled" in r.reason
    assert time.monotonic() - t0 < 20
    assert not w._proc.is_alive()
    assert (tmp_path / "AX3-12345_1.cwa.part").stat().st_size > 0


def test_a_hung_reread_before_the_clear_ends_the_device_in_error(emu, tmp_path):
    """The re-read of the device just before its clear runs in a worker with the stall bound: a
    read that hangs there (a pulled drive) ends the device in error, not cleared, its verified copy
    kept, and the worker process is gone; the station is never hung."""
    import multiprocessing
    import time
    bad = emu(10001, faults=("hang-before-clear",))
    out, st = _station(tmp_path, inline=False, stall_s=8.0)  # a worker process starts within 8 s
    t0 = time.monotonic()
    with st:
        rc = st.run(once=True)
        f = next(iter(st.flows.values()))
        verified = [r for r in st.ledger.downloads(10001) if r.verified]
        clears = st.ledger.clears()
    assert time.monotonic() - t0 < 90
    assert rc == 2 and f.state == "error"
    assert f.reason.startswith("not cleared: cannot re-read the data file") and \
        "stalled: no progress for 8 s" in f.reason, f.reason
    assert bad.clears == [] and clears == []
    assert len(verified) == 1 and (out / "AX3-10001_1.cwa").exists()
    assert multiprocessing.active_children() == []


def test_worker_process_download_ok(emu, tmp_path):
    d = emu(12345)
    job = DownloadJob(12345, 1, str(d.data_file), str(tmp_path))
    w = DownloadWorker(job, stall_s=30).start()
    r = w.wait()
    assert r.ok, r.reason
    assert w.peak_rss_mb and w.peak_rss_mb < 300
    assert (tmp_path / "AX3-12345_1.unverified.mcap").exists() and r.mcap_part


def test_unplugged_download_resumes_when_the_device_returns(emu, tmp_path):
    emu(10001, faults=("unplug-mid-copy",), replug_s=0.5)
    out, st = _station(tmp_path)
    import threading
    import time
    stop = threading.Event()
    with st:
        th = threading.Thread(target=st.run, kwargs={"stop": stop})
        th.start()
        end = time.monotonic() + 30
        while time.monotonic() < end and not (
                (out / "AX3-10001_1.cwa").exists()
                and [e[1] for e in st.ledger.events(10001)][-1:] == ["cleared"]):
            time.sleep(0.1)
        stop.set()
        th.join(10)
        states = [e[1] for e in st.ledger.events(10001)]
        dls = st.ledger.downloads(10001)
    assert "error" in states and states[-1] == "cleared"
    assert [r.state for r in dls] == ["error", "verified"]
    assert (out / "AX3-10001_1.cwa").read_bytes()[:2] == b"MD"


def test_a_blocked_discovery_never_stalls_the_loop(tmp_path, runtime):
    import threading
    import time
    release = threading.Event()

    class Stuck:  # a stat on a pulled drive blocked in the kernel
        def ports(self):
            return []

        def volumes(self):
            release.wait(10)
            return []

    out = tmp_path / "out"
    out.mkdir()
    st = Station(StationOptions(str(out)), Stuck(), tty=False, out=io.StringIO())
    try:
        t0 = time.monotonic()
        assert st._discover(bound_s=0.2) is None
        assert st._discover(bound_s=0.2) is None  # the same pass, not a second blocked one
        assert time.monotonic() - t0 < 2
        release.set()
        assert st._discover(bound_s=2) == []
    finally:
        release.set()
        st.close()


def test_pipeline_finishing_after_the_last_read_is_not_a_stall(tmp_path):
    """After the copy and the verification read, the pipeline may need minutes on a week-long
    file; its heartbeat keeps the worker alive, while a frozen byte count does not."""
    import time
    job = DownloadJob(1, 1, str(tmp_path / "x"), str(tmp_path))
    w = DownloadWorker(job, stall_s=0.3, inline=True)  # not started: messages fed by hand
    for _ in range(5):
        w._q.put(("progress", "finishing", 100, 100))
        time.sleep(0.12)
        w.poll()
    assert w.result is None
    w._q.put(("progress", "copy", 50, 100))
    w.poll()
    time.sleep(0.4)
    w._q.put(("progress", "copy", 50, 100))  # the same count again: no progress
    w.poll()
    assert w.result is not None and "stalled" in w.result.reason


_ORPHAN_SCRIPT = """
import os, sys, time
from pathlib import Path
from stillpoint.drivers.ax.emulator import EmulatedDevice
from stillpoint.engine.sim.record import device_recording
from stillpoint.engine.station.download import DownloadJob
from stillpoint.engine.station.download import DownloadWorker
if __name__ == "__main__":
    w = Path(sys.argv[1])
    d = EmulatedDevice(w / "dev", 12345, faults=("hang",), make_recording=device_recording, days=0.01)
    d.plug()
    (w / "out").mkdir()
    job = DownloadJob(12345, 1, str(d.data_file), str(w / "out"), faults=("hang",),
                      control=str(d.control), pipeline=False)
    wk = DownloadWorker(job).start()
    while not (w / "out" / "AX3-12345_1.cwa.part").exists():
        time.sleep(0.05)
    (w / "pid").write_text(str(wk._proc.pid))
    os._exit(0)  # the station dies without stopping its worker
"""


# for the processes of one test: no parent-death signal (as on a system without prctl), so the
# worker's lifeline pipe alone must end it
_NO_PRCTL = """
import ctypes
_CDLL = ctypes.CDLL
def _no_libc(name, *a, **k):
    if name is None:
        raise OSError("no prctl on this system")
    return _CDLL(name, *a, **k)
ctypes.CDLL = _no_libc
"""


@pytest.mark.parametrize("means", ["prctl and lifeline", "lifeline only"])
def test_a_worker_never_outlives_its_station(tmp_path, runtime, monkeypatch, means):
    """A station that dies (here: exits without a word to its worker, whose read hangs) takes its
    download worker with it: nothing renames or writes after the station is gone."""
    import subprocess
    import sys
    import time
    script = tmp_path / "station.py"
    script.write_text(_ORPHAN_SCRIPT)
    if means == "lifeline only":
        (tmp_path / "site").mkdir()
        (tmp_path / "site" / "sitecustomize.py").write_text(_NO_PRCTL)
        monkeypatch.setenv("PYTHONPATH", str(tmp_path / "site"))
    subprocess.run([sys.executable, str(script), str(tmp_path)], timeout=60, check=True,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    pid = int((tmp_path / "pid").read_text())

    def alive():
        try:
            with open(f"/proc/{pid}/stat") as f:
                return f.read().rsplit(")", 1)[1].split()[0] != "Z"
        except OSError:
            return False
    end = time.monotonic() + 2.0
    while alive() and time.monotonic() < end:
        time.sleep(0.05)
    still = alive()
    if still:
        os.kill(pid, 9)
    assert not still, "the download worker outlived its station"
