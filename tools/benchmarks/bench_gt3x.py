"""Benchmark: ActiGraph .gt3x decode speed and peak memory, against actfast (Rust) in the same run.

    python tools/benchmarks/bench_gt3x.py [--days 7] [--hz 30] [--dir /tmp] [--repeat 3]
        [--peers /work/venv-peers] [--flat-check]

Writes a ``--days``-long .gt3x with ``stillpoint simulate --device gt3x`` (the default wearer at
the wrist, log.bin layout, 12-bit ACTIVITY records, idle sleep on), then times, each in a fresh
subprocess with its peak RSS (benchlib.measure), alternating the commands ``--repeat`` times and
keeping the least wall and the least CPU of each:

* ``stillpoint decode``: every Block of drivers.gt3x.Gt3xReader (the reader alone: records
  checked, samples decoded, idle sleep filled and flagged, times made);
* ``stillpoint inspect``: the command (a full pass plus its summary);
* ``actfast.read``: actfast's reader (whole file in memory; it does not fill idle sleep), from
  the peers' Python (``--peers``: a venv with ``pip install actfast``).

Prints wall and CPU seconds, peak RSS and the ratios actfast / stillpoint decode.
``--flat-check`` also writes a file twice as long and compares the decode's peak RSS.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from benchlib import best_of, peers_python

DECODE = r'''
import sys
from stillpoint.drivers.gt3x import Gt3xReader
n = idle = 0
with Gt3xReader(sys.argv[1]) as src:
    for b in src:
        n += b.n
        idle += int(b.per_sample["idle_sleep"].sum())
print(n, idle)
'''

ACTFAST = r'''
import sys, actfast
d = actfast.read(sys.argv[1])
print(d["timeseries"]["acceleration"]["acceleration"].shape[0])
'''


def write_file(path: Path, days: float, hz: float) -> None:
    if path.exists():
        return
    from stillpoint.engine.sim import simulate_recording
    t = time.perf_counter()
    tmp = path.with_name(path.stem + ".part.gt3x")
    simulate_recording(tmp, device="gt3x", days=days, hz=hz, seed=1, truth_path=False)
    tmp.replace(path)
    for extra in (".truth.json", ".labels.csv"):
        q = tmp.with_name(tmp.name[:-len(".gt3x")] + extra)
        if q.exists():
            q.unlink()
    print(f"wrote {path} ({days:g} days at {hz:g} Hz, {path.stat().st_size / 1e6:.0f} MB) in "
          f"{time.perf_counter() - t:.0f} s", flush=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--days", type=float, default=7.0)
    ap.add_argument("--hz", type=float, default=30.0)
    ap.add_argument("--dir", default="/tmp")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--peers", default="/work/venv-peers",
                    help="Python (or venv folder) with actfast installed")
    ap.add_argument("--flat-check", action="store_true")
    ap.add_argument("--keep", action="store_true", help="keep the written files")
    args = ap.parse_args(argv)
    d = Path(args.dir)
    d.mkdir(parents=True, exist_ok=True)
    py = sys.executable
    peer = peers_python(args.peers)
    files = [(args.days, d / f"bench_gt3x_{args.days:g}d_{args.hz:g}hz.gt3x")]
    if args.flat_check:
        files.append((2 * args.days, d / f"bench_gt3x_{2 * args.days:g}d_{args.hz:g}hz.gt3x"))
    try:
        out = {}
        for days, path in files:
            write_file(path, days, args.hz)
            cmds = {"stillpoint decode": [py, "-c", DECODE, str(path)]}
            if days == args.days:
                cmds["stillpoint inspect"] = [py, "-m", "stillpoint.tools", "inspect", "--json", str(path)]
                if peer:
                    cmds["actfast.read"] = [peer, "-c", ACTFAST, str(path)]
                else:
                    print("actfast skipped: no peers' Python (--peers)")
            res = best_of(cmds, repeat=args.repeat)
            out[days] = res
            print(f"\n{days:g} days, least of {args.repeat} alternating runs:")
            for name, m in res.items():
                ok = m["out"].strip()[:60] if m["rc"] == 0 else f"FAILED rc={m['rc']}: {m['err'].strip()[-200:]}"
                print(f"  {name:<20} {m['wall']:7.2f} s wall  {m['cpu']:7.2f} s CPU  "
                      f"peak RSS {m['rss_mb']:7.0f} MB   ({ok})")
        res = out[args.days]
        ours = res["stillpoint decode"]
        if "actfast.read" in res and res["actfast.read"]["rc"] == 0:
            a = res["actfast.read"]
            print(f"\nactfast / stillpoint decode: wall {a['wall'] / ours['wall']:.2f}x, "
                  f"CPU {a['cpu'] / ours['cpu']:.2f}x, peak RSS {a['rss_mb'] / ours['rss_mb']:.2f}x "
                  "(above 1: stillpoint is faster / smaller)")
        if args.flat_check:
            big = out[2 * args.days]["stillpoint decode"]
            print(f"flat memory: decode peak RSS {ours['rss_mb']:.0f} MB at {args.days:g} days, "
                  f"{big['rss_mb']:.0f} MB at {2 * args.days:g} days (x{big['rss_mb'] / ours['rss_mb']:.2f})")
    finally:
        if not args.keep:
            for _, path in files:
                if path.exists():
                    path.unlink()
    return 0


if __name__ == "__main__":
    sys.exit(main())
