"""Benchmark: `stillpoint view` by log length: what a Foxglove WebSocket client receives, how fast,
and the server's peak RSS (must be flat as the log grows).

    python tools/benchmarks/live_view.py [--days 0.25,2] [--hz 100] [--speed 1000000] [--workdir DIR]

For each length: a recording simulated by engine/sim (AX3 packed, adult wrist), processed once
(`process`), then `stillpoint view LOG --port P --speed S` in its own process and a loopback client
(tests/live_client.py, the `websockets` package) that subscribes to every advertised channel and
reads until playback has ended and nothing more arrives. Printed per length: messages received and
in the log, wall time from subscription to the end, messages per second, the server's peak RSS
(VmHWM of its process, read before it is stopped). For the first length also the counts per
topic and one decoded message per schema. A client slower than the server loses the oldest
queued data messages (the SDK's per-client backlog): "received" then falls short of "in log".
Needs the test extra (foxglove-sdk, websockets) and Linux (/proc).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests"))  # the loopback client the tests use


def recording(wd: Path, days: float, hz: float) -> Path:
    p = wd / f"view_{days:g}d_{hz:g}hz.cwa"
    if not p.is_file():
        from stillpoint.engine.sim import simulate_recording
        tmp = p.with_name(p.stem + ".tmp.cwa")
        simulate_recording(tmp, days=days, hz=hz, seed=5, truth_path=False)
        os.replace(tmp, p)
    return p


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def peak_rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def decoded(channel: dict, payload: bytes) -> str:
    if channel["encoding"] == "json":
        return json.dumps(json.loads(payload))[:300]
    from stillpoint.engine.mcap.schemas import ALL_TYPES
    t = {x.name: x for x in ALL_TYPES}[channel["schemaName"]]
    d = t.decode(payload)
    show = {k: (v.tolist()[:3] + (["..."] if len(v) > 3 else []) if hasattr(v, "tolist") and
                getattr(v, "ndim", 0) else (v.item() if hasattr(v, "item") else v))
            for k, v in d.items()}
    return json.dumps(show, default=str)[:300]


def serve_and_read(log: Path, speed: float, show: bool) -> dict:
    from live_client import LiveClient
    from stillpoint.engine.mcap.stream import iter_messages
    want = Counter(t for t, _i, _m in iter_messages(log))
    port = free_port()
    proc = subprocess.Popen([sys.executable, "-m", "stillpoint.tools", "view", str(log), "--port",
                             str(port), "--speed", f"{speed:g}"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        end = time.monotonic() + 60
        while True:
            try:
                c = LiveClient(port)
                break
            except OSError:
                if time.monotonic() > end or proc.poll() is not None:
                    raise SystemExit(f"the server did not start: {proc.stderr.read()}") from None
                time.sleep(0.2)
        c.pump(10.0, until=lambda: len(c.channels) == len(want))
        c.subscribe()
        t0 = time.monotonic()
        c.pump(3600.0, until=lambda: any(s["status"] == "ended" for s in c.states))
        wall = time.monotonic() - t0
        n = -1
        while n != sum(len(v) for v in c.messages.values()):  # the data queued behind the end
            n = sum(len(v) for v in c.messages.values())
            c.pump(1.0)
        rss = peak_rss_mb(proc.pid)
        c.close()
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(30)
    if show:
        print(f"  command: stillpoint view {log.name} --port {port} --speed {speed:g}")
        print(f"  serverInfo capabilities: {c.server_info['capabilities']}")
        for topic, ch in sorted(c.topics().items()):
            got = c.messages.get(topic, [])
            print(f"  {topic:18s} {ch['encoding']:4s} {ch['schemaName']:32s} received {len(got):7d} "
                  f"of {want[topic]:7d}")
        seen = set()
        for topic, ch in sorted(c.topics().items()):
            if ch["schemaName"] in seen or not c.messages.get(topic):
                continue
            seen.add(ch["schemaName"])
            t, payload = c.messages[topic][0]
            print(f"  {ch['schemaName']} ({topic}, log time {t}): {decoded(ch, payload)}")
    return {"received": n, "in_log": sum(want.values()), "wall": wall, "rss_mb": rss}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--days", default="0.25,2")
    ap.add_argument("--hz", type=float, default=100.0)
    ap.add_argument("--speed", type=float, default=1e6)
    ap.add_argument("--workdir", default=os.path.join(tempfile.gettempdir(), "stillpoint_bench"))
    args = ap.parse_args(argv)
    wd = Path(args.workdir)
    wd.mkdir(parents=True, exist_ok=True)
    rows = []
    for k, d in enumerate(float(x) for x in args.days.split(",") if x.strip()):
        rec = recording(wd, d, args.hz)
        log = wd / f"view_{d:g}d.mcap"
        if not log.is_file():
            r = subprocess.run([sys.executable, "-m", "stillpoint.tools", "process", str(rec), "-o",
                                str(log), "-q"], capture_output=True, text=True)
            if r.returncode != 0:
                raise SystemExit(f"process failed: {r.stderr}")
        rows.append((d, log.stat().st_size / 1e6, serve_and_read(log, args.speed, show=k == 0)))
    print(f"{'days':>5s} {'MCAP MB':>8s} {'received':>9s} {'in log':>9s} {'wall s':>7s} "
          f"{'msg/s':>8s} {'server RSS MB':>13s}")
    for d, mb, r in rows:
        print(f"{d:5g} {mb:8.1f} {r['received']:9d} {r['in_log']:9d} {r['wall']:7.1f} "
              f"{r['received'] / max(r['wall'], 1e-9):8.0f} {r['rss_mb']:13.0f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
