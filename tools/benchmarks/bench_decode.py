"""Benchmark: decode speed and peak memory of the .cwa reader on a week-long recording.

Writes a 7-day (``--days``) 100 Hz packed AX3 file with ``CwaWriter`` (about 60.5 M samples,
258 MB; realistic content: gravity + noise + slow orientation changes, a 0.75 % slow clock,
temperature drifting with time), then times, each in a fresh subprocess (wall time and peak
RSS of that child, via ``getrusage(RUSAGE_CHILDREN)`` in a one-shot meter process):

* ``stillpoint inspect FILE --json`` (a full pass through ``CwaReader``),
* a full ``CwaReader`` pass in Python (no CLI around it),
* a plain numpy whole-file decode (the in-memory baseline: read all, decode all at once),
* cwa-reader-rs from the peers' environment (``--peers``; and, with ``--all-peers``, actipy and scikit-digital-health),

and the same two passes over the realistic ``stillpoint simulate`` file of the same length
(``benchlib.realistic_recording``: default wearer, seed 3; listed first, kept in ``--dir`` for
the other benchmarks), and prints the figures and their ratios measured in the same run (machines are noisy: compare
ratios, not seconds). With several ``--days`` values (default ``7 14``) it also checks that the
reader's peak RSS does not grow with the file length. Run:

    /work/venv/bin/python tools/benchmarks/bench_decode.py [--days 7 14] [--dir /tmp/stillpoint-bench]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from benchlib import best_of, peers_python, realistic_recording

NS = 1_000_000_000

READER_PASS = r"""
import sys
from stillpoint.drivers.cwa import CwaReader
n = 0
r = CwaReader(sys.argv[1])
for b in r:
    n += b.n
