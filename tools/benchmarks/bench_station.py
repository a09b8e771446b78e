"""Benchmark: the station's download worker on N emulated devices at once.

For N in --devices (default 1 2 4) and for each speed (USB full speed ~1.2 MB/s emulated by
throttling the reads, and unthrottled), every device serves a simulated AX3 recording of
--days days at 100 Hz, and we run, in the same session:

* ``cp``: a plain ``cp`` of the N data files from the emulated volumes (unthrottled only: the
  lower bound for moving the bytes at all);
* ``copy``: the download worker without the correction pipeline (copy + SHA-256 + sector checks +
  cache-bypassing verification read);
* ``full``: the download worker with the online pipeline writing the MCAP while the copy runs.

Printed per run: per-device copy MB/s, total wall, the time from the last byte copied to the MCAP
closed by the pipeline and to the MCAP finalised (renamed after the verification read, which at
USB speed reads the whole file a second time), and the peak RSS per worker process. The target
"the correction never slows the copy" is the ratio full / copy wall.

    python tools/benchmarks/bench_station.py --days 1 [--devices 1 2 4] [--rate-mbps 1.2] [--json]
    python tools/benchmarks/bench_station.py --days 7 --devices 1 --unthrottled-only   # a week, memory

Recordings are simulated once (in --work, default a temporary folder) and reused.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def _devices(work: Path, n: int, days: float):
    from stillpoint.engine.sim.record import simulate_recording
    out = []
    for i in range(n):
        dev_id = 30001 + i
        f = work / f"dev{dev_id}" / f"AX317_{dev_id:05d}" / "CWA-DATA.CWA"
        if not f.exists():
            f.parent.mkdir(parents=True, exist_ok=True)
            t = time.perf_counter()
            simulate_recording(f.with_suffix(".tmp.cwa"), device="ax3", days=days, seed=i + 1,
                               truth_path=False, device_id=dev_id, session_id=1)
            os.replace(f.with_suffix(".tmp.cwa"), f)
            print(f"simulated {f} ({f.stat().st_size / 1e6:.0f} MB) in {time.perf_counter() - t:.1f} s",
                  file=sys.stderr)
        out.append((dev_id, f))
    return out


def _drop_cache(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.posix_fadvise(fd, 0, 0, os.POSIX_FADV_DONTNEED)
    finally:
        os.close(fd)


def run_cp(devs, work: Path) -> dict:
    dst = work / "cp-out"
    shutil.rmtree(dst, ignore_errors=True)
    dst.mkdir()
    for _, f in devs:
        _drop_cache(f)
    t = time.perf_counter()
    procs = [subprocess.Popen(["cp", str(f), str(dst / f"{d}.cwa")]) for d, f in devs]
    for p in procs:
        p.wait()
    wall = time.perf_counter() - t
    size = sum(f.stat().st_size for _, f in devs)
    shutil.rmtree(dst, ignore_errors=True)
    return {"wall_s": round(wall, 2), "mb_s_per_device": round(size / len(devs) / wall / 1e6, 1)}


def run_workers(devs, work: Path, pipeline: bool, throttle_bps) -> dict:
    from stillpoint.engine.station.download import DownloadJob
    from stillpoint.engine.station.download import DownloadWorker
    out = work / "station-out"
    shutil.rmtree(out, ignore_errors=True)
    out.mkdir()
    for _, f in devs:
        _drop_cache(f)
    t = time.perf_counter()
    ws = [DownloadWorker(DownloadJob(d, 1, str(f), str(out), pipeline=pipeline,
                                     throttle_bps=throttle_bps), stall_s=120).start() for d, f in devs]
    rs = [w.wait() for w in ws]
    wall = time.perf_counter() - t
    bad = [r.reason for r in rs if not r.ok]
    if bad:
        raise SystemExit(f"a download failed: {bad[0]}")
    res = {"wall_s": round(wall, 2),
           "copy_mb_s": [round(r.bytes / r.copy_s / 1e6, 2) for r in rs],
           "verify_s": [round(r.verify_s, 1) for r in rs],
           "peak_rss_mb": [round(w.peak_rss_mb or 0, 0) for w in ws]}
    if pipeline:
        res["mcap_closed_after_last_byte_s"] = [round(r.pipeline_after_copy_s or 0, 2) for r in rs]
        res["mcap_final_after_last_byte_s"] = [round(r.mcap_after_copy_s or 0, 2) for r in rs]
    shutil.rmtree(out, ignore_errors=True)
    return res


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--days", type=float, default=1.0)
    ap.add_argument("--devices", type=int, nargs="+", default=[1, 2, 4])
    ap.add_argument("--rate-mbps", type=float, default=1.2, help="throttled read rate (MB/s)")
    ap.add_argument("--work", type=Path, default=None)
    ap.add_argument("--unthrottled-only", action="store_true", help="skip the throttled runs (long files)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    work = args.work or Path(tempfile.mkdtemp(prefix="bench-station-"))
    work.mkdir(parents=True, exist_ok=True)
    devs_all = _devices(work, max(args.devices), args.days)
    size_mb = devs_all[0][1].stat().st_size / 1e6
    rows = []
    for n in args.devices:
        devs = devs_all[:n]
        speeds = [("unthrottled", None)]
        if not args.unthrottled_only:
            speeds.append((f"{args.rate_mbps:g} MB/s", args.rate_mbps * 1e6))
        for label, thr in speeds:
            row = {"devices": n, "speed": label}
            if thr is None:
                row["cp"] = run_cp(devs, work)
            row["copy"] = run_workers(devs, work, False, thr)
            row["full"] = run_workers(devs, work, True, thr)
            row["full_over_copy"] = round(row["full"]["wall_s"] / row["copy"]["wall_s"], 3)
            rows.append(row)
            if not args.json:
                f, c = row["full"], row["copy"]
                print(f"N={n} {label:>12}: " + (f"cp {row['cp']['wall_s']:.2f} s; " if "cp" in row else "")
                      + f"copy-only {c['wall_s']:.2f} s; full {f['wall_s']:.2f} s (x{row['full_over_copy']:.3f}); "
                      f"copy MB/s per device {f['copy_mb_s']}; MCAP closed {f['mcap_closed_after_last_byte_s']} s "
                      f"/ final {f['mcap_final_after_last_byte_s']} s after the last byte; peak RSS per "
                      f"worker {f['peak_rss_mb']} MB", flush=True)
    if args.json:
        json.dump({"days": args.days, "file_mb": round(size_mb, 1), "cpus": os.cpu_count(), "runs": rows},
                  sys.stdout, indent=1)
        print()
    else:
        print(f"({args.days:g}-day 100 Hz AX3 recording = {size_mb:.1f} MB per device; {os.cpu_count()} CPUs)")
    if not args.work:
        shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
