"""Dev script: cross-check our .cwa decoder against independent readers (not a test).

Runs cwa-reader-rs, scikit-digital-health and actipy from the separate peers venv
(/work/peers, via subprocesses; never a dependency) on every real .cwa recording and compares
with ``CwaReader``: sample counts, first/last sample times, per-sample time differences,
accelerometer values (g) and temperature. ``.cwa.gz`` files are decompressed to a temporary
file for the peers (we read the .gz directly). Prints one table per file. Run:

    STILLPOINT_REAL_DATA=/work/shared/data/real /work/venv/bin/python tools/crosschecks/crosscheck_peers.py

Columns: n (samples), dn (peer - ours), t0/t_end (ms, peer - ours), |dt| median/max over the
aligned samples (ms), |da| max (g), temp0 (the peer's first temperature and, for comparison,
the raw ADC code pushed through the known formulas).
"""

from __future__ import annotations

import gzip
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

PEERS_PY = "/work/peers/bin/python"

PEER_CODE = {
    "cwa-reader-rs": r"""
import sys, numpy as np, cwa_reader_rs
df = cwa_reader_rs.read_cwa_file(sys.argv[1])
t = df.index.to_numpy().astype("datetime64[ns]").astype(np.int64)
a = df[["acc_x", "acc_y", "acc_z"]].to_numpy(np.float64)
extra = {}
if "gyro_x" in df:
    extra["gyro"] = df[["gyro_x", "gyro_y", "gyro_z"]].to_numpy(np.float64)
np.savez(sys.argv[2], time_ns=t, accel=a, temperature=df["temperature"].to_numpy(np.float64),
         battery=df["battery"].to_numpy(np.float64), light=df["light"].to_numpy(np.float64), **extra)
""",
    "skdh": r"""
import sys, warnings, numpy as np
warnings.simplefilter("ignore")
from skdh.io import ReadCwa
r = ReadCwa().predict(file=sys.argv[1])
t = np.rint(np.asarray(r["time"], np.float64) * 1e9).astype(np.int64)
extra = {"gyro": np.asarray(r["gyro"], np.float64)} if "gyro" in r else {}
np.savez(sys.argv[2], time_ns=t, accel=np.asarray(r["accel"], np.float64),
         temperature=np.asarray(r["temperature"], np.float64), **extra)
""",
    "actipy": r"""
import sys, numpy as np, actipy
d, info = actipy.read_device(sys.argv[1], lowpass_hz=None, calibrate_gravity=False,
                             detect_nonwear=False, resample_hz=None, verbose=False)
t = d.index.to_numpy().astype("datetime64[ns]").astype(np.int64)
np.savez(sys.argv[2], time_ns=t, accel=d[["x", "y", "z"]].to_numpy(np.float64),
         temperature=d["temperature"].to_numpy(np.float64), light=d["light"].to_numpy(np.float64))
""",
}


def ours(path: Path) -> dict:
    from stillpoint.drivers.cwa import CwaReader

    r = CwaReader(path)
    t, a, g, temp, traw, batt, light = [], [], [], [], [], [], []
    for b in r:
        u = b.unit_of_sample()
        t.append(b.time_ns)
        a.append(b.accel_g())
        if b.gyro is not None:
            g.append(b.gyro_dps())
        temp.append(b.temperature_c[u])
        traw.append(b.temperature_raw[u])
        batt.append(b.battery_v[u])
        light.append(b.light[u])
    cat = np.concatenate
    return {"time_ns": cat(t), "accel": cat(a), "gyro": cat(g) if g else None,
            "temperature": cat(temp), "temperature_raw": cat(traw), "battery": cat(batt),
            "light_raw": cat(light),
            "qc": [(e.index, e.reason) for e in r.qc.events], "segments": r.qc.segments}


def peer(name: str, path: Path, tmp: Path) -> dict:
    out = tmp / f"{name}.npz"
    p = subprocess.run([PEERS_PY, "-c", PEER_CODE[name], str(path), str(out)],
                       capture_output=True, text=True, timeout=900)
    if p.returncode != 0:
        last = (p.stderr.strip().splitlines() or ["?"])[-1]
        return {"error": last[:120]}
    with np.load(out) as z:
        return {k: z[k] for k in z.files}


