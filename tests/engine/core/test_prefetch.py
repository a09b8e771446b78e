"""A source read ahead on a thread (engine/core/prefetch.py) changes nothing the pipeline sees: the
same blocks, the QC report as it stood at each block, the source's error in its place, and a
log byte for byte the same as without the thread (damaged files, both modes, real files)."""

from __future__ import annotations

import threading
import time
from dataclasses import replace
from pathlib import Path

import pytest

from stillpoint.engine.core.blocks import QCEvent, QCReport
from stillpoint.engine.core.prefetch import Prefetched
from stillpoint.engine.run import RunSettings, process_file

from cwa_helpers import damaged_cwa


class _Source:
    """Yields integers; before each, logs an event and re-times the event before it in place
    (as a reader times an event once a later block reaches it); optionally fails at the end."""

    def __init__(self, n, fail_after=None):
        self.n, self.fail_after = n, fail_after
        self.qc = QCReport(unit="sector")
        self.closed = False
        self.finished = threading.Event()  # the generator's cleanup ran
        self.expected = []  # the QC log as it stood when each item was yielded

    def __iter__(self):
        try:
            for i in range(self.n):
                if self.fail_after is not None and i == self.fail_after:
                    raise ValueError(f"{i}: damaged")
                if self.qc.events:
                    self.qc.events[-1] = replace(self.qc.events[-1], time_ns=i)
                self.qc.add(QCEvent(index=i, reason="checksum"))
                self.qc.total += 1
                self.expected.append((self.qc.total, list(self.qc.events)))
                yield i
            self.qc.events.append(QCEvent(index=-1, reason="end"))
        finally:
            self.finished.set()

    def close(self):
        self.closed = True


def test_blocks_and_qc_as_they_stood_while_the_thread_runs_ahead():
    src = _Source(8)
    pre = Prefetched(src, depth=3)
    seen = []
    for item in pre:
        time.sleep(0.02)  # a slow stage: the thread is up to three items ahead
        seen.append((item, pre.qc.total, list(pre.qc.events)))
    assert [s[0] for s in seen] == list(range(8))
    for i, (_, total, events) in enumerate(seen):
        assert (total, events) == src.expected[i], f"item {i}"
    assert src.qc.events[-1].reason == "end" and pre.qc is src.qc  # exhausted: the live report


def test_the_source_error_comes_after_the_blocks_before_it():
    src = _Source(10, fail_after=4)
    pre = Prefetched(src)
    got = []
    with pytest.raises(ValueError, match="4: damaged"):
        for item in pre:
            got.append(item)
    assert got == [0, 1, 2, 3]
    assert pre.qc.total == 4  # the report as it stood when the error was raised


def test_leaving_early_stops_the_thread_and_close_closes_the_source():
    src = _Source(10_000)
    pre = Prefetched(src, depth=2)
    for item in pre:
        if item == 3:
            break
    pre.close()
    assert src.finished.wait(5), "the source's generator was not closed"
    assert src.closed and not pre._thread.is_alive()
    assert src.qc.total < 100  # the thread stopped; it did not read the source to the end


def test_an_error_starting_the_source_is_raised_not_waited_for():
    class Broken(_Source):
        def __iter__(self):
            raise OSError("cannot start")

    got = []

    def run():  # on a thread, so a consumer left waiting fails the test instead of hanging it
        try:
            list(Prefetched(Broken(3)))
        except OSError as e:
            got.append(str(e))

    t = threading.Thread(target=run, daemon=True)
    t.start()
    t.join(10)
    assert got == ["cannot start"]


def test_single_pass():
    pre = Prefetched(_Source(2))
    assert list(pre) == [0, 1]
    with pytest.raises(RuntimeError, match="single-pass"):
        list(pre)


def _run(src: Path, where: Path, mode: str, prefetch: bool, monkeypatch, **kw) -> bytes:
    """The MCAP of one run, written under a relative name (the summary records the name)."""
    from stillpoint.engine.tables import TablesSettings
    where.mkdir()
    monkeypatch.chdir(where)
    tables = TablesSettings(epochs_path=Path("out.epochs.csv"), days_path=Path("out.days.csv"))
    summary = process_file(src, "out.mcap", RunSettings(mode=mode, chunk_hours=0.25, first_hours=0.25),
                           prefetch=prefetch, tables=tables, **kw)
    assert summary["qc"]["events"] > 0 or "damaged" not in src.name
    return b"".join((where / f).read_bytes() for f in ("out.mcap", "out.epochs.csv", "out.days.csv"))


@pytest.mark.parametrize("mode", ["batch", "online"])
def test_logs_are_the_same_with_and_without_the_thread(tmp_path, monkeypatch, mode):
    src = damaged_cwa(tmp_path / "damaged.cwa", 7)
    opts = {"source_options": {"batch_sectors": 3}}  # many blocks, QC events between them
    a = _run(src, tmp_path / "off", mode, False, monkeypatch, **opts)
    b = _run(src, tmp_path / "on", mode, True, monkeypatch, **opts)
    assert a == b


@pytest.mark.parametrize("name", ["ax3_ggirread_corrupt_blocks_0_13_14_142_143_144.cwa",
                                  "ax3_oxwearables_tiny_sample_3h_with_restart.cwa.gz",
                                  "geneactiv_ggirread_testfile_85p7hz_truncated64k.bin"])
def test_real_files_same_with_and_without_the_thread(real_file, tmp_path, monkeypatch, name):
    src = real_file(name).resolve()  # the runs change folder; the data folder may be relative
    for mode in ("batch", "online"):
        a = _run(src, tmp_path / f"off_{mode}", mode, False, monkeypatch)
        b = _run(src, tmp_path / f"on_{mode}", mode, True, monkeypatch)
        assert a == b, f"{name} {mode}"


@pytest.mark.skipif(not __import__("sys").platform.startswith("linux"), reason="glibc's mallopt: Linux only")
def test_one_arena_once_and_the_environment_wins():
    import subprocess
    import sys
    code = ("from stillpoint.engine.core.malloc import one_arena; "
            "print(one_arena(), one_arena())")
    env = {k: v for k, v in __import__("os").environ.items() if k != "MALLOC_ARENA_MAX"}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["True", "True"]
    out = subprocess.run([sys.executable, "-c", code], env=dict(env, MALLOC_ARENA_MAX="4"),
                         capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "False"]


@pytest.mark.parametrize("mode, cores, used", [("batch", 2, True), ("online", 2, False),
                                               ("batch", 1, False)])
def test_the_thread_by_default_reads_for_batch_runs_on_more_than_one_core(
        tmp_path, monkeypatch, mode, cores, used):
    """process_file's default: a batch run reads ahead where it has a second core; an online run
    (the station's, which compresses inline) does not (run.tuning.PREFETCH_BY_MODE)."""
    from stillpoint.engine.run import inputs, job
    made = []

    class Spy(Prefetched):
        def __init__(self, source, *a, **k):
            made.append(source)
            super().__init__(source, *a, **k)

    monkeypatch.setattr(inputs, "Prefetched", Spy)
    monkeypatch.setattr(job, "cores_available", lambda: cores)
    src = damaged_cwa(tmp_path / "damaged.cwa", 3)
    process_file(src, tmp_path / "out.mcap", RunSettings(mode=mode, chunk_hours=0.25, first_hours=0.25))
    assert bool(made) == used
