"""Shared pieces of the benchmark scripts (tools/benchmarks/bench_*.py).

* ``measure(cmd)``: run a command in a fresh child under a one-shot meter process and return its
  wall time, CPU time (user + system) and peak RSS (``getrusage(RUSAGE_CHILDREN)`` of the meter,
  i.e. of that child alone), exit code and output.
* ``best_of(cmds, repeat)``: run several commands interleaved (A B C, A B C, ...) so slow phases
  of a busy machine hit all of them alike; keep the best wall and CPU and the largest RSS.
* ``peers_python()``: the Python of the separate environment holding the peer tools
  (cwa-reader-rs, scikit-digital-health, actipy), from ``STILLPOINT_PEERS_PYTHON`` or the
  ``--peers`` option; peers are only ever run as child processes, never imported.

The scripts import this as a sibling module (``python tools/benchmarks/bench_x.py`` puts
tools/benchmarks/ on sys.path).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Optional

DEFAULT_PEERS_PYTHON = "/work/peers/bin/python"
THROWAWAY_SKDH_PYTHON = "/tmp/skdh-venv/bin/python"
# python3 -m venv /tmp/actipy-venv && /tmp/actipy-venv/bin/pip install actipy (needs a Java runtime)
THROWAWAY_ACTIPY_PYTHON = "/tmp/actipy-venv/bin/python"
REALISTIC_SEED = 3

METER = r"""
import json, resource, subprocess, sys, time
cmd = json.loads(sys.argv[1])
t = time.perf_counter()
p = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
wall = time.perf_counter() - t
ru = resource.getrusage(resource.RUSAGE_CHILDREN)
print(json.dumps({"wall": wall, "cpu": ru.ru_utime + ru.ru_stime, "rss_mb": ru.ru_maxrss / 1024,
                  "rc": p.returncode, "out": p.stdout, "err": p.stderr[-2000:]}))
"""


# A full pass of the drivers over a recording (every Block decoded): the decode baseline.
DECODE_PASS = r"""
import sys
from stillpoint.drivers import open_recording
n = 0
with open_recording(sys.argv[1]) as src:
    for b in src:
        n += b.n
print(n)
"""

# scikit-digital-health's read + autocalibration of a .cwa (run with the peers' Python).
SKDH_READ_AUTOCAL = r"""
import sys, warnings
warnings.simplefilter("ignore")
from skdh.io import ReadCwa
from skdh.preprocessing import CalibrateAccelerometer
d = ReadCwa().predict(file=sys.argv[1])
r = CalibrateAccelerometer().predict(time=d["time"], accel=d["accel"], fs=d.get("fs"),
                                     temperature=d.get("temperature"))
print({k: (v.tolist() if hasattr(v, "tolist") else v) for k, v in r.items()
       if k in ("offset", "scale", "temperature scale", "temp_scale")})
"""

# ... the same plus ENMO per sample on the calibrated stream (what process computes besides logging).
SKDH_READ_AUTOCAL_ENMO = r"""
import sys, warnings
warnings.simplefilter("ignore")
import numpy as np
from skdh.io import ReadCwa
from skdh.preprocessing import CalibrateAccelerometer
d = ReadCwa().predict(file=sys.argv[1])
r = CalibrateAccelerometer().predict(time=d["time"], accel=d["accel"], fs=d.get("fs"),
                                     temperature=d.get("temperature"))
a = r.get("accel", d["accel"])
enmo = np.maximum(np.linalg.norm(a, axis=1) - 1.0, 0.0)
# skdh calibrates only recordings of min_hours (72 h by default) or more: say whether it did
print(a.shape[0], float(enmo.mean()), "calibrated" if "accel" in r else "not-calibrated")
"""

# actipy's read_device with its defaults (20 Hz low-pass, gravity calibration, nonwear
# detection, uniform resampling; its Java reader decodes the .cwa) and ENMO in 5 s epochs (run
# with actipy's own Python).
ACTIPY_READ_ENMO = r"""
import sys, warnings
warnings.simplefilter("ignore")
import numpy as np
import actipy
data, info = actipy.read_device(sys.argv[1], verbose=False)
enmo = (np.sqrt(np.square(data[["x", "y", "z"]]).sum(axis=1)) - 1.0).clip(lower=0.0)
epochs = enmo.resample("5s").mean()
print(len(data), len(epochs), float(epochs.mean() * 1000.0), "calibrated" if info.get("CalibOK") else "not-calibrated")
"""


def measure(cmd: list, env: Optional[dict] = None) -> dict:
    """{"wall", "cpu", "rss_mb", "rc", "out", "err"} of one run of ``cmd`` in a fresh child.

    The child may write bytecode whatever the caller's ``PYTHONDONTWRITEBYTECODE``: an installed
    package has its ``.pyc`` files, and compiling ~100 modules from source again in every child
    (0.2-0.4 CPU-s a run here) would be counted as the command's cost."""
    env = dict(os.environ if env is None else env)
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    out = subprocess.run([sys.executable, "-c", METER, json.dumps([str(c) for c in cmd])],
                         capture_output=True, text=True, check=True, env=env).stdout
    return json.loads(out)


