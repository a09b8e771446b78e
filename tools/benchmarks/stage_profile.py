"""Where the CPU of `stillpoint process` goes, stage by stage and thread by thread.

    python tools/benchmarks/stage_profile.py REC.cwa [REC2.cwa ...] [--mode batch] [--repeat 2]
                                             [--markdown]

Runs ``engine.run.process_file`` with the epoch and day tables (as the command does) and times,
with each thread's own CPU clock (``time.thread_time``), every stage of the run:

* on the engine's (main) thread, each stage's *exclusive* CPU (a stage's time minus the stages
  it calls): pass 1's window features and nonmovement selection, the fit, the correction, the
  epoch metrics (ENMO and the BFEN filter, the filter alone as its own row), the MCAP framing of
  a step (``McapSink.write_slices``), the tables (anglez, nonwear, the rest of the epoch
  assembly, the CSV rows and gzip); "main, other" is the rest of the main thread (the pass-1
  decode when it is read inline, start-up, summary);
* every other thread's whole CPU by name (``source-prefetch``: the decode; ``mcap-writer``: zstd,
  CRCs, records and writes; zstd alone as its own row).

With ``--repeat N`` the run with the least total CPU is kept (the machine may be shared: CPU
time, not wall, and the minimum over repeats). ``--markdown`` prints the table as Markdown for
docs/performance.md. ``--max-block-s`` runs with another pipeline step (the reader's read size
scaled with it), to see which stages cost per step rather than per sample. Only the run's own process is measured; the first run also pays the
imports.
"""

from __future__ import annotations

import argparse
import tempfile
import threading
import time
from pathlib import Path

MAIN_STAGES = [
    # (label, module, class or None, attribute)
    ("pass 1: window features + nonmovement", "stillpoint.engine.run", "FeatureStage", "push"),
    ("pass 1: window features + nonmovement", "stillpoint.engine.run", "FeatureStage", "flush"),
    ("fit (batch schedule)", "stillpoint.engine.run.batch", None, "fit_batch_schedule"),
    ("online calibrator: refits", "stillpoint.engine.calibration.online", "OnlineCalibrator",
     "_refit"),
    ("online calibrator: windows kept", "stillpoint.engine.calibration.online", "OnlineCalibrator",
     "add"),
    ("correction (affine, temperature, quantisation)", "stillpoint.engine.operators.correction",
     "CorrectionOperator", "push"),
    ("correction (affine, temperature, quantisation)", "stillpoint.engine.operators.correction",
     "CorrectionOperator", "flush"),
    ("epoch metrics (ENMO, means; BFEN below)", "stillpoint.engine.operators.metrics",
     "MetricsOperator", "push"),
    ("epoch metrics (ENMO, means; BFEN below)", "stillpoint.engine.operators.metrics",
     "MetricsOperator", "flush"),
    ("BFEN band-pass (sosfilt)", "stillpoint.engine.operators.filters", "SosStream", "push"),
    ("MCAP framing of a step", "stillpoint.engine.mcap.sink", "McapSink", "write_slices"),
    ("tables: anglez", "stillpoint.engine.operators.anglez", "AnglezOperator", "push"),
    ("tables: nonwear", "stillpoint.engine.operators.nonwear", "NonwearOperator", "push"),
    ("tables: epoch assembly (rest)", "stillpoint.engine.tables.epochs", "EpochAssembler", "push"),
    ("tables: epoch assembly (rest)", "stillpoint.engine.tables.epochs", "EpochAssembler", "flush"),
    # the tables' epoch-level half (engine/tables/writer.py): in the log's child process when
    # the run has one (then not measured here: only this process is)
    ("tables: CSV rows + gzip", "stillpoint.engine.tables.writer", "EpochTableWriter", "rows"),
    ("tables: CSV rows + gzip", "stillpoint.engine.tables.writer", "EpochTableWriter", "advance"),
    ("tables: CSV rows + gzip", "stillpoint.engine.tables.writer", "EpochTableWriter", "finish"),
    ("tables: CSV rows + gzip", "stillpoint.engine.tables.writer", "EpochTableWriter", "close"),
]


class Meter:
    """Exclusive thread-CPU per stage label, nesting-aware, per thread."""

    def __init__(self):
        self.spent: dict = {}
        self.local = threading.local()

    def wrap(self, label, fn, generator=False):
        meter = self

        def timed(*a, **k):
            stack = meter.local.__dict__.setdefault("stack", [])
            stack.append([time.thread_time(), 0.0])
            try:
                r = fn(*a, **k)
                if generator:  # EpochAssembler.push/flush yield rows: run them inside the timer
                    r = list(r)
                return r
            finally:
                t0, child = stack.pop()
                el = time.thread_time() - t0
                meter.spent[label] = meter.spent.get(label, 0.0) + el - child
                if stack:
                    stack[-1][1] += el
        return timed


