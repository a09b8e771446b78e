"""What framing the MCAP log costs a pipeline step of `stillpoint process`.

    python tools/benchmarks/bench_framing.py [REC.cwa] [--mode batch] [--repeat 3]

Runs ``engine.run.process_file`` (with the epoch and day tables, as the command does) on the
recording (default: the realistic 1-day file of ``benchlib.realistic_recording``, ``stillpoint
simulate`` with the default wearer, written there if missing; ``--pattern``: the 1-day test
pattern of tools/benchmarks/bench_process.py instead)
and prints, per run, the CPU time of the engine's thread spent in ``McapSink.write_slices``
(framing every message of a step, handing its chunks to the writer) per pipeline step, its
share of the run's CPU, and the run's wall and CPU time. The CPU clock is the calling thread's
(``time.thread_time``), so the writer and reader threads' work is not in the framing figure.
It also prints the writer's CPU (``_WriterCore.execute``, on the writer thread in batch mode,
inline online) and how much of it is zstd, with the bytes in and out: the rest is the chunks'
CRC32s, their records and the writes.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("recording", nargs="?", default=None)
    ap.add_argument("--mode", choices=("batch", "online"), default="batch")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--workdir", default=os.path.join(tempfile.gettempdir(), "stillpoint_bench"))
    ap.add_argument("--pattern", action="store_true", help="default file: the test pattern, not wear")
    a = ap.parse_args(argv)
    if a.recording is None:
        from bench_process import recording
        from benchlib import realistic_recording
        wd = Path(a.workdir)
        wd.mkdir(parents=True, exist_ok=True)
        path = (recording if a.pattern else realistic_recording)(wd, 1.0, 100.0)
    else:
        path = Path(a.recording)

    import stillpoint.engine.mcap.sink as sink_mod
    import stillpoint.engine.mcap.writer as writer_mod
    from stillpoint.engine.run import RunSettings, process_file
    from stillpoint.engine.tables import TablesSettings, table_paths

    spent = [0.0, 0]
    write_slices = sink_mod.McapSink.write_slices

    def timed(self, *args, **kw):
        t = time.thread_time()
        try:
            return write_slices(self, *args, **kw)
        finally:
            spent[0] += time.thread_time() - t
            spent[1] += 1

    sink_mod.McapSink.write_slices = timed
    wr = {"cpu": 0.0, "zstd": 0.0, "in": 0, "out": 0}
    compressor, execute = writer_mod._compressor, writer_mod._WriterCore.execute

    def timed_compressor(*args):
        compress = compressor(*args)
        if compress is None:
            return None

        def timed_compress(data):
            t = time.thread_time()
            z = compress(data)
            wr["zstd"] += time.thread_time() - t
            wr["in"] += len(data)
            wr["out"] += len(z)
            return z
        return timed_compress

    def timed_execute(self, *args):
        t = time.thread_time()
        try:
            return execute(self, *args)
        finally:
            wr["cpu"] += time.thread_time() - t

    writer_mod._compressor = timed_compressor
    writer_mod._WriterCore.execute = timed_execute
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "framing.mcap"
        print(f"{path.name}, --mode {a.mode}")
        for _ in range(a.repeat):
            spent[:] = [0.0, 0]
            wr.update(cpu=0.0, zstd=0.0, out=0)
            wr["in"] = 0
            w, c = time.perf_counter(), time.process_time()
            process_file(path, out, RunSettings(mode=a.mode), tables=TablesSettings(*table_paths(out)))
            wall, cpu = time.perf_counter() - w, time.process_time() - c
            print(f"  framing {1e3 * spent[0] / max(spent[1], 1):.2f} ms CPU a step over {spent[1]} "
                  f"steps ({spent[0]:.2f} s, {100 * spent[0] / cpu:.0f} % of the run's CPU); "
                  f"run {wall:.2f} s wall, {cpu:.2f} s CPU")
            print(f"  writer {wr['cpu']:.2f} s CPU, of which zstd {wr['zstd']:.2f} s "
                  f"({wr['in'] / 1e6:.0f} MB -> {wr['out'] / 1e6:.0f} MB), the rest "
                  f"{wr['cpu'] - wr['zstd']:.2f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
