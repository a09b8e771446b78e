"""Dev script: cross-check our GENEActiv decoder against scikit-digital-health and actipy.

    /work/venv/bin/python tools/crosschecks/crosscheck_geneactiv.py [--data /work/shared/data/real] [--peers /work/peers]

The peers run in their own virtual environment (never a dependency of stillpoint): a small script
is executed there with subprocess; it decodes every file and saves time (local clock, as both
peers report it), acceleration (g), temperature and light to .npz. We then compare sample counts,
acceleration, times and temperature with ``GeneactivReader`` and print each difference with the
side that is right and why. Two synthetic files written with ``GeneactivWriter`` make the known
disagreements visible: a long 85.7 Hz file (600/7 vs 85.7 drift) and a file holding the raw value
-2048 (sign extension).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

PEER_SCRIPT = r'''
import json, sys, traceback, warnings
import numpy as np
warnings.simplefilter("ignore")
out_dir, files = sys.argv[1], sys.argv[2:]
report = {}
for i, f in enumerate(files):
    rep = report.setdefault(f, {})
    try:
        from skdh.io import ReadBin
        r = ReadBin().predict(file=f)
        t = np.round(np.asarray(r["time"], np.float64) * 1e9).astype(np.int64)  # local clock as UTC
        np.savez(f"{out_dir}/skdh_{i}.npz", time_ns=t, accel=r["accel"], temperature=r["temperature"],
                 light=r.get("light", np.zeros(0)))
        rep["skdh"] = {"ok": True, "file": f"skdh_{i}.npz", "fs": float(r.get("fs", float("nan")))}
    except Exception as e:
        rep["skdh"] = {"ok": False, "error": f"{type(e).__name__}: {e}"}
    try:
        import actipy
        data, info = actipy.read_device(f, lowpass_hz=None, calibrate_gravity=False,
                                        detect_nonwear=False, resample_hz=None, verbose=False)
        t = data.index.values.astype("datetime64[ns]").astype(np.int64)  # local clock, naive
        np.savez(f"{out_dir}/actipy_{i}.npz", time_ns=t, accel=data[["x", "y", "z"]].to_numpy(),
                 temperature=data["temperature"].to_numpy(np.float64))
        rep["actipy"] = {"ok": True, "file": f"actipy_{i}.npz", "fs": float(info.get("SampleRate", 0))}
    except Exception as e:
        rep["actipy"] = {"ok": False, "error": f"{type(e).__name__}: {e}"}
json.dump(report, open(f"{out_dir}/report.json", "w"))
'''


def ours(path):
    from stillpoint.drivers.geneactiv import GeneactivReader
    from stillpoint.engine.core.blocks import Block
    r = GeneactivReader(path)
    blocks = list(r)
    b = Block.concat(blocks)
    local = b.time_ns + r.info.timezone_offset_s * 10**9
    return {"time_ns": local, "accel": b.accel_g(), "raw": b.accel,
            "temperature": b.temperature_per_sample(), "qc": r.qc, "info": r.info}


def synthetic_files(d: Path) -> list[Path]:
    from stillpoint.drivers.geneactiv import GeneactivWriter
    out = []
    # 1. 85.7 Hz ("600/7"), 2000 pages = 1.94 h: readers that use 85.7 Hz drift 0.58 ms per page
    p = d / "synthetic_85p7hz_2000pages.bin"
    n = 2000 * 300
    t = 1_600_000_000_000_000_000 + np.round(np.arange(n) * 7e9 / 600).astype(np.int64)
    rng = np.random.default_rng(0)
    w = GeneactivWriter(p, rate_hz=600 / 7, partial_page="drop")
    w.write(t, rng.integers(-300, 300, (n, 3)), temperature_c=25.0)
    w.close()
    out.append(p)
    # 2. raw -2048 (0x800) and +2047 on every axis: sign extension
    p = d / "synthetic_sign_extension.bin"
    n = 3 * 300
    a = np.tile(np.array([[-2048, 2047, -1], [2047, -2048, 0], [-1, 0, -2048]]), (n // 3, 1))
    w = GeneactivWriter(p, rate_hz=100.0)
    w.write(1_600_000_000_000_000_000 + np.arange(n) * 10_000_000, a)
    w.close()
    out.append(p)
    return out


def compare(name, mine, peer_name, peer) -> list[str]:
    lines = []
    n0, n1 = mine["time_ns"].shape[0], peer["time_ns"].shape[0]
    lines.append(f"  {peer_name:<7} samples {n1} (ours {n0})")
    n = min(n0, n1)
    if n == 0:
        return lines
    da = np.abs(mine["accel"][:n] - peer["accel"][:n])
    dt = (peer["time_ns"][:n] - mine["time_ns"][:n]) / 1e6
    lines.append(f"          accel max |diff| {da.max():.3g} g; time diff (peer - ours) first "
                 f"{dt[0]:+.3f} ms, last {dt[-1]:+.3f} ms, max |.| {np.abs(dt).max():.3f} ms")
    bad = np.nonzero(da.max(axis=1) > 1e-5)[0]
    if bad.size:
        i = bad[0]
        lines.append(f"          first accel disagreement at sample {i}: ours {mine['accel'][i]} "
                     f"(raw {mine['raw'][i]}), {peer_name} {peer['accel'][i]}")
    if "temperature" in peer and peer["temperature"].shape[0] >= n:
        dT = np.abs(peer["temperature"][:n] - mine["temperature"][:n])
        lines.append(f"          temperature max |diff| {np.nanmax(dT):.3g} degC")
    return lines


FINDINGS = """
Findings (which side is right, and why) - skdh 0.17.18, actipy 3.8.3 as installed in /work/peers:
 1. Rate "85.7 Hz": Page Times are exactly 3.5 s apart (300 samples), so the true rate is 600/7 =
    85.714 Hz. skdh places samples at 1/85.7 s from each page's own Page Time: right at each page
    start, 0.58 ms late at the page end (the synthetic 85.7 Hz file shows +0.581 ms); no
    accumulation because each page is re-anchored. A reader anchoring only the first page
    (GGIRread) drifts 14 s/day. Ours: linear between consecutive Page Times -> 600/7 within every
    page. Ours is right.
 2. actipy truncates every sample time to whole milliseconds ((long) of startMillis + i*1000/f):
    up to -0.667 ms at 60 Hz and 85.7 Hz (1/60 s and 7/600 s are not whole ms), 0 at 20/50/100 Hz.
    Ours keeps nanoseconds. Ours is right.
 3. actipy writes acceleration and temperature as float32 (2e-7 g, 7.6e-7 degC differences);
    skdh and we agree to 1e-15 g (float64 of (raw*100 - offset)/gain).
 4. First page of the 50 Hz Ver4.08a files: the Page Time step 0->1 is 6.5 s (6.0 s elsewhere).
    skdh and actipy keep 50 Hz within the page and leave a 0.52 s gap, as we do (times identical);
    we additionally log a time_jump and start a new segment so no window spans the gap.
 5. Truncated final page (GGIRread test file, 2781 of 3600 characters): skdh raises "Data length is
    shorter than 3600" and returns nothing; actipy skips the partial page (4800 samples). We return
    its 231 complete samples (5031) and log truncated_page. Ours keeps data that is really there.
 6. Raw 0x800 (= -2048): the spec notes actipy @a39c76a sign-extends with '> 2048' (0x800 -> +2048).
    The installed actipy 3.8.3 uses '>= 2048' (GENEActivReader.java decodePageSamples) and agrees
    with skdh and us on the synthetic file holding -2048 on every axis: fixed upstream.
 7. Times: both peers report the device's local clock as naive times; we convert to UTC with the
    header Time Zone (sign, hours and minutes). The comparison above adds the offset back.
