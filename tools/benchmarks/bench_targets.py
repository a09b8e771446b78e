"""`process` (full and lean log, batch and online) against skdh, actipy and the plain decode, in
one run, on the simulator's default wearer and on its wearer with long still periods.

    python tools/benchmarks/bench_targets.py [--days 7] [--wearers default,still] [--repeat 3]
                                             [--online-days 1,14] [--skdh PY] [--actipy PY]

For each wearer (``stillpoint simulate --wearer NAME``, AX3 at the wrist, 100 Hz, seed 3;
``benchlib.realistic_recording``, written once into ``--workdir`` and reused) the commands run
in rounds, one after the other in each round (decode, process batch full, lean, online, skdh,
actipy; then again), each in a fresh child (wall, CPU = user + system of the child and its
children, peak RSS). Of ``--repeat`` rounds the least wall and the least CPU are kept separately,
and the largest peak RSS. Then, for every length of ``--online-days`` not already measured,
batch and online alternate the same way (online refits must not grow faster than the file).

* plain decode: one reader pass over the whole file (the drivers' decode);
* ``stillpoint process --mode batch`` (full log, with the epoch and day tables, as the command
  runs by default), ``--log lean`` (no per-sample streams), ``--mode online`` (refits every 12 h,
  then the tables from a second pass with the final estimate), and batch and online with
  ``--no-tables`` (the differences are what the tables cost each mode, for online its second
  pass);
* scikit-digital-health: read + autocalibration + ENMO per sample (``--skdh``, else
  $STILLPOINT_PEERS_PYTHON, else /tmp/skdh-venv); it calibrates only files of 72 h or more;
* actipy: ``read_device`` with its defaults (20 Hz low-pass, gravity calibration, nonwear
  detection, uniform resampling; Java reads the .cwa) + ENMO in 5 s epochs (``--actipy``, else
  $STILLPOINT_ACTIPY_PYTHON, else /tmp/actipy-venv).

Peers run from their own virtual environments, never imported. A command that fails is reported
in one line and left out of the ratios; the run goes on. The last lines compare each ratio with
its target and say met or not met.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from pathlib import Path

from benchlib import (ACTIPY_READ_ENMO, DECODE_PASS, SKDH_READ_AUTOCAL_ENMO, actipy_python,
                      best_of, peers_python, realistic_recording)

# The targets (wall and CPU ratios; same run, least of the rounds).
TARGETS = {
    "full_vs_skdh_wall": 1.5,  # skdh wall / process full wall >= 1.5
    "full_vs_actipy_wall": 3.0,  # actipy wall / process full wall >= 3
    "lean_vs_skdh_wall": 2.0,  # skdh wall / process lean wall >= 2
    "lean_vs_skdh_cpu": 1.5,  # skdh CPU / process lean CPU >= 1.5
    "online_vs_batch_cpu": 1.1,  # online CPU / batch CPU <= 1.1
    "peak_rss_mb": 300.0,  # every process run below 300 MB
}

LABELS = {"decode": "plain decode (reader, whole file)",
          "batch": "process --mode batch (full log)",
          "lean": "process --mode batch --log lean",
          "online": "process --mode online (full log)",
          "batch_nt": "process --mode batch --no-tables",
          "online_nt": "process --mode online --no-tables",
          "skdh": "skdh read + autocalibration + ENMO",
          "actipy": "actipy read_device + ENMO 5 s epochs"}


def commands(path: Path, wd: Path, skdh: str | None, actipy: str | None, *,
             modes=tuple(LABELS)) -> dict:
    sp = [sys.executable, "-m", "stillpoint.tools", "process", path, "-q", "--overwrite"]
    stem = wd / f"bt_{path.stem}"
    all_cmds = {
        "decode": [sys.executable, "-c", DECODE_PASS, path],
        "batch": sp + ["-o", f"{stem}.batch.mcap", "--mode", "batch",
                       "--summary", f"{stem}.batch.json"],
        "lean": sp + ["-o", f"{stem}.lean.mcap", "--mode", "batch", "--log", "lean"],
        "online": sp + ["-o", f"{stem}.online.mcap", "--mode", "online",
                        "--summary", f"{stem}.online.json"],
        # without the tables: an online run then makes no second pass (engine/tables/
        # estimate_pass.py), so the two differences give that pass's cost
        "batch_nt": sp + ["-o", f"{stem}.batch_nt.mcap", "--mode", "batch", "--no-tables"],
        "online_nt": sp + ["-o", f"{stem}.online_nt.mcap", "--mode", "online", "--no-tables"],
    }
    if skdh:
        all_cmds["skdh"] = [skdh, "-c", SKDH_READ_AUTOCAL_ENMO, path]
    if actipy:
        all_cmds["actipy"] = [actipy, "-c", ACTIPY_READ_ENMO, path]
    return {k: v for k, v in all_cmds.items() if k in modes}


def run(path: Path, wd: Path, repeat: int, skdh, actipy, modes) -> dict:
    res = best_of(commands(path, wd, skdh, actipy, modes=modes), repeat)
    for name, r in res.items():
        if r["rc"] != 0:
            last = (r["err"].strip().splitlines() or ["?"])[-1]
            print(f"  {name} failed on {path.name} (exit {r['rc']}): {last}", flush=True)
            r["failed"] = True
    for f in wd.glob(f"bt_{path.stem}.*"):
        if f.suffix == ".json":
            res.setdefault("_summaries", {})[f.name.split(".")[-2]] = json.loads(f.read_text())
        f.unlink()
    return res


def _mg(v) -> str:
    return "n/a" if v is None else f"{v:.2f} mg"


def ok(res: dict, name: str) -> bool:
    return name in res and not res[name].get("failed")


def verdict(value: float, target: float, at_least: bool) -> str:
    met = value >= target if at_least else value <= target
    return f"{value:.2f}x ({'>=' if at_least else '<='} {target:g}x: {'met' if met else 'NOT met'})"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--days", type=float, default=7.0, help="length of the main recordings")
    ap.add_argument("--rate", type=float, default=100.0)
    ap.add_argument("--wearers", default="default,still", help="simulated wearers (--wearer)")
    ap.add_argument("--repeat", type=int, default=3, help="rounds (least wall and CPU kept)")
    ap.add_argument("--online-days", default="1,14",
                    help="other lengths for online vs batch ('' skips)")
    ap.add_argument("--workdir", default=os.path.join(tempfile.gettempdir(), "stillpoint_bench"))
    ap.add_argument("--skdh", default=None, help="Python (or venv) with scikit-digital-health "
                    "('none' skips)")
    ap.add_argument("--actipy", default=None, help="Python (or venv) with actipy ('none' skips)")
    a = ap.parse_args(argv)
    wd = Path(a.workdir)
    wd.mkdir(parents=True, exist_ok=True)
    skdh = None if a.skdh == "none" else peers_python(a.skdh)
    actipy = None if a.actipy == "none" else actipy_python(a.actipy)
    for name, py, how in (("skdh", skdh, "--skdh, $STILLPOINT_PEERS_PYTHON, /tmp/skdh-venv"),
                          ("actipy", actipy, "--actipy, $STILLPOINT_ACTIPY_PYTHON, /tmp/actipy-venv")):
        print(f"{name}: {py}" if py else f"{name} skipped: no Python for it ({how})", flush=True)
    wearers = [w.strip() for w in a.wearers.split(",") if w.strip()]
    recs = {w: realistic_recording(wd, a.days, a.rate, wearer=w) for w in wearers}
    cols = {}
    for w, path in recs.items():
        print(f"measuring {path.name} ({a.repeat} rounds) ...", flush=True)
        cols[w] = run(path, wd, a.repeat, skdh, actipy, tuple(LABELS))
    online_days = sorted({float(x) for x in a.online_days.split(",") if x.strip()} - {a.days})
    extra = {}
    for d in online_days:
        for w in wearers:
            path = realistic_recording(wd, d, a.rate, wearer=w)
            print(f"measuring {path.name}, batch and online ({a.repeat} rounds) ...", flush=True)
            extra[(w, d)] = run(path, wd, a.repeat, None, None, ("batch", "online"))

    print(f"\nload average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores; each figure the least "
          f"of {max(1, a.repeat)} rounds (wall and CPU separately), the largest peak RSS")
    for w, path in recs.items():
        s = cols[w].get("_summaries", {}).get("batch")
        if s:
            c = s["calibration"]
            print(f"{w} wearer: {path.name}: {s['samples']:,} samples, "
                  f"{s['duration_s'] / 86400:.2f} days, {path.stat().st_size / 1e6:.0f} MB; "
                  f"{s['nonmovement_windows']:,} nonmovement windows of {s['windows']:,}; "
                  f"calibration {c['status']} ({_mg(c.get('error_before_mg'))} -> "
                  f"{_mg(c.get('error_after_mg'))})")
    head = "".join(f" | {w + ' wearer':>24s}" for w in cols)
    print(f"{'command (wall s / CPU s / peak RSS MB)':42s}{head}")
    for key, label in LABELS.items():
        cells = []
        for w in cols:
            r = cols[w].get(key)
            if r is None or r.get("failed"):
                cells.append(f" | {'skipped' if r is None else 'failed':>24s}")
            else:
                cells.append(f" | {r['wall']:7.2f} {r['cpu']:7.2f} {r['rss_mb']:8.0f}")
        print(f"{label:42s}" + "".join(cells))
    for (w, d), r in extra.items():
        print(f"{f'{d:g} days, {w} wearer':42s}" + "".join(
            f" | {k} {r[k]['wall']:6.2f} {r[k]['cpu']:6.2f} {r[k]['rss_mb']:5.0f}"
            for k in ("batch", "online") if ok(r, k)))

    print("ratios against the targets (same run):")

    def line(label, f, need):
        cells = []
        for w in cols:
            r = cols[w]
            cells.append(f" | {f(r) if all(ok(r, n) for n in need) else 'n/a':>24s}")
        print(f"  {label:40s}" + "".join(cells))

    t = TARGETS
    line("skdh / full, wall", lambda r: verdict(r["skdh"]["wall"] / r["batch"]["wall"],
                                                 t["full_vs_skdh_wall"], True), ("skdh", "batch"))
    line("actipy / full, wall", lambda r: verdict(r["actipy"]["wall"] / r["batch"]["wall"],
                                                   t["full_vs_actipy_wall"], True),
         ("actipy", "batch"))
    line("skdh / lean, wall", lambda r: verdict(r["skdh"]["wall"] / r["lean"]["wall"],
                                                 t["lean_vs_skdh_wall"], True), ("skdh", "lean"))
    line("skdh / lean, CPU", lambda r: verdict(r["skdh"]["cpu"] / r["lean"]["cpu"],
                                                t["lean_vs_skdh_cpu"], True), ("skdh", "lean"))
    line("tables' cost in batch, CPU s", lambda r: f"{r['batch']['cpu'] - r['batch_nt']['cpu']:.2f}",
         ("batch", "batch_nt"))
    line("tables' cost in online, CPU s", lambda r: (
        f"{r['online']['cpu'] - r['online_nt']['cpu']:.2f} "
        f"({(r['online']['cpu'] - r['online_nt']['cpu']) / r['online']['cpu'] * 100:.0f} %)"),
         ("online", "online_nt"))
    line("online / batch, CPU, --no-tables", lambda r: verdict(
        r["online_nt"]["cpu"] / r["batch_nt"]["cpu"], t["online_vs_batch_cpu"], False),
         ("online_nt", "batch_nt"))
    line(f"online / batch, CPU ({a.days:g} days)",
         lambda r: verdict(r["online"]["cpu"] / r["batch"]["cpu"], t["online_vs_batch_cpu"], False),
         ("online", "batch"))
    for d in online_days:
        cells = []
        for w in cols:
            r = extra[(w, d)]
            cells.append(verdict(r["online"]["cpu"] / r["batch"]["cpu"], t["online_vs_batch_cpu"],
                                 False) if ok(r, "online") and ok(r, "batch") else "n/a")
        print(f"  {f'online / batch, CPU ({d:g} days)':40s}" + "".join(f" | {c:>24s}" for c in cells))
    rss = {w: max([cols[w][k]["rss_mb"] for k in ("batch", "lean", "online") if ok(cols[w], k)]
                  + [extra[(w, d)][k]["rss_mb"] for d in online_days for k in ("batch", "online")
                     if ok(extra[(w, d)], k)], default=float("nan")) for w in cols}
    cap = t["peak_rss_mb"]
    cells = [f"{rss[w]:.0f} MB (< {cap:g} MB: {'met' if rss[w] < cap else 'NOT met'})" for w in cols]
    print(f"  {'peak RSS of process, every run':40s}" + "".join(f" | {c:>24s}" for c in cells))
    line("skdh calibrated the file", lambda r: "no: < 72 h, read + ENMO only"
         if "not-calibrated" in r["skdh"]["out"] else "yes", ("skdh",))
    line("peak RSS skdh / full", lambda r: f"{r['skdh']['rss_mb'] / r['batch']['rss_mb']:.1f}x",
         ("skdh", "batch"))
    line("peak RSS actipy / full",
         lambda r: f"{r['actipy']['rss_mb'] / r['batch']['rss_mb']:.1f}x", ("actipy", "batch"))
    line("online estimates published", lambda r: str(len(
        r.get("_summaries", {}).get("online", {}).get("estimates", []))), ("online",))
    return 0


if __name__ == "__main__":
    sys.exit(main())
