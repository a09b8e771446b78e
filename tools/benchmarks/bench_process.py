"""Benchmark `stillpoint process --mode batch` (two passes, full MCAP log) on long AX3 files.

    python tools/benchmarks/bench_process.py [--days 7] [--rss-days 1,7,14] [--repeat 2]
                                  [--no-pattern] [--before 81a4d51]

Two recordings, two columns of one table, every row measured in the same run:

1. **realistic** (first): ``stillpoint simulate`` with the default wearer (AX3 wrist, 100 Hz,
   seed 3; ``benchlib.realistic_recording``): days of wear, sleep, sitting and walking;
2. **test pattern** (second, ``--no-pattern`` skips it): the synthetic window-feature generator of
   tests/synthetic_calibration.py (packed AX3, blocks of constant orientation plus white noise,
   known sensor errors), the file every figure used before.

Each command runs in its own child process (wall time, CPU time and peak RSS of that child and
its children via ``getrusage(RUSAGE_CHILDREN)``), ``--repeat`` times interleaved, keeping the
least wall and the least CPU separately (the machine is shared: read the CPU ratios, taken
against baselines measured in the same run):

* plain decode: one reader pass over the whole file (the drivers' decode baseline);
* ``stillpoint process --mode batch`` (default flush cadence), the same with ``--log lean``
  (no per-sample streams; alternating with the full run and the plain decode), with ``--flush-every-s 60``, and
  without the epoch/day tables and the view topic (``--no-tables --view-hz 0``: the work the
  bound does);
* the same command at an earlier commit (``--before REV``: ``git archive`` of engine/, drivers/,
  tools/ into the workdir, run with that tree first on PYTHONPATH), for a before/after table;
* scikit-digital-health read + autocalibration + ENMO (``--peers`` Python, else
  $STILLPOINT_PEERS_PYTHON, else /tmp/skdh-venv; it logs nothing, so it does less work);
* the vectorised same-work bound (tools/benchmarks/bound_process.py), with and without filter and zstd;
* peak RSS of ``process`` on 1-, 7- and 14-day realistic files (must be flat);
* MCAP size against the input for both files and for every real file of
  $STILLPOINT_REAL_DATA (too short for speed figures: minutes to hours).

Recordings are written once into ``--workdir`` and reused.
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

from benchlib import (DECODE_PASS, SKDH_READ_AUTOCAL_ENMO, best_of, measure, peers_python,
                      real_recordings, realistic_recording)

BOUND = str(Path(__file__).resolve().parent / "bound_process.py")

def measure_ok(cmd, env=None) -> dict:
    r = measure(cmd, env)
    if r["rc"] != 0:
        raise SystemExit(f"command failed: {' '.join(map(str, cmd))}\n{r['err']}")
    return r


def best(cmd, repeat, env=None):
    """The least wall and the least CPU (separately) and the largest peak RSS of ``repeat`` runs."""
    runs = [measure_ok(cmd, env) for _ in range(max(1, repeat))]
    r = dict(min(runs, key=lambda x: x["wall"]))
    r["cpu"] = min(x["cpu"] for x in runs)
    r["rss_mb"] = max(x["rss_mb"] for x in runs)
    return r


def before_tree(workdir: Path, rev: str) -> dict:
    """An environment running the engine as it was at ``rev`` (git archive into the workdir)."""
    repo = Path(__file__).resolve().parents[2]
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

    from stillpoint.tools import testdoubles  # noqa: F401  (tests/ on sys.path)
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


def run_file(path: Path, wd: Path, args, peers_py, bt) -> dict:
    """Every row of the table for one recording: {name: measure result}, plus sizes."""
    sp = [sys.executable, "-m", "stillpoint.tools"]
    out = wd / "bench_process.mcap"
    summ = wd / "bench_process.json"
    cmds = {"decode": [sys.executable, "-c", DECODE_PASS, path],
            "process": sp + ["process", path, "-o", out, "--mode", "batch", "-q", "--summary", summ,
                             "--overwrite"],
            # the lean log (no per-sample streams), alternating with the full one
            "process_lean": sp + ["process", path, "-o", wd / "bench_lean.mcap", "--mode", "batch",
                                  "-q", "--log", "lean", "--overwrite"]}
    if peers_py:  # the peers alternate with process too (least of the rounds)
        cmds["skdh"] = [peers_py, "-c", SKDH_READ_AUTOCAL_ENMO, path]
    res = best_of(cmds, args.repeat)
    for name, r in res.items():
        if r["rc"] != 0:
            raise SystemExit(f"{name} failed on {path}:\n{r['err']}")
    mcap_mb = out.stat().st_size / 1e6
    lean_mb = (wd / "bench_lean.mcap").stat().st_size / 1e6
    (wd / "bench_lean.mcap").unlink()
    s = json.loads(summ.read_text())
    more = {"process60": sp + ["process", path, "-o", out, "--mode", "batch", "-q",
                               "--flush-every-s", "60", "--overwrite"],
            # the work the same-work bound does: no epoch/day tables, no view topic
            "process_same": sp + ["process", path, "-o", out, "--mode", "batch", "-q",
                                  "--no-tables", "--view-hz", "0", "--overwrite"],
            "bound": [sys.executable, BOUND, path],
            "bound_bare": [sys.executable, BOUND, path, "--no-filter", "--no-zstd"]}
    if bt:
        more["before"] = sp + ["process", path, "-o", wd / "bench_before.mcap", "--mode", "batch",
                               "-q", "--overwrite"]
    for name, cmd in more.items():
        res[name] = best(cmd, args.repeat, env=bt["env"] if name == "before" else None)
    for r in res.values():
        if r["rc"] != 0:
            raise SystemExit(f"a command failed on {path}:\n{r['err']}")
    res["_summary"] = s
    res["_mcap_mb"] = mcap_mb
    res["_lean_mb"] = lean_mb
    res["_cwa_mb"] = path.stat().st_size / 1e6
    if bt:
        res["_before_mb"] = (wd / "bench_before.mcap").stat().st_size / 1e6
        (wd / "bench_before.mcap").unlink()
    out.unlink(missing_ok=True)
    return res


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--days", type=float, default=7.0)
    ap.add_argument("--rate", type=float, default=100.0)
    ap.add_argument("--rss-days", default="1,7,14", help="realistic file lengths for the peak-RSS check ('' skips)")
    ap.add_argument("--workdir", default=os.path.join(tempfile.gettempdir(), "stillpoint_bench"))
    ap.add_argument("--peers", default=None, help="Python (or venv) of the peer tools (default "
                    "$STILLPOINT_PEERS_PYTHON, /tmp/skdh-venv or /work/peers)")
    ap.add_argument("--repeat", type=int, default=2, help="runs of each command (least wall and least CPU kept)")
    ap.add_argument("--no-pattern", action="store_true", help="realistic file only (no test-pattern column)")
    ap.add_argument("--before", default="", help="also run process at this git revision "
                    "(e.g. 81a4d51, the engine before the speed work)")
    args = ap.parse_args(argv)
    wd = Path(args.workdir)
    wd.mkdir(parents=True, exist_ok=True)
    files = [("realistic", realistic_recording(wd, args.days, args.rate))]
    if not args.no_pattern:
        files.append(("test pattern", recording(wd, args.days, args.rate)))
    bt = before_tree(wd, args.before) if args.before else None
    peers_py = peers_python(args.peers)
    if peers_py is None:
        print("skdh skipped: no peers Python (--peers, $STILLPOINT_PEERS_PYTHON, /tmp/skdh-venv); "
              "process is compared with the same-work bound only", flush=True)
    cols = [(kind, path, run_file(path, wd, args, peers_py, bt)) for kind, path in files]

    print(f"\nload average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores; each figure the least "
          f"of {max(1, args.repeat)} runs (CPU and wall separately)")
    for kind, path, res in cols:
        s = res["_summary"]
        print(f"{kind}: {path.name}: {s['samples']:,} samples, {s['duration_s'] / 86400:.2f} days, "
              f"{res['_cwa_mb']:.0f} MB; calibration {s['calibration']['status']} "
              f"({s['calibration']['error_before_mg']:.2f} -> {s['calibration']['error_after_mg']:.2f} mg)")
    head = "".join(f" | {k:>27s}" for k, _, _ in cols)
    print(f"{'command (wall s / CPU s / peak RSS MB)':48s}{head}")
    names = [("decode", "plain decode (reader, whole file)")]
    if bt:
        names.append(("before", f"before ({bt['sha']}): process --mode batch"))
    names += [("process", "process --mode batch"),
              ("process_lean", "process --mode batch --log lean"),
              ("process60", "process --mode batch --flush-every-s 60"),
              ("process_same", "process --no-tables --view-hz 0 (bound's work)"),
              ("bound", "same-work bound (tools/benchmarks/bound_process.py)"),
              ("bound_bare", "  bound without BFEN filter and zstd")]
    if peers_py:
        names.append(("skdh", "skdh read + autocalibration + ENMO"))
    for key, label in names:
        print(f"{label:48s}" + "".join(f" | {r[key]['wall']:8.2f} {r[key]['cpu']:8.2f} {r[key]['rss_mb']:7.0f}"
                                       for _, _, r in cols))

    def ratio(label, f):
        print(f"  {label:46s}" + "".join(f" | {f(r):>27s}" for _, _, r in cols))
    print("ratios (same run; CPU first):")
    ratio("process / plain decode (target <= 4x CPU)",
          lambda r: f"{r['process']['cpu'] / r['decode']['cpu']:.2f}x cpu {r['process']['wall'] / r['decode']['wall']:.2f}x wall")
    if peers_py:
        ratio("skdh / process (target >= 1.5x CPU, 2x wall)",
              lambda r: f"{r['skdh']['cpu'] / r['process']['cpu']:.2f}x cpu {r['skdh']['wall'] / r['process']['wall']:.2f}x wall")
        ratio("peak RSS skdh / process", lambda r: f"{r['skdh']['rss_mb'] / r['process']['rss_mb']:.1f}x")
        # skdh skips its calibration on recordings under 72 h (CalibrateAccelerometer min_hours)
        ratio("skdh calibrated the file", lambda r: "no: read + ENMO only" if "not-calibrated" in r["skdh"]["out"]
              else "yes")
    if bt:
        ratio("before / now", lambda r: f"{r['before']['cpu'] / r['process']['cpu']:.2f}x cpu {r['before']['wall'] / r['process']['wall']:.2f}x wall")
    ratio("process / same-work bound",
          lambda r: f"{r['process']['cpu'] / r['bound']['cpu']:.2f}x cpu {r['process']['wall'] / r['bound']['wall']:.2f}x wall")
    ratio("process, bound's work only / bound",
          lambda r: f"{r['process_same']['cpu'] / r['bound']['cpu']:.2f}x cpu {r['process_same']['wall'] / r['bound']['wall']:.2f}x wall")
    ratio("process --log lean / full",
          lambda r: f"{r['process_lean']['cpu'] / r['process']['cpu']:.2f}x cpu {r['process_lean']['wall'] / r['process']['wall']:.2f}x wall")
    if peers_py:
        ratio("skdh / process --log lean",
              lambda r: f"{r['skdh']['cpu'] / r['process_lean']['cpu']:.2f}x cpu {r['skdh']['wall'] / r['process_lean']['wall']:.2f}x wall")
    ratio("lean MCAP size / input .cwa", lambda r: f"{r['_lean_mb'] / r['_cwa_mb']:.3f}x ({r['_lean_mb']:.1f} MB)")
    ratio("MCAP size / input .cwa", lambda r: f"{r['_mcap_mb'] / r['_cwa_mb']:.2f}x ({r['_mcap_mb']:.0f} MB)")
    ratio("MCAP flushes", lambda r: str(r["_summary"].get("mcap_flushes", "n/a")))

    real = real_recordings()
    if real:
        print("\nMCAP size of process --mode batch against each real file ($STILLPOINT_REAL_DATA; "
              "too short for speed):")
        sp = [sys.executable, "-m", "stillpoint.tools"]
        for p in real:
            o = wd / "bench_real.mcap"
            r = measure(sp + ["process", p, "-o", o, "--mode", "batch", "-q", "--no-tables", "--overwrite"])
            if r["rc"] != 0 or not o.exists():
                print(f"  {p.name:60s} not processed: {r['err'].strip().splitlines()[-1:] or ['?']}")
                continue
            print(f"  {p.name:60s} {p.stat().st_size / 1e6:7.2f} MB -> {o.stat().st_size / 1e6:7.2f} MB "
                  f"({o.stat().st_size / p.stat().st_size:.2f}x{' the gzip file' if p.suffix == '.gz' else ''})")
            o.unlink()

    days = [float(x) for x in args.rss_days.split(",") if x.strip()]
    if days:
        print("\npeak RSS of process --mode batch by realistic file length (target: flat, not above before):")
        sp = [sys.executable, "-m", "stillpoint.tools"]
        for d in days:
            p = realistic_recording(wd, d, args.rate)
            o = wd / f"bench_rss_{d:g}d.mcap"
            r = measure_ok(sp + ["process", p, "-o", o, "--mode", "batch", "-q", "--overwrite"])
            print(f"  {d:5g} days ({p.stat().st_size / 1e6:5.0f} MB .cwa): {r['rss_mb']:6.0f} MB "
                  f"peak RSS, {r['cpu']:6.1f} s CPU, {r['wall']:6.1f} s wall")
            o.unlink(missing_ok=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
