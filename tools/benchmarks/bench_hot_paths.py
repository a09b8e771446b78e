"""The per-sample hot paths every mode shares, timed alone: correction, then epoch metrics.

    python tools/benchmarks/bench_hot_paths.py REC.cwa [--blocks 100] [--repeat 9]

Reads the first ``--blocks`` blocks of a .cwa recording as a batch run's output pass reads them
(500 sectors: 600 s at 100 Hz), keeps them in memory, then pushes them through
``CorrectionOperator`` (an estimate with a temperature term, so every part of the correction
runs) and ``MetricsOperator`` ``--repeat`` times, each run with fresh operators. It prints the
least thread CPU of each stage over the runs and a SHA-256 of everything both stages returned
(times, corrected samples, temperatures, every epoch metric): the same digest from two source
trees (``PYTHONPATH`` pointing at the other one's package) means the same output bit for bit.
The full run's stages are ``stage_profile.py``'s; this isolates two of them from the decode and
the log's threads, whose CPU makes small changes hard to see on a shared machine.
"""

from __future__ import annotations

import argparse
import hashlib
import time
from pathlib import Path

import numpy as np

EPOCH_FIELDS = ("start_ns", "n", "enmo_mg", "bfen_mg", "mad_mg", "mean", "temperature", "segment")


def read_blocks(path: Path, count: int) -> tuple[list, float]:
    """The first ``count`` blocks and the recording's nominal rate."""
    from stillpoint.drivers.cwa_reader import CwaReader
    blocks = []
    with CwaReader(path, batch_sectors=500) as reader:
        for b in reader:
            blocks.append(b)
            if len(blocks) >= count:
                break
        rate = float(reader.info.sample_rate_nominal)
    return blocks, rate


def one_run(blocks: list, rate_hz: float) -> tuple[float, float, str]:
    """(correction CPU, metrics CPU, digest of both outputs) of one pass over the blocks."""
    from stillpoint.engine.calibration.estimate import CalibrationEstimate
    from stillpoint.engine.operators.correction import CorrectionOperator
    from stillpoint.engine.operators.metrics import MetricsOperator
    est = CalibrationEstimate(offset=[0.011, -0.02, 0.005], scale=[1.01, 0.995, 1.003],
                              tempoffset=[0.001, -0.0005, 0.0002], temperature_ref=22.5,
                              method="bench")
    corr, met = CorrectionOperator(est, rate_hz=rate_hz), MetricsOperator(rate_hz)
    h = hashlib.sha256()
    tc = tm = 0.0
    for b in blocks + [None]:
        t0 = time.thread_time()
        batches = corr.push(b) if b is not None else corr.flush()
        t1 = time.thread_time()
        epochs = [met.push(x) for x in batches] + ([met.flush()] if b is None else [])
        t2 = time.thread_time()
        tc, tm = tc + t1 - t0, tm + t2 - t1
        for x in batches:
            for a in (x.time_ns, x.accel, x.temperature):
                h.update(np.ascontiguousarray(a).tobytes())
        for e in epochs:
            for f in EPOCH_FIELDS:
                h.update(np.ascontiguousarray(getattr(e, f)).tobytes())
    return tc, tm, h.hexdigest()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("recording", type=Path)
    ap.add_argument("--blocks", type=int, default=100)
    ap.add_argument("--repeat", type=int, default=9)
    a = ap.parse_args(argv)
    blocks, rate = read_blocks(a.recording, a.blocks)
    runs = [one_run(blocks, rate) for _ in range(max(1, a.repeat))]
    digests = {r[2] for r in runs}
    if len(digests) != 1:
        raise SystemExit("bench_hot_paths: the runs' outputs differ from each other")
    samples = sum(b.n for b in blocks)
    print(f"{a.recording.name}: {len(blocks)} blocks, {samples:,} samples, least of {len(runs)} runs")
    print(f"correction     {min(r[0] for r in runs):6.3f} s CPU")
    print(f"epoch metrics  {min(r[1] for r in runs):6.3f} s CPU (BFEN band-pass included)")
    print(f"output digest  {digests.pop()}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