def install(meter: Meter) -> dict:
    import importlib
    import inspect

    threads: dict = {}
    run = threading.Thread.run

    def timed_run(self):
        try:
            run(self)
        finally:
            threads[self.name] = threads.get(self.name, 0.0) + time.thread_time()
    threading.Thread.run = timed_run

    for label, mod, cls, attr in MAIN_STAGES:
        m = importlib.import_module(mod)
        owner = getattr(m, cls) if cls else m
        fn = getattr(owner, attr)
        setattr(owner, attr, meter.wrap(label, fn, inspect.isgeneratorfunction(fn)))

    import stillpoint.engine.mcap.writer as writer_mod
    compressor = writer_mod._compressor

    def timed_compressor(*args):
        compress = compressor(*args)
        return None if compress is None else meter.wrap("zstd", compress)
    writer_mod._compressor = timed_compressor
    return threads


def one_run(path: Path, mode: str, block_s: float) -> dict:
    from stillpoint.engine.run import RunSettings, process_file, tuning
    from stillpoint.engine.tables import TablesSettings, table_paths
    if block_s != 600.0:  # the reader's read size follows the step (500 sectors = 600 s at 100 Hz)
        tuning.OUTPUT_BATCH_SECTORS = int(round(tuning.OUTPUT_BATCH_SECTORS * block_s / 600.0))
    meter = Meter()
    threads = install(meter)
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "profile.mcap"
        w, c, m0 = time.perf_counter(), time.process_time(), time.thread_time()
        process_file(path, out, RunSettings(mode=mode, max_block_s=block_s), tables=TablesSettings(*table_paths(out)))
        wall, cpu, main = (time.perf_counter() - w, time.process_time() - c,
                           time.thread_time() - m0)
    return {"wall": wall, "cpu": cpu, "main": main, "stages": meter.spent, "threads": threads}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("recordings", nargs="+", type=Path)
    ap.add_argument("--mode", choices=("batch", "online"), default="batch")
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--markdown", action="store_true")
    ap.add_argument("--max-block-s", type=float, default=600.0,
                    help="pipeline step in data seconds (default 600, the engine's): how much is per step")
    a = ap.parse_args(argv)
    import subprocess
    import json
    import sys
    cols = []
    for p in a.recordings:
        runs = []
        for _ in range(max(1, a.repeat)):  # each run in a fresh process: no patched state kept
            r = subprocess.run([sys.executable, __file__, "--child", str(p), a.mode, str(a.max_block_s)],
                               capture_output=True, text=True)
            if r.returncode != 0:
                raise SystemExit(f"{p}: profile run failed\n{r.stderr[-2000:]}")
            runs.append(json.loads(r.stdout))
        cols.append((p.name, min(runs, key=lambda x: x["cpu"])))
    labels = []
    for _, r in cols:
        for k in list(r["stages"]) + [f"thread {t}" for t in r["threads"]]:
            if k not in labels and k != "zstd":
                labels.append(k)
    sep = " | " if a.markdown else "  "

    def row(name, vals):
        cells = [f"{v:6.2f} s ({100 * v / r['cpu']:3.0f} %)" for v, r in vals]
        return ("| " if a.markdown else "") + sep.join([f"{name:48s}"] + cells) + (" |" if a.markdown else "")
    print(("| " if a.markdown else "") + sep.join([f"{'stage (thread CPU, share of run CPU)':48s}"] +
                                                 [f"{n:>18s}" for n, _ in cols]) + (" |" if a.markdown else ""))
    if a.markdown:
        print("|" + "---|" * (len(cols) + 1))
    for lab in labels:
        vals = []
        for _, r in cols:
            if lab.startswith("thread "):
                v = r["threads"].get(lab[7:], 0.0)
            else:
                v = r["stages"].get(lab, 0.0)
            vals.append((v, r))
        print(row(lab if not lab.startswith("thread ") else lab + " (whole thread)", vals))
        if lab == "thread mcap-writer":
            print(row("  of which zstd", [(r["stages"].get("zstd", 0.0), r) for _, r in cols]))
    print(row("main, other (inline decode, start-up, summary)",
              [(r["main"] - sum(v for k, v in r["stages"].items() if k != "zstd"), r) for _, r in cols]))
    print(row("whole run (process CPU)", [(r["cpu"], r) for _, r in cols]))
    print(("| " if a.markdown else "") + sep.join([f"{'wall (s)':48s}"] + [f"{r['wall']:18.2f}" for _, r in cols])
          + (" |" if a.markdown else ""))
    return 0


if __name__ == "__main__":
    import sys
    if len(sys.argv) == 5 and sys.argv[1] == "--child":
        import json
        print(json.dumps(one_run(Path(sys.argv[2]), sys.argv[3], float(sys.argv[4]))))
        raise SystemExit(0)
    raise SystemExit(main())
