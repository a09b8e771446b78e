"""Benchmark: GENEActiv .bin decode speed and peak memory, against baselines measured in the same run.

    /work/venv/bin/python tools/benchmarks/bench_geneactiv.py [--days 7] [--dir /tmp] [--flat-check] [--no-peers]

Writes a ``--days``-long 100 Hz .bin with ``GeneactivWriter`` (7 days = 60.5 M samples, ~770 MB),
then times, each in a fresh subprocess with its peak RSS (``getrusage(RUSAGE_CHILDREN)`` of a
wrapper process that runs only that command):

* ``stillpoint inspect FILE --json`` (our streaming reader, a full pass);
* baseline: a plain numpy whole-file decode (read all bytes, pick the data lines, one lookup table
  over everything) - the fastest simple approach, at whole-file memory;
* skdh and actipy from /work/peers (if present; ``--no-peers`` skips them).

Prints wall and CPU seconds (CPU time is the steadier figure on a shared machine), samples per
second, peak RSS and ratios against our reader and the numpy baseline.
``--flat-check`` also writes a file twice as long and compares our peak RSS on both (bounded memory
means the same RSS).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from benchlib import measure, peers_python

HERE = Path(__file__).resolve().parent

NUMPY_BASELINE = r'''
import re, sys, numpy as np
data = open(sys.argv[1], "rb").read()
hexlines = re.findall(rb"\n([0-9A-Fa-f]{3600})\r?\n", data)
lut = np.full(256, 0, np.uint8)
lut[np.frombuffer(b"0123456789ABCDEF", np.uint8)] = np.arange(16)
nib = lut[np.frombuffer(b"".join(hexlines), np.uint8)].reshape(-1, 4, 3).astype(np.int16)
w = (nib[:, :, 0] << 8) | (nib[:, :, 1] << 4) | nib[:, :, 2]
xyz = np.where(w[:, :3] >= 2048, w[:, :3] - 4096, w[:, :3])
print(xyz.shape[0])
'''

SKDH = r'''
import sys, warnings
warnings.simplefilter("ignore")
from skdh.io import ReadBin
r = ReadBin().predict(file=sys.argv[1])
print(r["accel"].shape[0])
'''

ACTIPY = r'''
import sys, actipy
d, info = actipy.read_device(sys.argv[1], lowpass_hz=None, calibrate_gravity=False,
                             detect_nonwear=False, resample_hz=None, verbose=False)
print(len(d))
'''


def write_file(path: Path, days: float, rate: float = 100.0) -> int:
    from stillpoint.drivers.geneactiv import GeneactivWriter
    n = int(days * 86400 * rate)
    rng = np.random.default_rng(0)
    w = GeneactivWriter(path, rate_hz=rate, partial_page="drop")
    chunk = 300 * 2000
    base = rng.integers(-300, 300, (chunk, 3))
    for s in range(0, n, chunk):
        m = min(chunk, n - s)
        t = 1_700_000_000_000_000_000 + np.round(np.arange(s, s + m) * (1e9 / rate)).astype(np.int64)
        w.write(t, base[:m], light_raw=5, temperature_c=25.0 + (s // chunk) % 10 / 10)
    w.close()
    return (n // 300) * 300


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--days", type=float, default=7.0)
    ap.add_argument("--dir", default="/tmp")
    ap.add_argument("--flat-check", action="store_true", help="also a file twice as long (RSS must not grow)")
    ap.add_argument("--no-peers", action="store_true")
    ap.add_argument("--peers", default=None, help="Python (or venv folder) of the peer tools (default: $STILLPOINT_PEERS_PYTHON or /work/peers)")
    ap.add_argument("--keep", action="store_true", help="keep the written files")
    args = ap.parse_args(argv)
    d = Path(args.dir)
    d.mkdir(parents=True, exist_ok=True)
    py = sys.executable
    stillpoint = [py, "-m", "stillpoint.tools"]
    peer_py = peers_python(args.peers)
    files = [(args.days, d / f"bench_geneactiv_{args.days:g}d.bin")]
    if args.flat_check:
        files.append((2 * args.days, d / f"bench_geneactiv_{2 * args.days:g}d.bin"))
    results = {}
    try:
        for days, path in files:
            t = time.perf_counter()
            n = write_file(path, days)
            print(f"wrote {path} ({days:g} days, {n} samples, {path.stat().st_size / 1e6:.0f} MB) "
                  f"in {time.perf_counter() - t:.1f} s")
            runs = {"stillpoint inspect": stillpoint + ["inspect", str(path), "--json"]}
            if days == args.days:
                runs["numpy whole-file"] = [py, "-c", NUMPY_BASELINE, str(path)]
                if not args.no_peers and peer_py:
                    runs["skdh ReadBin"] = [peer_py, "-c", SKDH, str(path)]
                    runs["actipy read_device"] = [peer_py, "-c", ACTIPY, str(path)]
            for name, cmd in runs.items():
                m = measure(cmd)
                results[(days, name)] = m
                ok = "ok" if m["rc"] == 0 else f"FAILED rc={m['rc']}: {m['err'].strip()[-200:]}"
                print(f"  {name:<20} {m['wall']:7.2f} s wall ({m['cpu']:6.2f} s CPU)  "
                      f"{n / m['wall'] / 1e6:6.2f} M samples/s  peak RSS {m['rss_mb']:7.0f} MB  {ok}")
        base = results.get((args.days, "numpy whole-file"))
        ours = results[(args.days, "stillpoint inspect")]
        print("\nratios (same run):")
        for (days, name), m in results.items():
            if days != args.days or m["rc"] != 0:
                continue
            line = (f"  {name:<20} wall / stillpoint wall = {m['wall'] / ours['wall']:.2f}, "
                    f"CPU / stillpoint CPU = {m['cpu'] / ours['cpu']:.2f}")
            if base:
                line += (f"; wall / numpy-baseline wall = {m['wall'] / base['wall']:.2f}, "
                         f"RSS / numpy-baseline RSS = {m['rss_mb'] / base['rss_mb']:.2f}")
            print(line)
        if args.flat_check:
            big = results[(2 * args.days, "stillpoint inspect")]
            print(f"\nflat memory: stillpoint inspect peak RSS {ours['rss_mb']:.0f} MB at {args.days:g} days, "
                  f"{big['rss_mb']:.0f} MB at {2 * args.days:g} days (x{big['rss_mb'] / ours['rss_mb']:.2f}); "
                  f"wall {ours['wall']:.1f} s vs {big['wall']:.1f} s")
    finally:
        if not args.keep:
            for _, path in files:
                if path.exists():
                    path.unlink()
    return 0


if __name__ == "__main__":
    sys.exit(main())