def compare(o: dict, q: dict) -> dict:
    if "error" in q:
        return q
    n_o, n_q = o["time_ns"].shape[0], q["time_ns"].shape[0]
    res = {"n": n_q, "dn": n_q - n_o,
           "t0_ms": (q["time_ns"][0] - o["time_ns"][0]) / 1e6,
           "tend_ms": (q["time_ns"][-1] - o["time_ns"][-1]) / 1e6,
           "temp0": float(q["temperature"][0])}
    if n_q == n_o:
        io = iq = np.arange(n_o)
    else:  # align each of our samples with the peer sample nearest in time
        iq = np.clip(np.searchsorted(q["time_ns"], o["time_ns"]), 1, n_q - 1)
        iq = np.where(np.abs(q["time_ns"][iq - 1] - o["time_ns"]) < np.abs(q["time_ns"][iq] - o["time_ns"]),
                      iq - 1, iq)
        io = np.arange(n_o)
    dt = np.abs(q["time_ns"][iq] - o["time_ns"][io]) / 1e6
    da = np.abs(q["accel"][iq] - o["accel"][io]).max(axis=1)
    res.update(dt_med_ms=float(np.median(dt)), dt_max_ms=float(dt.max()), da_max_g=float(da.max()),
               da_bad=int((da > 1e-6).sum()))
    if o["gyro"] is not None and "gyro" in q:
        res["dg_max_dps"] = float(np.abs(q["gyro"][iq] - o["gyro"][io]).max())
    if "battery" in q:
        res["dbatt_max_v"] = float(np.abs(q["battery"][iq] - o["battery"][io]).max())
    if "light" in q:
        raw = o["light_raw"][io].astype(np.float64)
        forms = {"10^((raw+512)*6/1024) (docs)": 10 ** ((raw + 512) * 6 / 1024), "10^(raw/341)": 10 ** (raw / 341)}
        res["light_formula"] = next((k for k, v in forms.items()
                                     if np.allclose(q["light"][iq], v, rtol=1e-4)), "?")
    return res


def temperature_formula(temp0: float, raw: int) -> str:
    forms = {"raw*75/256-50 (MCP9700)": raw * 75 / 256 - 50, "raw*0.15-20.5 (MCP9701)": raw * 0.15 - 20.5,
             "(raw-171)/3.142": (raw - 171) / 3.142, "raw*19/64-50": raw * 19 / 64 - 50}
    best = min(forms, key=lambda k: abs(forms[k] - temp0))
    return best if abs(forms[best] - temp0) < 0.05 else "?"


def main() -> int:
    data = Path(os.environ.get("STILLPOINT_REAL_DATA", "/work/shared/data/real"))
    files = sorted(list(data.glob("*.cwa")) + list(data.glob("*.cwa.gz")))
    if not Path(PEERS_PY).exists():
        print(f"no peers venv at {PEERS_PY}")
        return 1
    summary = {}
    with tempfile.TemporaryDirectory() as td:
        tmp = Path(td)
        for f in files:
            plain = f
            if f.suffix == ".gz":
                plain = tmp / f.stem
                with gzip.open(f, "rb") as src, open(plain, "wb") as dst:
                    shutil.copyfileobj(src, dst)
            o = ours(f)
            print(f"\n== {f.name}: ours n={o['time_ns'].shape[0]:,} segments={o['segments']} "
                  f"t0={np.datetime64(int(o['time_ns'][0]), 'ns')} temp0={o['temperature'][0]:.3f} C "
                  f"(raw {o['temperature_raw'][0]}) qc={o['qc'][:8]}")
            print(f"   {'peer':14s} {'n':>9s} {'dn':>6s} {'t0 ms':>8s} {'tend ms':>8s} {'|dt| med':>9s} "
                  f"{'|dt| max':>9s} {'|da| max':>9s} {'#da>0':>6s}  temp0 (formula)")
            summary[f.name] = {}
            for name in PEER_CODE:
                c = compare(o, peer(name, plain, tmp))
                summary[f.name][name] = c
                if "error" in c:
                    print(f"   {name:14s} FAILED: {c['error']}")
                    continue
                print(f"   {name:14s} {c['n']:9,d} {c['dn']:6d} {c['t0_ms']:8.2f} {c['tend_ms']:8.2f} "
                      f"{c['dt_med_ms']:9.3f} {c['dt_max_ms']:9.3f} {c['da_max_g']:9.2g} {c['da_bad']:6d}  "
                      f"{c['temp0']:.3f} ({temperature_formula(c['temp0'], int(o['temperature_raw'][0]))})")
                more = {k: c[k] for k in ("dg_max_dps", "dbatt_max_v", "light_formula") if k in c}
                if more:
                    print(f"   {'':14s} {more}")
    if "--json" in sys.argv:
        print(json.dumps(summary, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
