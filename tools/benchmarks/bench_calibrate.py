"""Benchmark: ``stillpoint calibrate`` on a 7-day 100 Hz packed AX3 file vs scikit-digital-health's
read + autocalibration of the same file, in the same run (targets: >= 4x faster, peak RSS < 200 MB).

    /work/venv/bin/python tools/benchmarks/bench_calibrate.py [--days 7] [--rate 100] [--workdir DIR]
                                                   [--peers /work/peers/bin/python] [--repeat 1]

Two recordings, cached in --workdir, each with its own table: first the realistic one
(``benchlib.realistic_recording``: ``stillpoint simulate`` with the default wearer, AX3 wrist,
seed 3), then (unless ``--no-pattern``) the test pattern with a known calibration error
(tests/synthetic_calibration.py: still runs over the sphere, daily temperature cycle, 5 mg noise)
written with the project's CwaWriter, whose fit is also compared with its truth. Every command runs in its own child process; wall time and the child's peak
RSS (``resource.getrusage(RUSAGE_CHILDREN).ru_maxrss`` in a wrapper) are printed, plus ratios
against skdh and against a plain decode pass (our CwaReader over the whole file) measured in the
same run. Timings on a shared machine are noisy: compare the ratios.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

from benchlib import DECODE_PASS, SKDH_READ_AUTOCAL, measure, peers_python, realistic_recording

def make_recording(path: Path, days: float, rate: float, seed: int = 7) -> dict:
    import numpy as np

    from stillpoint.tools import testdoubles  # noqa: F401  (tests/ on sys.path)
    from synthetic_calibration import (random_truth, synthetic_recording,
                                       write_synthetic_cwa)

    truth = random_truth(np.random.default_rng(seed))
    rec = synthetic_recording(days * 24.0, truth, seed=seed + 1)
    tmp = path.with_suffix(".part")
    write_synthetic_cwa(tmp, rec.features, rate_hz=rate, seed=seed + 2, packed=True)
    os.replace(tmp, path)
    t = {"offset": truth.offset.tolist(), "scale": truth.scale.tolist(),
         "tempoffset": truth.tempoffset.tolist(), "temperature_ref": truth.temperature_ref}
    path.with_suffix(".truth.json").write_text(json.dumps(t))
    return t


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--days", type=float, default=7.0)
    ap.add_argument("--rate", type=float, default=100.0)
    ap.add_argument("--workdir", default=os.path.join(tempfile.gettempdir(), "stillpoint_bench"))
    ap.add_argument("--peers", default=None,
                    help="Python (or venv) with scikit-digital-health (default $STILLPOINT_PEERS_PYTHON or /work/peers; skipped if missing)")
    ap.add_argument("--repeat", type=int, default=1, help="runs per command (least wall and least CPU kept)")
    ap.add_argument("--no-pattern", action="store_true", help="the realistic file only")
    args = ap.parse_args(argv)

    wd = Path(args.workdir)
    wd.mkdir(parents=True, exist_ok=True)
    bench_file(realistic_recording(wd, args.days, args.rate), None, args, "realistic")
    if args.no_pattern:
        return 0
    path = wd / f"calib_{args.days:g}d_{args.rate:g}hz_packed.cwa"
    if not path.is_file():
        t = time.perf_counter()
        truth = make_recording(path, args.days, args.rate)
        print(f"wrote {path} ({path.stat().st_size / 1e6:.0f} MB) "
              f"in {time.perf_counter() - t:.1f} s")
    else:
        truth = json.loads(path.with_suffix(".truth.json").read_text())
    bench_file(path, truth, args, "test pattern")
    return 0


def bench_file(path: Path, truth, args, kind: str) -> None:
    """The table and ratios for one recording (and the fit against ``truth`` when known)."""
    size_mb = path.stat().st_size / 1e6
    stillpoint = [sys.executable, "-m", "stillpoint.tools.cli"]

    def best(cmd):
        runs = [measure(cmd) for _ in range(max(1, args.repeat))]
        for r in runs:
            if r["rc"] != 0:
                print(f"command failed: {' '.join(map(str, cmd))}\n{r['err']}", file=sys.stderr)
                sys.exit(1)
        r = dict(min(runs, key=lambda r: r["wall"]))
        r["cpu"] = min(x["cpu"] for x in runs)
        return r

    res = {}
    res["calibrate"] = best(stillpoint + ["calibrate", str(path), "--json"])
    res["calibrate --read-all"] = best(stillpoint + ["calibrate", str(path), "--json",
                                                    "--read-all"])
    res["decode (CwaReader, whole file)"] = best([sys.executable, "-c", DECODE_PASS, str(path)])
    peers_py = peers_python(args.peers)
    have_skdh = peers_py is not None
    if have_skdh:
        res["skdh read + autocal"] = best([peers_py, "-c", SKDH_READ_AUTOCAL, str(path)])

    est = json.loads(res["calibrate"]["out"])
    print(f"\n{kind} file: {path.name}, {args.days:g} days at {args.rate:g} Hz, {size_mb:.0f} MB")
    print(f"{'command':<34} {'wall (s)':>9} {'CPU (s)':>8} {'peak RSS (MB)':>14}")
    for k, r in res.items():
        print(f"{k:<34} {r['wall']:>9.2f} {r['cpu']:>8.2f} {r['rss_mb']:>14.0f}")
    ours = res["calibrate"]
    print("\nratios (same run):")
    if have_skdh:
        sk = res["skdh read + autocal"]
        print("  skdh read+autocal / stillpoint calibrate      = "
              f"{sk['wall'] / ours['wall']:.1f}x"
              "  (target >= 4x)")
        print(f"  skdh read+autocal / calibrate --read-all      = "
              f"{sk['wall'] / res['calibrate --read-all']['wall']:.1f}x")
        print(f"  peak RSS skdh / stillpoint                    = "
              f"{sk['rss_mb'] / ours['rss_mb']:.1f}x")
    else:
        print(f"  (peer tools' Python not found ({args.peers or 'default'}): skdh skipped)")
    dec = res["decode (CwaReader, whole file)"]
    ra = res["calibrate --read-all"]
    print(f"  calibrate / plain decode of the whole file    = "
          f"{ours['wall'] / dec['wall']:.2f} wall, {ours['cpu'] / dec['cpu']:.2f} CPU")
    print(f"  calibrate --read-all / plain decode           = "
          f"{ra['wall'] / dec['wall']:.2f} wall, {ra['cpu'] / dec['cpu']:.2f} CPU (target <= 1.3x)")
    print(f"  stillpoint calibrate peak RSS                 = {ours['rss_mb']:.0f} MB "
          "(target < 200 MB)")
    print(f"\nfit: {est['status']}, {est['windows']} windows, {est['hours_used']:.0f} h used, "
          f"error {est['error_before_mg']:.2f} -> {est['error_after_mg']:.2f} mg")
    if have_skdh:
        print(f"  skdh: {res['skdh read + autocal']['out'].strip()[:300]}")
    if truth is None:
        return
    import numpy as np

    from stillpoint.engine.calibration import CalibrationEstimate
    from stillpoint.engine.calibration.fit import rereference

    tr = rereference(CalibrationEstimate(**truth), est["temperature_ref"])
    d_off = np.max(np.abs(np.subtract(est['offset'], tr.offset))) * 1e3
    print(f"  |offset - true| max {d_off:.3f} mg"
          f", |scale/true - 1| max "
          f"{np.max(np.abs(np.divide(est['scale'], truth['scale']) - 1)) * 100:.4f} %, "
          f"|tempoffset - true| max "
          f"{np.max(np.abs(np.subtract(est['tempoffset'], truth['tempoffset']))) * 1e3:.3f} mg/degC"
          " (AX3 temperature is quantised to 0.29 degC)")


if __name__ == "__main__":
    sys.exit(main())
