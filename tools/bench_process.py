"""Benchmark `stillpoint process --mode batch` (two passes, full MCAP log) on long packed AX3 files.

    /work/venv/bin/python tools/bench_process.py [--days 7] [--rss-days 1,7,14] [--repeat 1]
                                                 [--before 81a4d51]

Measured side by side in one run, each command in its own child process (wall time, CPU time and
peak RSS of that child and its children via ``getrusage(RUSAGE_CHILDREN)``):

* plain decode: one CwaReader pass over the whole file (the drivers' decode baseline);
* ``stillpoint process --mode batch`` with the default 10 s flush cadence (inline writer), with
  the writer in a child process (``writer="process"``, API), and with 60 s flushes;
* the same command at an earlier commit (``--before REV``: ``git archive`` of engine/, drivers/,
  tools/ into the workdir, run with that tree first on PYTHONPATH), for a before/after table;
* scikit-digital-health read + autocalibration + ENMO (if ``--peers`` python has skdh; it
  does not log anything, so this is less work than process);
* the vectorised same-work bound (tools/bound_process.py: two decodes, window features, affine
  correction, ENMO, BFEN filter, zstd as straight numpy per block), with and without the filter
  and compression;
* peak RSS of ``process`` on 1-, 7- and 14-day files (must be flat and < 300 MB);
* the same ``process`` without the epoch/day tables and the view topic (``--no-tables
  --view-hz 0``): the work the bound does;
* MCAP size against the input .cwa (target <= 1.2x; ``tools/mcap_size.py`` says where it goes).

Recordings are written once with the synthetic window-feature generator of tests/synthetic_calibration.py (packed AX3, 100 Hz,
known sensor errors) into ``--workdir`` and reused (same names as tools/bench_calibrate.py).
The machine is shared and noisy: read the ratios, not the seconds.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchlib import DECODE_PASS, SKDH_READ_AUTOCAL_ENMO, measure, peers_python

BOUND = str(Path(__file__).resolve().parent / "bound_process.py")

PROCESS_API = r"""
import sys
from stillpoint.engine.run import RunSettings, process_file
process_file(sys.argv[1], sys.argv[2], RunSettings(mode="batch"), writer=sys.argv[3])
"""


def measure_ok(cmd, env=None) -> dict:
    r = measure(cmd, env)
    if r["rc"] != 0:
        raise SystemExit(f"command failed: {' '.join(map(str, cmd))}\n{r['err']}")
    return r


def best(cmd, repeat, env=None):
    return min((measure_ok(cmd, env) for _ in range(max(1, repeat))), key=lambda r: r["wall"])


def before_tree(workdir: Path, rev: str) -> dict:
    """An environment running the engine as it was at ``rev`` (git archive into the workdir)."""
    repo = Path(__file__).resolve().parent.parent
    sha = subprocess.run(["git", "-C", str(repo), "rev-parse", "--short", rev], check=True,
                         stdout=subprocess.PIPE, text=True).stdout.strip()
    root = workdir / f"before_{sha}"
    pkg = root / "stillpoint"
    if not (pkg / "engine").is_dir():
        pkg.mkdir(parents=True, exist_ok=True)
        init = subprocess.run(["git", "-C", str(repo), "show", f"{sha}:_stillpoint/__init__.py"],
                              stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
        # the package's own __init__ (the entry point), where the revision has one
        (pkg / "__init__.py").write_bytes(init.stdout if init.returncode == 0 else b"")
        tar = subprocess.run(["git", "-C", str(repo), "archive", sha, "engine", "drivers", "tools"],
                             check=True, stdout=subprocess.PIPE).stdout
        subprocess.run(["tar", "-x", "-C", str(pkg)], input=tar, check=True)
    env = dict(os.environ)
    env["PYTHONPATH"] = str(root) + os.pathsep + env.get("PYTHONPATH", "")
    return {"env": env, "sha": sha}


def recording(workdir: Path, days: float, rate: float) -> Path:
    path = workdir / f"calib_{days:g}d_{rate:g}hz_packed.cwa"
    if path.is_file():
        return path
    import numpy as np

    import testdoubles  # noqa: F401  (tests/ on sys.path)
    from synthetic_calibration import (random_truth, synthetic_recording,
                                       write_synthetic_cwa)
    t = time.perf_counter()
    truth = random_truth(np.random.default_rng(7))
    rec = synthetic_recording(days * 24.0, truth, seed=8)
    tmp = path.with_suffix(".part")
    write_synthetic_cwa(tmp, rec.features, rate_hz=rate, seed=9, packed=True)
    os.replace(tmp, path)
    path.with_suffix(".truth.json").write_text(json.dumps(
        {"offset": truth.offset.tolist(), "scale": truth.scale.tolist(),
         "tempoffset": truth.tempoffset.tolist(), "temperature_ref": truth.temperature_ref}))
    print(f"wrote {path.name} ({path.stat().st_size / 1e6:.0f} MB) in {time.perf_counter() - t:.0f} s",
          flush=True)
    return path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--days", type=float, default=7.0)
    ap.add_argument("--rate", type=float, default=100.0)
    ap.add_argument("--rss-days", default="1,7,14", help="file lengths for the peak-RSS check ('' skips)")
    ap.add_argument("--workdir", default=os.path.join(tempfile.gettempdir(), "stillpoint_bench"))
    ap.add_argument("--peers", default=None, help="Python (or venv) of the peer tools (default $STILLPOINT_PEERS_PYTHON or /work/peers)")
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--before", default="", help="also run process at this git revision "
                    "(e.g. 81a4d51, the engine before the speed work)")
    args = ap.parse_args(argv)
    wd = Path(args.workdir)
    wd.mkdir(parents=True, exist_ok=True)
    path = recording(wd, args.days, args.rate)
    cwa_mb = path.stat().st_size / 1e6
    sp = [sys.executable, "-m", "stillpoint.tools"]
    out = wd / "bench_process.mcap"
    summ = wd / "bench_process.json"

    res = {"decode": best([sys.executable, "-c", DECODE_PASS, path], args.repeat)}
    res["process"] = best(sp + ["process", path, "-o", out, "--mode", "batch", "-q", "--summary", summ, "--overwrite"],
                          args.repeat)
    mcap_mb = out.stat().st_size / 1e6
    s = json.loads(summ.read_text())
    res["process60"] = best(sp + ["process", path, "-o", out, "--mode", "batch", "-q",
                                  "--flush-every-s", "60", "--overwrite"], args.repeat)
    # the work the same-work bound does: no epoch/day tables, no view topic
    res["process_same"] = best(sp + ["process", path, "-o", out, "--mode", "batch", "-q",
                                     "--no-tables", "--view-hz", "0", "--overwrite"], args.repeat)
    res["process_wp"] = best([sys.executable, "-c", PROCESS_API, path, out, "process"], args.repeat)
    res["bound"] = best([sys.executable, BOUND, path], args.repeat)
    res["bound_bare"] = best([sys.executable, BOUND, path, "--no-filter", "--no-zstd"], args.repeat)
    if args.before:
        bt = before_tree(wd, args.before)
        res["before"] = best(sp + ["process", path, "-o", wd / "bench_before.mcap", "--mode",
                                   "batch", "-q"], args.repeat, env=bt["env"])
        before_mb = (wd / "bench_before.mcap").stat().st_size / 1e6
        (wd / "bench_before.mcap").unlink()
    peers_py = peers_python(args.peers)
    have_skdh = peers_py is not None
    if have_skdh:
        res["skdh"] = best([peers_py, "-c", SKDH_READ_AUTOCAL_ENMO, path], args.repeat)
    else:
        print(f"skdh skipped: no peers Python (--peers, $STILLPOINT_PEERS_PYTHON); process is "
              f"compared with the same-work bound only", flush=True)

    dec, pr, pr60 = res["decode"], res["process"], res["process60"]
    print(f"\nfile: {path.name}: {s['samples']:,} samples, {s['duration_s'] / 86400:.2f} days, "
          f"{cwa_mb:.0f} MB; calibration {s['calibration']['status']} "
          f"({s['calibration']['error_before_mg']:.2f} -> {s['calibration']['error_after_mg']:.2f} mg)")
    print(f"{'command':48s} {'wall s':>8s} {'cpu s':>8s} {'peak RSS MB':>12s}")
    rows = [("plain decode (CwaReader, whole file)", dec)]
    if args.before:
        rows.append((f"before ({bt['sha']}): process --mode batch", res["before"]))
    rows += [("process --mode batch (flush every 10 s)", pr),
             ("  same, writer in a child process (API)", res["process_wp"]),
             ("process --mode batch --flush-every-s 60", pr60),
             ("process --no-tables --view-hz 0 (bound's work)", res["process_same"]),
             ("same-work bound (tools/bound_process.py)", res["bound"]),
             ("  bound without BFEN filter and zstd", res["bound_bare"])]
    if have_skdh:
        rows.append(("skdh read + autocalibration + ENMO", res["skdh"]))
    for name, r in rows:
        print(f"{name:48s} {r['wall']:8.2f} {r['cpu']:8.2f} {r['rss_mb']:12.0f}")
    rss = s.get("peak_rss_mb") or {}
    if rss.get("writer"):
        print(f"  process peak RSS: engine {rss['engine']:.0f} MB + writer process {rss['writer']:.0f} MB "
              f"= {rss['engine'] + rss['writer']:.0f} MB (each process's VmHWM)")
    print("ratios (same run):")
    print(f"  process / plain decode                      = {pr['wall'] / dec['wall']:.1f}x wall, "
          f"{pr['cpu'] / dec['cpu']:.1f}x cpu")
    if args.before:
        b = res["before"]
        print(f"  before / now                                = {b['wall'] / pr['wall']:.2f}x wall, "
              f"{b['cpu'] / pr['cpu']:.2f}x cpu (before's MCAP {before_mb / cwa_mb:.2f}x the .cwa)")
    bd, bb = res["bound"], res["bound_bare"]
    print(f"  process / same-work bound                   = {pr['wall'] / bd['wall']:.2f}x wall, "
          f"{pr['cpu'] / bd['cpu']:.2f}x cpu (target <= 1.2x)")
    ps = res["process_same"]
    print(f"  process, bound's work only / bound          = {ps['wall'] / bd['wall']:.2f}x wall, "
          f"{ps['cpu'] / bd['cpu']:.2f}x cpu (no tables, no view)")
    print(f"  process / bound without filter and zstd     = {pr['wall'] / bb['wall']:.2f}x wall, "
          f"{pr['cpu'] / bb['cpu']:.2f}x cpu")
    if have_skdh:
        sk = res["skdh"]
        print(f"  skdh read+autocal+ENMO / process            = {sk['wall'] / pr['wall']:.2f}x wall, "
              f"{sk['cpu'] / pr['cpu']:.2f}x cpu (target >= 2x), "
              f"{sk['wall'] / pr60['wall']:.2f}x wall with 60 s flushes")
        print(f"  peak RSS skdh / process                     = {sk['rss_mb'] / pr['rss_mb']:.1f}x")
    print(f"  MCAP size / input .cwa                      = {mcap_mb / cwa_mb:.2f}x "
          f"({mcap_mb:.0f} MB; target <= 1.2x)")
    print(f"  MCAP flushes                                = {s.get('mcap_flushes', 'n/a')}")

    days = [float(x) for x in args.rss_days.split(",") if x.strip()]
    if days:
        print("\npeak RSS of process --mode batch by file length (target: flat, < 300 MB):")
        for d in days:
            p = recording(wd, d, args.rate)
            o = wd / f"bench_rss_{d:g}d.mcap"
            sj = wd / f"bench_rss_{d:g}d.json"
            if p == path:
                r, ss = pr, s
            else:
                r = measure_ok(sp + ["process", p, "-o", o, "--mode", "batch", "-q", "--summary", sj,
                                   "--overwrite"])
                ss = json.loads(sj.read_text())
            rr = ss.get("peak_rss_mb") or {}
            both = (f" (engine {rr['engine']:.0f} + writer {rr['writer']:.0f} = "
                    f"{rr['engine'] + rr['writer']:.0f} MB)") if rr.get("writer") else ""
            print(f"  {d:5g} days ({p.stat().st_size / 1e6:5.0f} MB .cwa): {r['rss_mb']:6.0f} MB "
                  f"peak RSS of the largest process{both}, {r['wall']:6.1f} s wall")
            if o.exists():
                o.unlink()
    out.unlink(missing_ok=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