print(n, r.qc.valid, r.qc.skipped)
"""

NUMPY_BASELINE = r"""
import sys
import numpy as np
from stillpoint.drivers.cwa_layout import SECTOR_DTYPE, unpack_timestamps
raw = np.fromfile(sys.argv[1], np.uint8, offset=1024)
sec = raw[: raw.size // 512 * 512].view(SECTOR_DTYPE)
ok = sec.view("<u2").reshape(-1, 256).sum(axis=1, dtype=np.uint16) == 0
sec = sec[ok]
v = np.ascontiguousarray(sec.view(np.uint8).reshape(-1, 512)[:, 30:510]).view("<u4").reshape(-1)
e = (v >> 30).astype(np.int16)
xyz = np.empty((v.size, 3), np.int16)
for i, s in enumerate((0, 10, 20)):
    f = ((v >> s) & 0x3FF).astype(np.int16)
    xyz[:, i] = ((f ^ 0x200) - 0x200) << e
secs, good = unpack_timestamps(sec["timestamp"])
f15 = (sec["device_fractional"] & 0x7FFF).astype(np.int64)
idx = np.arange(sec.size) * 120 + sec["timestamp_offset"] + ((f15 << 1) * 100 >> 16)
t_anchor = secs * 1e9 + f15 * (1e9 / 32768)
t = np.interp(np.arange(v.size, dtype=np.float64), idx, t_anchor - t_anchor[0]).astype(np.int64)
print(v.size, xyz[:, 2].mean(), t[-1])
"""

RS = r"""
import sys, cwa_reader_rs
df = cwa_reader_rs.read_cwa_file(sys.argv[1])
print(len(df))
"""

ACTIPY = r"""
import sys, actipy
data, info = actipy.read_device(sys.argv[1], lowpass_hz=None, calibrate_gravity=False,
                                detect_nonwear=False, resample_hz=None, verbose=False)
print(len(data))
"""

SKDH = r"""
import sys
from skdh.io import ReadCwa
r = ReadCwa().predict(file=sys.argv[1])
print(len(r["accel"]))
"""


def write_recording(path: Path, days: float, rate: float = 100.0, chunk: int = 1_200_000):
    """A realistic week at 100 Hz, written chunk by chunk (memory flat).

    Returns (samples, seconds spent inside CwaWriter.write, i.e. without making the data)."""
    from stillpoint.drivers.cwa import CwaWriter

    n_total = int(days * 86400 * rate)
    period = NS / (rate * 0.9925)  # device clock runs 0.75 % slow (typical of real AX3 files)
    t0 = 1_700_000_000 * NS
    rng = np.random.default_rng(42)
    spent = 0.0
    with CwaWriter(path, device_id=42424, session_id=7, rate_hz=rate, range_g=8,
                   metadata={"_sc": "bench", "_p": "left wrist"}) as w:
        for i0 in range(0, n_total, chunk):
            n = min(chunk, n_total - i0)
            i = np.arange(i0, i0 + n)
            ang = 0.3 * np.sin(i / (rate * 3600.0 * 3)) + 0.2 * np.sin(i / (rate * 600.0))
            g = np.stack([256 * np.sin(ang), 40 * np.cos(i / (rate * 900.0)), 256 * np.cos(ang)], axis=1)
            a = (g + rng.normal(0, 6, (n, 3))) / 4
            a = (np.clip(np.rint(a), -512, 511) * 4).astype(np.int16)
            temp = (256 + 10 * np.sin(i / (rate * 86400.0) * 2 * np.pi)).astype(np.int64)
            t = t0 + np.rint(i * period).astype(np.int64)
            battery = 190 - (i * 60 // max(n_total, 1))
            s = time.perf_counter()
            w.write(t, a, temperature_raw=temp, battery_raw=battery, light_raw=200)
            spent += time.perf_counter() - s
        s = time.perf_counter()
    spent += time.perf_counter() - s  # the final flush and close
    return n_total, spent


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--days", type=float, nargs="+", default=[7.0, 14.0])
    ap.add_argument("--dir", default="/tmp/stillpoint-bench")
    ap.add_argument("--repeat", type=int, default=2,
                    help="runs per measurement (best wall and CPU, max RSS); CPU time (user+sys) is "
                         "less sensitive to other load than wall time")
    ap.add_argument("--all-peers", action="store_true", help="also time actipy and skdh (slow, GBs)")
    ap.add_argument("--peers", default=None, help="Python of the peer tools' environment (default: $STILLPOINT_PEERS_PYTHON or /work/peers/bin/python)")
    ap.add_argument("--keep", action="store_true", help="keep the generated files")
    args = ap.parse_args(argv)
    d = Path(args.dir)
    d.mkdir(parents=True, exist_ok=True)
    py = sys.executable
    stillpoint = str(Path(py).with_name("stillpoint"))
    peers_py = peers_python(args.peers)
    have_peers = peers_py is not None
    results: dict[float, dict[str, dict]] = {}
    for k, days in enumerate(args.days):
        path = d / f"bench_{days:g}d.cwa"
        t = time.perf_counter()
        n, in_writer = write_recording(path, days)
        wt = time.perf_counter() - t
        print(f"\n== {days:g} days: {n:,} samples, {path.stat().st_size / 1e6:.0f} MB "
              f"(made and written in {wt:.1f} s; inside CwaWriter.write {in_writer:.1f} s = "
              f"{n / in_writer / 1e6:.0f} M samples/s)")
        wear = realistic_recording(d, days)
        cmds = {
            "inspect --json, wear": [stillpoint, "inspect", str(wear), "--json"],
            "CwaReader pass, wear": [py, "-c", READER_PASS, str(wear)],
            "stillpoint inspect --json": [stillpoint, "inspect", str(path), "--json"],
            "CwaReader full pass": [py, "-c", READER_PASS, str(path)],
        }
        if k == 0:  # baselines once, on the first (7-day) file
            cmds["numpy whole-file decode"] = [py, "-c", NUMPY_BASELINE, str(path)]
            if have_peers:
                cmds["cwa-reader-rs"] = [peers_py, "-c", RS, str(path)]
                if args.all_peers:
                    cmds["actipy"] = [peers_py, "-c", ACTIPY, str(path)]
                    cmds["skdh"] = [peers_py, "-c", SKDH, str(path)]
        res = best_of(cmds, args.repeat)
        for name, r in res.items():
            status = "" if r["rc"] == 0 else f"  FAILED rc={r['rc']}: {r['err'].strip().splitlines()[-1:]}"
            print(f"  {name:28s} {r['wall']:7.2f} s wall {r['cpu']:7.2f} s CPU {r['rss_mb']:7.0f} MB peak RSS"
                  f"{status}")
        results[days] = res
        if not args.keep:
            path.unlink()

    first = results[args.days[0]]
    ours = first["stillpoint inspect --json"]
    print("\n== ratios (same run)")
    for name, r in first.items():
        if name != "stillpoint inspect --json" and r["rc"] == 0:
            print(f"  {name:28s} wall x{r['wall'] / ours['wall']:5.2f} of inspect, "
                  f"CPU x{r['cpu'] / ours['cpu']:5.2f}, RSS x{r['rss_mb'] / ours['rss_mb']:5.1f}")
    ok = True
    if "cwa-reader-rs" in first and first["cwa-reader-rs"]["rc"] == 0:
        speed = first["cwa-reader-rs"]["wall"] / ours["wall"]
        print(f"  target inspect >= 2x faster than cwa-reader-rs: x{speed:.2f} "
              f"-> {'MET' if speed >= 2 else 'NOT MET'}")
        ok &= speed >= 2
    print(f"  target peak RSS < 200 MB: {ours['rss_mb']:.0f} MB -> "
          f"{'MET' if ours['rss_mb'] < 200 else 'NOT MET'}")
    ok &= ours["rss_mb"] < 200
    if len(args.days) > 1:
        rss = [results[dd]["stillpoint inspect --json"]["rss_mb"] for dd in args.days]
        flat = max(rss) / min(rss)
        print(f"  flat memory: inspect peak RSS {', '.join(f'{x:.0f}' for x in rss)} MB for "
              f"{', '.join(f'{dd:g}' for dd in args.days)} days (x{flat:.2f}) -> "
              f"{'MET' if flat < 1.15 else 'NOT MET'}")
        ok &= flat < 1.15
        walls = [results[dd]["CwaReader full pass"]["wall"] for dd in args.days]
        print(f"  scaling: CwaReader wall {', '.join(f'{x:.2f}' for x in walls)} s")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
