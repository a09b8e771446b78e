"""Benchmark: what the web dashboard adds to the CPU of a station with four devices.

`stillpoint device emulate --count 4` runs in its own process (emulated devices serve their data
at --read-mbps, USB full speed by default); this process runs `station --once
--clear-after-verify` on them (downloads in worker processes, as the command does) with the
dashboard, one browser-like client on the live stream (a `curl -N` process reading /events) and
one opening a device page and a handover sheet every 5 s (another process).

The dashboard's own CPU is measured where it is spent: the station listener (``LiveDock.on_change``,
on the flows' threads) and every request thread of the server, each timed with the thread's CPU
clock (``time.thread_time``). The station's CPU is this process's plus its worker processes'
(``getrusage``). Printed: both, and the dashboard's share. Target: at most 2 %.

    python tools/benchmarks/bench_dashboard.py [--days 0.05] [--read-mbps 1.2] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

POLLER = r"""
import sys, time, urllib.request
base = sys.argv[1]
while True:
    for path in ("device/AX3-20001", "device/AX3-20002/sheet"):
        try:
            urllib.request.urlopen(base + path, timeout=5).read()
        except OSError:
            pass
    time.sleep(5.0)
"""


def _cpu() -> float:
    s, c = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return s.ru_utime + s.ru_stime + c.ru_utime + c.ru_stime


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--days", type=float, default=0.05, help="recording per device (0.05: ~1.9 MB)")
    ap.add_argument("--read-mbps", type=float, default=1.2, help="emulated USB read speed")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)

    from stillpoint.engine.station.flow import StationOptions
    from stillpoint.engine.station.station import Station
    from stillpoint.engine.station.web import Dashboard, live, server

    spent = {"listener": 0.0, "requests": 0.0}
    lock = threading.Lock()

    def timed(fn, what):
        def run(*a, **k):
            t0 = time.thread_time()
            try:
                return fn(*a, **k)
            finally:
                with lock:
                    spent[what] += time.thread_time() - t0
        return run
    live.LiveDock.on_change = timed(live.LiveDock.on_change, "listener")
    for name in ("do_GET", "do_POST"):
        setattr(server._Handler, name, timed(getattr(server._Handler, name), "requests"))

    work = Path(tempfile.mkdtemp(prefix="bench-dashboard-"))
    env = dict(os.environ, STILLPOINT_RUNTIME_DIR=str(work / "runtime"), PYTHONUNBUFFERED="1")
    os.environ["STILLPOINT_RUNTIME_DIR"] = env["STILLPOINT_RUNTIME_DIR"]
    procs = []
    try:
        emu = subprocess.Popen([sys.executable, "-m", "stillpoint", "device", "emulate", "--count",
                                "4", "--first-id", "20001", "--days", str(args.days), "--read-mbps",
                                str(args.read_mbps), "--dir", str(work / "emu")], env=env,
                               stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                               start_new_session=True)
        procs.append(emu)
        for line in emu.stdout:
            if re.search(r"4 emulated device\(s\) attached", line):
                break
        threading.Thread(target=lambda: [None for _ in emu.stdout], daemon=True).start()
        out = work / "out"
        out.mkdir()
        st = Station(StationOptions(str(out), clear_after_verify=True), tty=False,
                     out=open(os.devnull, "w"))
        dash = Dashboard(out, st)
        url = dash.start()
        curl = shutil.which("curl")
        sse = [curl, "-sN", url + "events"] if curl else \
            [sys.executable, "-c", "import sys,urllib.request\nfor _ in urllib.request.urlopen("
             "sys.argv[1]): pass", url + "events"]
        procs.append(subprocess.Popen(sse, stdout=subprocess.DEVNULL, start_new_session=True))
        procs.append(subprocess.Popen([sys.executable, "-c", POLLER, url],
                                      start_new_session=True))
        time.sleep(0.5)
        c0, w0 = _cpu(), time.monotonic()
        with lock:
            spent.update(listener=0.0, requests=0.0)
        rc = st.run(once=True)
        c1, w1 = _cpu(), time.monotonic()
        dash.close()  # the live stream's request ends: its thread's CPU is counted
        time.sleep(1.0)
        with lock:
            dash_cpu = spent["listener"] + spent["requests"]
            parts = dict(spent)
        st.close()
    finally:
        for p in procs:
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGINT if p is procs[0] else signal.SIGTERM)
                try:
                    p.wait(15)
                except subprocess.TimeoutExpired:
                    os.killpg(p.pid, signal.SIGKILL)
        shutil.rmtree(work, ignore_errors=True)
    station_cpu = c1 - c0
    res = {"devices": 4, "days": args.days, "read_mbps": args.read_mbps, "exit_code": rc,
           "wall_s": round(w1 - w0, 2), "station_cpu_s": round(station_cpu, 3),
           "dashboard_cpu_s": round(dash_cpu, 4),
           "dashboard_listener_cpu_s": round(parts["listener"], 4),
           "dashboard_requests_cpu_s": round(parts["requests"], 4),
           "dashboard_share_pct": round(100.0 * dash_cpu / station_cpu, 2) if station_cpu else None}
    if args.json:
        print(json.dumps(res))
    else:
        print(f"4 devices, {args.days:g} days each at {args.read_mbps:g} MB/s: station {w1 - w0:.1f} s "
              f"wall, {station_cpu:.2f} s CPU (exit {rc}); dashboard {dash_cpu:.3f} s CPU "
              f"(listener {parts['listener']:.3f}, requests {parts['requests']:.3f}) = "
              f"{res['dashboard_share_pct']} % of the station's (target <= 2 %)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
