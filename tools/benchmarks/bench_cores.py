"""Benchmark `stillpoint process --mode batch` on two cores against one core (and an earlier
revision), full and lean logs, on the simulator's default wearer.

    python tools/benchmarks/bench_cores.py [--days 1,7] [--repeat 3] [--before REV]
                                           [--workdir DIR]

For each realistic recording (``benchlib.realistic_recording``: AX3 wrist, 100 Hz, seed 3) the
commands run in rounds, alternating (A B C .., A B C ..), each in a fresh child; per command the
least wall time and the least CPU time (user + system of the child and of its own child
process) over the rounds are kept separately, and the largest peak RSS:

* ``process`` (full log) and ``process --log lean`` as installed: on two cores the next block
  is decoded on a reader thread and the MCAP log framed, compressed and written by a child
  process (engine/mcap/sinkproc.py; inputs of ``tuning.SINK_PROCESS_MIN_BYTES`` or more);
* the same with ``STILLPOINT_SINK_PROCESS=0``: no child; the chunks compressed on a writer
  thread, the framing in the engine's thread (the default before the child process);
* the same with ``STILLPOINT_CORES=1``: no extra thread or process at all (one core);
* with ``--before REV``: the same two commands at that revision (``git archive`` of engine/,
  drivers/, tools/ into the workdir, first on PYTHONPATH, as bench_process.py --before).

The load average is printed before and after the rounds (the machine is shared: read CPU
first, and ratios measured in the same run). Then, once each, in-process: the CPU time of the
engine's threads (main, reader) and of the log's child process in a default full run, the peak
RSS of both, and a check that the default log and the one-core log of the same output path are
the same bytes.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from benchlib import measure, realistic_recording

# One batch run in-process with the CPU time of each thread (time.thread_time at its end).
THREAD_CPU = r"""
import json, sys, threading, time
cpu = {}
run = threading.Thread.run
def timed(self):
    try:
        run(self)
    finally:
        cpu[self.name] = cpu.get(self.name, 0.0) + time.thread_time()
threading.Thread.run = timed
from stillpoint.engine.run import RunSettings, process_file
t = time.perf_counter()
c = time.process_time()
s = process_file(sys.argv[1], sys.argv[2], RunSettings(mode="batch", log=sys.argv[3]))
cpu["main"] = time.thread_time()
import resource
ru = resource.getrusage(resource.RUSAGE_CHILDREN)
if ru.ru_utime + ru.ru_stime:
    cpu["log process"] = ru.ru_utime + ru.ru_stime
print(json.dumps({"wall": time.perf_counter() - t, "cpu": time.process_time() - c + ru.ru_utime
                  + ru.ru_stime, "threads": cpu, "rss": s["peak_rss_mb"]}))
