"""Property: random interleavings of unplug, crash (the station stopped at any moment and
restarted on the same folder), device swap and faults never produce a clear without a matching
verified record (same device id, session and SHA-256 of what was on the device, with the raw
copy on disk holding exactly that content)."""

from __future__ import annotations

import contextlib
import hashlib
import io
import tempfile
import threading
import time
from pathlib import Path

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from stillpoint.drivers.ax.discovery import EmulatedBackend
from stillpoint.drivers.ax.emulator import FAULTS, EmulatedDevice
from stillpoint.engine.sim.record import device_recording
from stillpoint.drivers.ax.registry import using_runtime_dir
from stillpoint.engine.station.flow import StationOptions
from stillpoint.engine.station.ledger import Ledger
from stillpoint.engine.station.station import Station

# the hangs: covered by the fault tests (each costs the stall bound)
FAULT_NAMES = sorted(set(FAULTS) - {"hang", "hang-before-clear"})

step = st.one_of(
    st.tuples(st.just("run"), st.integers(0, 1)),
    st.tuples(st.just("crash"), st.floats(0.0, 0.6)),
    st.tuples(st.just("unplug"), st.integers(0, 1)),
    st.tuples(st.just("plug"), st.integers(0, 1)),
    st.tuples(st.just("swap"), st.integers(0, 1)),
    st.tuples(st.just("fault"), st.integers(0, 1), st.sampled_from(FAULT_NAMES)),
)


def _station(out):
    opts = StationOptions(str(out), clear_after_verify=True, inline=True, stall_s=1.0, remount_s=0.5)
    return Station(opts, EmulatedBackend(), tty=False, out=io.StringIO(), poll_s=0.05)


@settings(max_examples=12, deadline=None, suppress_health_check=list(HealthCheck))
@given(st.lists(step, min_size=1, max_size=6))
def test_no_clear_without_matching_verified_record(steps):
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        in_runtime = contextlib.ExitStack()
        in_runtime.enter_context(using_runtime_dir(tmp / "runtime"))
        out = tmp / "out"
        out.mkdir()
        devs = [EmulatedDevice(tmp / f"d{i}", 10001 + i, make_recording=device_recording, days=0.005, remount_s=0.05, replug_s=0.2,
                               slot=f"emu-{i + 1}") for i in range(2)]
        try:
            for d in devs:
                d.plug()
            for s in steps:
                kind = s[0]
                if kind == "run":
                    with _station(out) as stn:
                        stn.run(once=True)
                elif kind == "crash":  # the station dies at an arbitrary moment
                    stn = _station(out)
                    stop = threading.Event()
                    th = threading.Thread(target=stn.run, kwargs={"stop": stop})
                    th.start()
                    time.sleep(s[1])
                    stop.set()
                    th.join(10)
                    stn.close()
                elif kind == "unplug" and devs[s[1]].plugged:
                    devs[s[1]].unplug()
                elif kind == "plug" and not devs[s[1]].plugged:
                    devs[s[1]].plug()
                elif kind == "swap" and devs[s[1]].plugged:
                    devs[s[1]]._swap()
                elif kind == "fault":
                    d = devs[s[1]]
                    d.faults.add(s[2])
                    d.locked = d.locked or s[2] == "locked"
                    if d.plugged:
                        d._register()
            with _station(out) as stn:  # a final pass, so clears happen whenever they may
                stn.run(once=True)
            lg = Ledger(out)
            verified = {(r.device_id, r.session_id, r.sha256): r for r in lg.downloads() if r.verified}
            for d in devs:
                for c in d.clears:
                    assert c in verified, f"clear {c} without a verified download; ledger {verified}"
                    copy = Path(verified[c].cwa_path)
                    assert hashlib.sha256(copy.read_bytes()).hexdigest() == c[2]
            lg.close()
        finally:
            for d in devs:
                d.shutdown()
            in_runtime.close()
