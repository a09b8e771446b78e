"""Benchmark `stillpoint cohort run -j 2` against the same files one after another in one process.

    python tools/benchmarks/bench_cohort.py [--files 8] [--days 1] [--hz 100] [--jobs 2]
                                 [--scheduler processes|local] [--workdir DIR]

Measured in one run, each side in its own child process (wall, CPU, peak RSS from
``benchlib.measure``):

* **serial baseline**: one Python process calling ``engine.run.process_file`` on each file in
  turn with the epoch and day tables, as ``stillpoint process`` and a cohort job write them (the
  per-file engine cost with nothing around it);
* **cohort**: ``stillpoint cohort run DIR -o OUT -j N`` as a user runs it: planning (keys),
  starting a Dask LocalCluster of N worker processes, the jobs (process + summary + hashes +
  fsync + markers), collation;
* **Dask overhead per file**: ``(cohort wall x N - sum of the jobs' in-worker wall) / files``, the
  worker-time per file not spent inside a job (cluster start, scheduling, idle tail, planning,
  collation); the start of a bare 2-worker LocalCluster is timed separately; and the job's own
  cost beyond the engine (summary, SHA-256 of the outputs, fsyncs, markers);
* **peak RSS per worker**: the largest per-file peak each worker process reported in its
  ``_DONE.json`` (reset per file), against the baseline process's peak.

Recordings: realistic ``stillpoint simulate`` output with the default wearer (AX3 wrist, default
100 Hz, seeds 100, 101, ...) 1-day files, written once into ``--workdir`` and reused. The machine
may be shared: the load average is printed before and after, and the cores the serial baseline
already keeps busy (its CPU / wall: the reader and writer threads run beside the engine) bound
what N workers can gain over it: at most N / (serial CPU / wall) on N cores.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
from pathlib import Path

from benchlib import measure

SERIAL = r"""
import json, sys, time
from pathlib import Path
from stillpoint.engine.run import RunSettings, process_file
from stillpoint.engine.tables import TablesSettings, table_paths
out = Path(sys.argv[1]); walls = []
for f in sys.argv[2:]:
    t = time.perf_counter()
    m = out / (Path(f).stem + ".mcap")
    process_file(f, m, RunSettings(), tables=TablesSettings(*table_paths(m)))
    walls.append(time.perf_counter() - t)
print(json.dumps(walls))
"""

CLUSTER_START = r"""
import json, logging, time
t = time.perf_counter()
from distributed import Client, LocalCluster
c = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None,
                 silence_logs=logging.CRITICAL)