"""


def before_env(workdir: Path, rev: str) -> tuple[dict, str]:
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from bench_process import before_tree
    bt = before_tree(workdir, rev)
    return bt["env"], bt["sha"]


def sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for b in iter(lambda: f.read(1 << 20), b""):
            h.update(b)
    return h.hexdigest()


def run_file(path: Path, wd: Path, repeat: int, before) -> dict:
    sp = [sys.executable, "-m", "stillpoint.tools", "process"]
    one = dict(os.environ, STILLPOINT_CORES="1")
    thread = dict(os.environ, STILLPOINT_SINK_PROCESS="0")

    def cmd(log, name):
        return sp + [path, "-o", wd / f"{name}.mcap", "--mode", "batch", "-q", "--log", log,
                     "--overwrite"]
    cmds = {"full2": (cmd("full", "full2"), None), "fullt": (cmd("full", "fullt"), thread),
            "full1": (cmd("full", "full1"), one),
            "lean2": (cmd("lean", "lean2"), None), "leant": (cmd("lean", "leant"), thread),
            "lean1": (cmd("lean", "lean1"), one)}
    if before:
        cmds["fullb"] = (cmd("full", "fullb"), before[0])
        cmds["leanb"] = (cmd("lean", "leanb"), before[0])
    runs: dict = {k: [] for k in cmds}
    load0 = os.getloadavg()
    for _ in range(max(1, repeat)):
        for k, (c, env) in cmds.items():
            r = measure(c, env)
            if r["rc"] != 0:
                raise SystemExit(f"{k} failed on {path}:\n{r['err']}")
            runs[k].append(r)
    res = {k: {"wall": min(r["wall"] for r in rs), "cpu": min(r["cpu"] for r in rs),
               "rss_mb": max(r["rss_mb"] for r in rs)} for k, rs in runs.items()}
    res["_load"] = (load0, os.getloadavg())
    res["_mb"] = {k: (wd / f"{k}.mcap").stat().st_size / 1e6 for k in cmds}
    for k in cmds:
        (wd / f"{k}.mcap").unlink()
    # the thread CPU of a two-core full run, in-process
    out = wd / "threads.mcap"
    t = subprocess.run([sys.executable, "-c", THREAD_CPU, str(path), str(out), "full"],
                       check=True, stdout=subprocess.PIPE, text=True).stdout
    res["_threads"] = json.loads(t.strip().splitlines()[-1])
    # the same bytes on one core and on two (the same output path: the log names it)
    same = wd / "same.mcap"
    hashes = []
    for env in (None, one):
        subprocess.run(cmd("full", "same"), check=True, env=env)
        hashes.append(sha256(same))
    res["_identical"] = hashes[0] == hashes[1]
    same.unlink()
    out.unlink(missing_ok=True)
    return res


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--days", default="1,7", help="realistic file lengths, comma-separated")
    ap.add_argument("--rate", type=float, default=100.0)
    ap.add_argument("--repeat", type=int, default=3, help="rounds (least wall, least CPU kept)")
    ap.add_argument("--before", default="", help="also run the commands at this git revision")
    ap.add_argument("--workdir", default=os.path.join(tempfile.gettempdir(), "stillpoint_bench"))
    args = ap.parse_args(argv)
    wd = Path(args.workdir)
    wd.mkdir(parents=True, exist_ok=True)
    before = before_env(wd, args.before) if args.before else None
    print(f"{os.cpu_count()} cores; each figure the least of {max(1, args.repeat)} alternating "
          f"rounds (wall and CPU separately); wall / CPU in s, peak RSS in MB", flush=True)
    for d in [float(x) for x in args.days.split(",") if x.strip()]:
        path = realistic_recording(wd, d, args.rate)
        r = run_file(path, wd, args.repeat, before)
        (l0, l1) = r["_load"]
        print(f"\n{path.name} ({path.stat().st_size / 1e6:.0f} MB), load average "
              f"{l0[0]:.2f} before the rounds, {l1[0]:.2f} after")
        rows = [("full2", "process (full log), default"),
                ("fullt", "process (full log), STILLPOINT_SINK_PROCESS=0"),
                ("full1", "process (full log), STILLPOINT_CORES=1"),
                ("lean2", "process --log lean, default"),
                ("leant", "process --log lean, STILLPOINT_SINK_PROCESS=0"),
                ("lean1", "process --log lean, STILLPOINT_CORES=1")]
        if before:
            rows += [("fullb", f"process (full log) at {before[1]}"),
                     ("leanb", f"process --log lean at {before[1]}")]
        for k, label in rows:
            x = r[k]
            print(f"  {label:44s} {x['wall']:7.2f} wall {x['cpu']:7.2f} CPU {x['rss_mb']:5.0f} MB"
                  f"  ({r['_mb'][k]:.1f} MB log)")

        def ratio(label, a, b):
            print(f"  {label:44s} {r[a]['wall'] / r[b]['wall']:6.2f}x wall "
                  f"{r[a]['cpu'] / r[b]['cpu']:5.2f}x CPU")
        ratio("full: default / one core", "full2", "full1")
        ratio("full: default / no child process", "full2", "fullt")
        ratio("lean: default / one core", "lean2", "lean1")
        ratio("lean: default / no child process", "lean2", "leant")
        if before:
            ratio(f"full: now / {before[1]}", "full2", "fullb")
            ratio(f"lean: now / {before[1]}", "lean2", "leanb")
        th = r["_threads"]
        tot = th["cpu"]
        parts = ", ".join(f"{k} {v:.2f} s ({v / tot:.0%})" for k, v in
                          sorted(th["threads"].items(), key=lambda kv: -kv[1]))
        print(f"  CPU of one default full run, in-process ({th['wall']:.2f} s wall, "
              f"{tot:.2f} s CPU): {parts}; peak RSS MB {th['rss']}")
        print(f"  default and one-core logs the same bytes: {'yes' if r['_identical'] else 'NO'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