def best_of(cmds: dict, repeat: int = 1) -> dict:
    """Per command name: the run with the best wall time, with the best CPU time and the largest
    peak RSS over the repeats."""
    runs: dict = {name: [] for name in cmds}
    for _ in range(max(1, repeat)):
        for name, cmd in cmds.items():
            runs[name].append(measure(cmd))
    out = {}
    for name, rs in runs.items():
        best = dict(min(rs, key=lambda r: r["wall"]))
        best["cpu"] = min(r["cpu"] for r in rs)
        best["rss_mb"] = max(r["rss_mb"] for r in rs)
        out[name] = best
    return out


def actipy_python(option: Optional[str] = None) -> Optional[str]:
    """The Python of the virtual environment holding actipy (option, else
    $STILLPOINT_ACTIPY_PYTHON, else /tmp/actipy-venv), or None when it does not exist."""
    p = option or os.environ.get("STILLPOINT_ACTIPY_PYTHON") or THROWAWAY_ACTIPY_PYTHON
    if Path(p).is_dir():
        p = str(Path(p) / "bin" / "python")
    return p if Path(p).exists() else None


def peers_python(option: Optional[str] = None) -> Optional[str]:
    """The peer tools' Python (option, else $STILLPOINT_PEERS_PYTHON, else the dev default), or
    None when it does not exist (the scripts then say the peers were skipped)."""
    p = option or os.environ.get("STILLPOINT_PEERS_PYTHON")
    if not p:
        p = THROWAWAY_SKDH_PYTHON if Path(THROWAWAY_SKDH_PYTHON).exists() else DEFAULT_PEERS_PYTHON
    if Path(p).is_dir():  # a virtual environment's folder
        p = str(Path(p) / "bin" / "python")
    return p if Path(p).exists() else None


def realistic_recording(workdir: Path, days: float, rate: float = 100.0,
                        seed: int = REALISTIC_SEED, wearer: str = "default") -> Path:
    """``stillpoint simulate`` output with the named wearer (``--wearer``; the default wearer
    unless told) and the default sensor (AX3 at the wrist), written once into ``workdir`` (with
    its truth and labels, as the command writes them)."""
    import time
    tag = "" if wearer == "default" else f"{wearer}_"
    path = Path(workdir) / f"wear_{tag}{days:g}d_{rate:g}hz_s{seed}.cwa"
    if path.is_file():
        return path
    from stillpoint.engine.sim import simulate_recording, wearer_params
    t = time.perf_counter()
    tmp = path.with_name(path.stem + ".part.cwa")
    simulate_recording(tmp, days=days, hz=rate, seed=seed, truth_path=path.with_suffix(".truth.json"),
                       labels_path=path.with_suffix(".labels.csv"), wearer=wearer_params(wearer))
    os.replace(tmp, path)
    print(f"wrote {path.name} ({path.stat().st_size / 1e6:.0f} MB, simulated {wearer} wearer) in "
          f"{time.perf_counter() - t:.0f} s", flush=True)
    return path


def real_recordings() -> list:
    """The real recordings under ``$STILLPOINT_REAL_DATA`` (.cwa, .cwa.gz, .bin), sorted by name;
    [] when it is not set."""
    d = os.environ.get("STILLPOINT_REAL_DATA")
    if not d or not Path(d).is_dir():
        return []
    return sorted(p for p in Path(d).iterdir()
                  if p.name.endswith((".cwa", ".cwa.gz", ".bin")) and p.is_file())