cl = Client(c); cl.submit(lambda: 1).result(); t1 = time.perf_counter()
futs = [cl.submit(lambda i: i, i, pure=False) for i in range(200)]
cl.gather(futs); t2 = time.perf_counter()
cl.close(); c.close()
print(json.dumps({"start_s": t1 - t, "per_task_ms": (t2 - t1) / 200 * 1000}))
"""


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--files", type=int, default=8)
    ap.add_argument("--days", type=float, default=1.0)
    ap.add_argument("--hz", type=float, default=100.0)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--scheduler", default=None,
                    help="cohort run's --scheduler (default: the command's own default)")
    ap.add_argument("--workdir", type=Path, default=Path(tempfile.gettempdir()) / "stillpoint_bench_cohort")
    a = ap.parse_args()

    data = a.workdir / f"in_{a.files}x{a.days:g}d_{a.hz:g}hz"
    data.mkdir(parents=True, exist_ok=True)
    from stillpoint.engine.sim import simulate_recording
    files = []
    for i in range(a.files):
        f = data / f"rec{i:02d}.cwa"
        if not f.exists():
            simulate_recording(f, days=a.days, hz=a.hz, seed=100 + i, truth_path=False, labels_path=False)
        files.append(f)
    mb = sum(f.stat().st_size for f in files) / 1e6
    print(f"{a.files} simulated {a.days:g}-day AX3 files at {a.hz:g} Hz, {mb:.0f} MB; "
          f"{os.cpu_count()} cores; load average before {os.getloadavg()[0]:.2f}")

    serial_out = a.workdir / "serial_out"
    cohort_out = a.workdir / "cohort_out"
    for d in (serial_out, cohort_out):
        shutil.rmtree(d, ignore_errors=True)
    serial_out.mkdir()

    base = measure([sys.executable, "-c", SERIAL, str(serial_out), *map(str, files)])
    if base["rc"] != 0:
        raise SystemExit(base["err"])
    walls = json.loads(base["out"])
    from stillpoint.tools.cli.commands.cohort import scheduler_of
    scheduler = scheduler_of(a.scheduler, None)
    coh = measure([sys.executable, "-m", "stillpoint.tools", "cohort", "run", str(data), "-o",
                   str(cohort_out), "-j", str(a.jobs), "-q", "--scheduler", scheduler])
    if coh["rc"] != 0:
        raise SystemExit(coh["err"])
    cluster = None
    if scheduler == "local":
        cs = measure([sys.executable, "-c", CLUSTER_START])
        cluster = json.loads(cs["out"]) if cs["rc"] == 0 else {"start_s": float("nan"),
                                                               "per_task_ms": float("nan")}

    markers = [json.loads(p.read_text()) for p in cohort_out.glob("files/*/*/_DONE.json")]
    if len(markers) != a.files:
        raise SystemExit(f"cohort finished {len(markers)} of {a.files} files")
    job_wall = sum(m["timings"]["wall_s"] for m in markers)
    engine_wall = sum(m["timings"]["engine_wall_s"] for m in markers)
    per_worker: dict = {}
    for m in markers:
        per_worker[m["pid"]] = max(per_worker.get(m["pid"], 0.0), m["peak_rss_mb"])
    scope = {m["peak_rss_scope"] for m in markers}

    print(f"serial, one process : wall {base['wall']:6.2f} s  CPU {base['cpu']:6.2f} s  peak RSS "
          f"{base['rss_mb']:.0f} MB  (per file {min(walls):.2f}-{max(walls):.2f} s)")
    print(f"cohort run -j {a.jobs}     : wall {coh['wall']:6.2f} s  CPU {coh['cpu']:6.2f} s  "
          f"(--scheduler {scheduler}: CLI start, plan, workers, jobs, collation)")
    print(f"speed-up            : {base['wall'] / coh['wall']:.2f}x (goal >= 1.7x); the serial run "
          f"already keeps {base['cpu'] / base['wall']:.2f} cores busy, so {a.jobs} workers on "
          f"{os.cpu_count()} cores can gain at most "
          f"{min(a.jobs, os.cpu_count() or 1) / max(1.0, base['cpu'] / base['wall']):.2f}x over it; CPU cohort / "
          f"serial {coh['cpu'] / base['cpu']:.2f}x, so at most "
          f"{min(a.jobs, os.cpu_count() or 1) * base['cpu'] / coh['cpu']:.2f}x on an idle machine")
    over = (coh["wall"] * a.jobs - job_wall) / a.files
    bare = (f"; bare LocalCluster(2) start {cluster['start_s']:.2f} s, "
            f"{cluster['per_task_ms']:.1f} ms per trivial task" if cluster else "")
    print(f"scheduler overhead  : {over:.2f} s of worker time per file outside the jobs "
          f"((wall x {a.jobs} - {job_wall:.2f} s of jobs) / {a.files}){bare}")
    print(f"job beyond engine   : {(job_wall - engine_wall) / a.files * 1000:.0f} ms per file "
          f"(summary, SHA-256, fsync, markers); in-worker engine {engine_wall / a.files:.2f} s per file "
          f"vs {sum(walls) / a.files:.2f} s serial")
    print("peak RSS per worker : " + ", ".join(f"pid {p} {v:.0f} MB" for p, v in sorted(per_worker.items()))
          + f" (scope: {'/'.join(sorted(scope))})")
    print(f"load average after  : {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