"""


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default="/work/shared/data/real")
    ap.add_argument("--peers", default="/work/peers", help="virtual environment with skdh and actipy")
    args = ap.parse_args(argv)
    files = sorted(Path(args.data).glob("geneactiv_*.bin"))
    with tempfile.TemporaryDirectory() as td:
        td = Path(td)
        files += synthetic_files(td)
        py = Path(args.peers) / "bin" / "python"
        r = subprocess.run([str(py), "-c", PEER_SCRIPT, str(td)] + [str(f) for f in files],
                           capture_output=True, text=True, timeout=1800)
        if r.returncode != 0:
            print(r.stderr, file=sys.stderr)
            return 1
        report = json.loads((td / "report.json").read_text())
        for f in files:
            mine = ours(f)
            qc = [(e.index, e.reason) for e in mine["qc"].events]
            print(f"{f.name}: ours {mine['time_ns'].shape[0]} samples, QC {qc}")
            for peer_name in ("skdh", "actipy"):
                rep = report[str(f)][peer_name]
                if not rep["ok"]:
                    print(f"  {peer_name:<7} FAILED: {rep['error']}")
                    continue
                z = np.load(td / rep["file"])
                print("\n".join(compare(f.name, mine, peer_name, {k: z[k] for k in z.files})))
    print(FINDINGS)
    return 0


if __name__ == "__main__":
    sys.exit(main())
