"""Batch `process` with its MCAP log written by a child process (engine/mcap/sinkproc.py, the
step's arrays through shared-memory slots, engine/mcap/slots.py) writes the same log and tables,
byte for byte, as a one-core run; a failure in the child (a full disk, a call that fails, the
child killed) is the one-line error and exit code 2 one core gives, with the partial log kept and
recoverable; an interrupt leaves no child process, no thread and nothing in /dev/shm.

Faults are made inside the child by a ``sitecustomize`` module put on its PYTHONPATH (the
child is a fresh interpreter: the test's monkeypatching does not reach it)."""

from __future__ import annotations

import os
import signal
import textwrap
import threading

import pytest
from log_messages import messages, recovers_to_prefix

import stillpoint.engine.mcap.sinkproc as sinkproc
import stillpoint.engine.run.job as job_mod
from stillpoint.engine.core.errors import StillpointError
from stillpoint.engine.mcap.compare import topic_digests
from stillpoint.engine.mcap.slots import SlotRing
from stillpoint.engine.run import RunSettings, process_file, tuning
from stillpoint.engine.tables import TablesSettings
from stillpoint.tools.cli import main as cli
from synthetic_recording import make_recording

TOPICS = ("/raw/accel", "/corrected/accel", "/temperature", "/metrics/epoch")
THREADS = ("mcap-framing", "mcap-writer", "source-prefetch")


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    rec = tmp_path_factory.mktemp("child") / "rec.cwa"
    make_recording(rec, hours=2.0, rate=100.0, seed=21)  # ~12 pipeline steps of pass 2
    return rec


@pytest.fixture
def child(monkeypatch):
    """Use the child process for any input on two cores; returns the SinkProcesses started."""
    started = []
    real = sinkproc.SinkProcess.start.__func__

    def start(cls):
        p = real(cls)
        started.append(p)
        return p
    monkeypatch.setattr(sinkproc.SinkProcess, "start", classmethod(start))
    monkeypatch.setattr(tuning, "SINK_PROCESS_MIN_BYTES", 0)
    monkeypatch.setattr(job_mod, "cores_available",  # two, unless capped to one
                        lambda: 1 if os.environ.get("STILLPOINT_CORES") == "1" else 2)
    monkeypatch.delenv(sinkproc.ENV, raising=False)
    monkeypatch.delenv("STILLPOINT_CORES", raising=False)
    return started


def _in_child(monkeypatch, tmp_path, code: str) -> None:
    """Run ``code`` at the start of the child interpreter (a sitecustomize on its path)."""
    d = tmp_path / "site"
    d.mkdir()
    (d / "sitecustomize.py").write_text(textwrap.dedent(code))
    monkeypatch.setenv("PYTHONPATH", str(d) + os.pathsep + os.environ.get("PYTHONPATH", ""))


def _messages(path):
    return messages(path, TOPICS)


def _children():
    """Live log-writing child processes of this one (pids), from /proc."""
    return _pids_of_parent(os.getpid())


def _clean():
    assert [t.name for t in threading.enumerate() if t.name in THREADS and t.is_alive()] == []
    assert _children() == []


def _shm():
    """Shared memory this process holds: its descriptors on /dev/shm entries or on memory files
    (the slots' ring is one). Not a listing of /dev/shm: other tests' processes add and remove
    their own entries there while this one runs."""
    held = []
    for fd in os.listdir("/proc/self/fd"):
        try:
            target = os.readlink(f"/proc/self/fd/{fd}")
        except OSError:
            continue
        if target.startswith(("/dev/shm/", "/memfd:")):
            held.append(target)
    return sorted(held)


@pytest.mark.parametrize("log", ["full", "lean"])
def test_child_writes_the_bytes_of_one_core(recording, tmp_path, child, monkeypatch, log):
    out = tmp_path / "r.mcap"  # the same names: the summary record names the outputs
    tables = TablesSettings(tmp_path / "r.epochs.csv.gz", tmp_path / "r.days.csv")
    s = RunSettings(mode="batch", log=log)
    shm = _shm()
    two = process_file(recording, out, s, tables=tables)
    assert len(started := child) == 1 and started[0].proc is None  # used, and ended
    got = {p: p.read_bytes() for p in (out, tables.epochs_path, tables.days_path)}
    for p in got:
        p.unlink()
    monkeypatch.setenv("STILLPOINT_CORES", "1")
    one = process_file(recording, out, s, tables=tables)
    assert len(child) == 1  # one core: no child
    for p, b in got.items():
        assert p.read_bytes() == b, p.name
    assert one["mcap_flushes"] == two["mcap_flushes"] > 20
    assert one["mcap_messages"] == two["mcap_messages"]
    assert two["peak_rss_mb"]["writer"] > 0  # the child's own peak RSS
    _clean()
    assert _shm() == shm


def test_child_off_by_env_and_for_short_inputs(recording, tmp_path, child, monkeypatch):
    monkeypatch.setenv(sinkproc.ENV, "0")
    process_file(recording, tmp_path / "a.mcap", RunSettings(mode="batch"))
    monkeypatch.delenv(sinkproc.ENV)
    monkeypatch.setattr(tuning, "SINK_PROCESS_MIN_BYTES", recording.stat().st_size + 1)
    process_file(recording, tmp_path / "b.mcap", RunSettings(mode="batch"))
    process_file(recording, tmp_path / "c.mcap", RunSettings(mode="online"))
    assert child == []


def test_no_child_for_a_job_that_has_one_core(recording, tmp_path, child):
    """A caller that reads without a read-ahead thread (a cohort worker: one job per core) gets no
    log child either; the log is the same."""
    process_file(recording, tmp_path / "a.mcap", RunSettings(mode="batch", log="lean"), prefetch=False)
    assert child == []
    process_file(recording, tmp_path / "b.mcap", RunSettings(mode="batch", log="lean"))
    assert len(child) == 1
    assert topic_digests(tmp_path / "a.mcap", None) == topic_digests(tmp_path / "b.mcap", None)


def _cli_run(recording, out, capsys):
    rc = cli(["process", str(recording), "-o", str(out), "-q", "--no-tables"])
    err = capsys.readouterr().err
    return rc, [ln for ln in err.strip().splitlines() if ln]


def _prefix_of(part, full, tmp_path):
    """``part`` (an unfinished log) recovers to a prefix of ``full``'s messages, not empty."""
    return recovers_to_prefix(part, full, tmp_path, TOPICS)


def _one_core_line(recording, tmp_path, monkeypatch, capsys, patch):
    """The one-line error of a one-core run with ``patch`` applied in this process."""
    monkeypatch.setenv("STILLPOINT_CORES", "1")
    undo = patch()
    out = tmp_path / "1" / "r.mcap"
    out.parent.mkdir()
    rc, lines = _cli_run(recording, out, capsys)
    undo()
    monkeypatch.delenv("STILLPOINT_CORES")
    assert rc == 2 and len(lines) == 1, lines
    return lines[0]


def test_disk_full_in_the_child(recording, tmp_path, child, monkeypatch, capsys):
    full = tmp_path / "full.mcap"
    process_file(recording, full, RunSettings(mode="batch"), writer="inline")
    child.clear()

    def patch():
        real, calls = os.writev, [0]

        def writev(fd, parts):
            calls[0] += 1
            if calls[0] > 8:
                raise OSError(28, "No space left on device")
            return real(fd, parts)
        os.writev = writev
        return lambda: setattr(os, "writev", real)
    line1 = _one_core_line(recording, tmp_path, monkeypatch, capsys, patch)
    _in_child(monkeypatch, tmp_path, """
        import os
        _real, _calls = os.writev, [0]
        def _writev(fd, parts):
            _calls[0] += 1
            if _calls[0] > 8:
                raise OSError(28, "No space left on device")
            return _real(fd, parts)
        os.writev = _writev
    """)
    out = tmp_path / "2" / "r.mcap"
    out.parent.mkdir()
    rc, lines = _cli_run(recording, out, capsys)
    assert len(child) == 1
    assert rc == 2 and len(lines) == 1, lines
    assert "no space left on device" in lines[0] and "stillpoint recover" in lines[0]
    assert lines[0].replace(str(tmp_path / "2"), str(tmp_path / "1")) == line1
    assert not out.exists() and (out.parent / "r.mcap.part").exists()
    _prefix_of(out.parent / "r.mcap.part", full, tmp_path / "2")
    _clean()


def test_error_in_a_call_in_the_child(recording, tmp_path, child, monkeypatch, capsys):
    import stillpoint.engine.mcap.sink as sink_mod

    def patch():
        real, calls = sink_mod._frame_block, [0]

        def frame(*a):
            calls[0] += 1
            if calls[0] == 4:
                raise StillpointError("step 4 could not be framed")
            return real(*a)
        sink_mod._frame_block = frame
        return lambda: setattr(sink_mod, "_frame_block", real)
    line1 = _one_core_line(recording, tmp_path, monkeypatch, capsys, patch)
    _in_child(monkeypatch, tmp_path, """
        import stillpoint.engine.mcap.sink as sink_mod
        from stillpoint.engine.core.errors import StillpointError
        _real, _calls = sink_mod._frame_block, [0]
        def _frame(*a):
            _calls[0] += 1
            if _calls[0] == 4:
                raise StillpointError("step 4 could not be framed")
            return _real(*a)
        sink_mod._frame_block = _frame
    """)
    out = tmp_path / "2" / "r.mcap"
    out.parent.mkdir()
    rc, lines = _cli_run(recording, out, capsys)
    assert len(child) == 1
    assert rc == 2 and len(lines) == 1, lines
    assert lines[0].replace(str(tmp_path / "2"), str(tmp_path / "1")) == line1
    assert (out.parent / "r.mcap.part").exists() and not out.exists()
    _clean()


def _child_has_written(part, full, share: float = 0.2, timeout_s: float = 120.0) -> None:
    """Hold the engine (from its progress callback) until the child has written ``share`` of
    the complete log's bytes into ``part``: the steps already handed over (up to
    ``sinkproc.SLOTS`` waiting) are framed and written whatever the machine's speed, so the
    unfinished log has whole chunks of every topic to recover."""
    import time
    want = share * full.stat().st_size
    end = time.monotonic() + timeout_s
    while not (part.exists() and part.stat().st_size >= want):
        assert time.monotonic() < end, f"the child wrote {part.stat().st_size if part.exists() else 0} bytes"
        time.sleep(0.02)


def test_killed_child_is_one_line(recording, tmp_path, child):
    full = tmp_path / "full.mcap"
    process_file(recording, full, RunSettings(mode="batch"), writer="inline")
    seen = [0]

    def progress(label, stats):
        if label == "pass 2/2":
            seen[0] += 1
            if seen[0] == 5:
                _child_has_written(tmp_path / "r.mcap.part", full)
                os.kill(child[-1].proc.pid, signal.SIGKILL)
                child[-1].proc.wait()

    out = tmp_path / "r.mcap"
    with pytest.raises(StillpointError) as e:
        process_file(recording, out, RunSettings(mode="batch"), progress=progress)
    msg = str(e.value)
    assert "\n" not in msg and "writer process ended (signal 9)" in msg
    assert "stillpoint recover" in msg and str(out) in msg
    assert not out.exists() and (tmp_path / "r.mcap.part").exists()
    _prefix_of(tmp_path / "r.mcap.part", full, tmp_path)
    _clean()


def test_interrupt_stops_the_child_and_keeps_a_recoverable_log(recording, tmp_path, child):
    full = tmp_path / "full.mcap"
    process_file(recording, full, RunSettings(mode="batch"), writer="inline")
    shm, fds = _shm(), len(os.listdir("/proc/self/fd"))
    seen = [0]

    def progress(label, stats):
        if label == "pass 2/2":
            seen[0] += 1
            if seen[0] == 6:
                _child_has_written(tmp_path / "r.mcap.part", full)
                raise KeyboardInterrupt

    out = tmp_path / "r.mcap"
    with pytest.raises(KeyboardInterrupt) as e:
        process_file(recording, out, RunSettings(mode="batch"), progress=progress)
    assert len(child) == 1 and child[0].proc is None
    _clean()
    assert _shm() == shm and len(os.listdir("/proc/self/fd")) == fds  # no segment, no fd left
    part = tmp_path / "r.mcap.part"
    assert e.value.partial_output == str(part) and not out.exists()
    got = _prefix_of(part, full, tmp_path)
    assert len(got["/raw/accel"]) < len(_messages(full)["/raw/accel"])


def test_failure_before_the_log_opens_ends_the_child(tmp_path, child):
    bad = tmp_path / "bad.cwa"
    bad.write_bytes(b"\0" * 4096)
    with pytest.raises(StillpointError):
        process_file(bad, tmp_path / "r.mcap", RunSettings(mode="batch"))
    assert len(child) == 1 and child[0].proc is None
    _clean()


def test_slots_carry_arrays_and_objects():
    import numpy as np
    ring = SlotRing(2, 1 << 16)
    other = SlotRing(2, 1 << 16, fd=os.dup(ring.fd))  # the child's view of the same memory
    a = np.arange(1000, dtype=np.int64)
    obj = {"a": a, "b": np.ones((10, 3))[:, 1], "s": "text"}  # b: not contiguous, in band
    head, sizes = ring.pack(obj)
    assert ring.fits(sizes) and len(sizes) == 1
    ring.fill(1, sizes)
    got = other.unpack(1, head, sizes)
    ring.fill(1, ring.pack({"a": a * 0, "b": a, "s": ""})[1])  # the slot reused: got is a copy
    assert np.array_equal(got["a"], a) and np.array_equal(got["b"], np.ones(10))
    got["a"][0] = 5  # writable, its own memory
    assert not ring.stopping and not other.stopping
    ring.stop()
    assert other.stopping
    assert not ring.fits([1 << 17])
    ring.close()
    other.close()


def test_engine_killed_the_child_aborts_and_the_log_recovers(recording, tmp_path, monkeypatch):
    """SIGKILL of the engine: the child sees its pipe close, aborts the log and ends; the
    .part file recovers to a prefix of the complete log."""
    import subprocess
    import sys
    import time
    full = tmp_path / "full.mcap"
    process_file(recording, full, RunSettings(mode="batch"), writer="inline")
    _in_child(monkeypatch, tmp_path, """
        import time
        import stillpoint.engine.run.tuning as tuning
        import stillpoint.engine.run.output as output
        tuning.SINK_PROCESS_MIN_BYTES = 0  # this short input too
        _push = output.OutputStage.push
        def _slow(self, block):  # each step takes a while: the engine is killed mid-run
            time.sleep(0.3)
            _push(self, block)
        output.OutputStage.push = _slow
    """)
    out = tmp_path / "r.mcap"
    part = tmp_path / "r.mcap.part"
    eng = subprocess.Popen([sys.executable, "-m", "stillpoint.tools", "process", str(recording),
                            "-o", str(out), "-q", "--no-tables"])
    kid = None
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and eng.poll() is None:
            kids = [p for p in _pids_of_parent(eng.pid)]
            if kids and part.exists() and part.stat().st_size > 200_000:
                kid = kids[0]
                break
            time.sleep(0.05)
        assert kid is not None and eng.poll() is None, "the run ended before it could be killed"
        eng.kill()
        eng.wait()
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and _alive_pid(kid):
            time.sleep(0.05)
        assert not _alive_pid(kid)
    finally:
        if eng.poll() is None:
            eng.kill()
            eng.wait()
    assert not out.exists() and part.exists()
    _prefix_of(part, full, tmp_path)


def _pids_of_parent(ppid: int) -> list:
    """Live (not zombie) log-writing child processes of ``ppid``, from /proc."""
    kids = []
    for d in os.listdir("/proc"):
        if d.isdigit():
            try:
                with open(f"/proc/{d}/stat") as f:
                    st = f.read().rsplit(")", 1)[1].split()
                with open(f"/proc/{d}/cmdline", "rb") as f:
                    cmd = f.read()
            except OSError:
                continue
            if int(st[1]) == ppid and st[0] != "Z" and b"mcap.sinkproc" in cmd:
                kids.append(int(d))
    return kids


def _alive_pid(pid: int) -> bool:
    """The process exists and is not a zombie (an orphan's exit may be reaped late)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


# ---------------------------------------------------------------------------- the tables' writer
# With the log in a child process, the tables' epoch-level half (EpochTableWriter: the epoch
# table's text and gzip, days, outcomes, sleep, rhythm, windows) runs there too, handed the rows
# the engine's per-sample half (EpochFeed) makes; its outputs and faults are a one-core run's.
TABLE_ARGS = ["--cutpoints", "hildebrand_adults_geneactiv_wrist", "--steps", "--impute"]


def _cli_tables(recording, out, capsys, *args):
    """``process`` with every table (outcomes, steps, imputation, sleep, rhythm, windows)."""
    rc = cli(["process", str(recording), "-o", str(out), "-q", *TABLE_ARGS,
              "--summary", str(out.parent / "summary.json"), *args])
    err = capsys.readouterr().err
    return rc, [ln for ln in err.strip().splitlines() if ln]


def _outputs(folder):
    """Every file of a run's folder (bytes), the summary without its timings."""
    import json
    got = {}
    for p in sorted(folder.iterdir()):
        if p.name == "summary.json":
            d = json.loads(p.read_text())
            for k in ("wall_s", "peak_rss_mb"):
                d.pop(k)
            got[p.name] = d
        elif p.is_file():
            got[p.name] = p.read_bytes()
    return got


@pytest.mark.parametrize("log", ["full", "lean"])
def test_tables_written_by_the_child_are_one_cores(recording, tmp_path, child, monkeypatch,
                                                    capsys, log):
    out = tmp_path / "r.mcap"  # the same names: the summary record names the outputs
    assert _cli_tables(recording, out, capsys, "--log", log) == (0, [])
    assert len(child) == 1 and child[0].proc is None
    two = _outputs(tmp_path)
    assert {"r.epochs.csv.gz", "r.days.csv", "r.nights.csv", "r.rhythm.csv",
            "r.windows.csv"} <= set(two)
    assert two["summary.json"]["tables"]["outcomes"]["steps"]
    for p in tmp_path.iterdir():
        p.unlink()
    monkeypatch.setenv("STILLPOINT_CORES", "1")
    assert _cli_tables(recording, out, capsys, "--log", log) == (0, [])
    assert len(child) == 1  # one core: no child
    one = _outputs(tmp_path)
    assert one.keys() == two.keys()
    for name in one:
        assert one[name] == two[name], name
    _clean()


def _table_fault(recording, tmp_path, child, monkeypatch, capsys, code, target):
    """The same fault (``code``, which replaces the attribute ``target = (owner, name)``) made
    in this process on one core and in the child on two: the same one line (exit code 2) and
    the same files left, nothing of the tables under a final name unless one core leaves it
    too, and no child."""
    left = {}
    lines = {}
    for run in ("1", "2"):
        out = tmp_path / run / "r.mcap"
        out.parent.mkdir()
        if run == "1":
            monkeypatch.setenv("STILLPOINT_CORES", "1")
            owner, name = target
            real = getattr(owner, name)
            exec(textwrap.dedent(code), {})
        else:
            _in_child(monkeypatch, tmp_path, code)
        rc, ls = _cli_tables(recording, out, capsys)
        if run == "1":
            setattr(owner, name, real)
            monkeypatch.delenv("STILLPOINT_CORES")
        assert rc == 2 and len(ls) == 1, ls
        lines[run] = ls[0].replace(str(out.parent), "<dir>")
        left[run] = sorted(p.name for p in out.parent.iterdir())
    assert len(child) == 1 and child[0].proc is None
    assert lines["2"] == lines["1"]
    assert left["2"] == left["1"]
    _clean()
    return lines["1"], left["1"]


def test_epoch_table_disk_full_in_the_child(recording, tmp_path, child, monkeypatch, capsys):
    import gzip
    line, left = _table_fault(recording, tmp_path, child, monkeypatch, capsys, """
        import gzip
        _real, _calls = gzip.GzipFile.write, [0]
        def _write(self, data):
            _calls[0] += 1
            if _calls[0] > 6:
                raise OSError(28, "No space left on device")
            return _real(self, data)
        gzip.GzipFile.write = _write
    """, (gzip.GzipFile, "write"))
    assert "no space left on device" in line.lower()
    assert "r.mcap.part" in left and "r.mcap" not in left  # the log kept for recovery
    assert not [n for n in left if n.endswith((".csv", ".csv.gz"))]  # no table under its name


def test_day_table_fails_at_close_in_the_child(recording, tmp_path, child, monkeypatch, capsys):
    from stillpoint.engine.core import outputs
    line, left = _table_fault(recording, tmp_path, child, monkeypatch, capsys, """
        from stillpoint.engine.core import outputs
        _real = outputs.AtomicOutput.commit
        def _commit(self):
            if self.path.name.endswith(".days.csv"):
                raise outputs.OutputError(self.part, "cannot finish writing: disk full")
            return _real(self)
        outputs.AtomicOutput.commit = _commit
    """, (outputs.AtomicOutput, "commit"))
    assert "r.days.csv.part" in line and "disk full" in line
    assert "r.days.csv" not in left and "r.mcap" not in left


def test_interrupt_leaves_the_tables_of_one_core_and_no_child(recording, tmp_path, child,
                                                             monkeypatch):
    """An interrupt in pass 2: the files left are a one-core run's (the logs' partial files; the
    tables' partial files abandoned as on one core: no table under its name)."""
    left = {}
    for run in ("1", "2"):
        if run == "1":
            monkeypatch.setenv("STILLPOINT_CORES", "1")
        else:
            monkeypatch.delenv("STILLPOINT_CORES")
        def progress(label, stats, seen=[0]):  # noqa: B006  (one counter per run)
            if label == "pass 2/2":
                seen[0] += 1
                if seen[0] == 6:
                    raise KeyboardInterrupt
        d = tmp_path / run
        d.mkdir()
        tables = TablesSettings(d / "r.epochs.csv.gz", d / "r.days.csv")
        with pytest.raises(KeyboardInterrupt):
            process_file(recording, d / "r.mcap", RunSettings(mode="batch"), tables=tables,
                         progress=progress)
        left[run] = sorted(p.name for p in d.iterdir())
    assert len(child) == 1 and child[0].proc is None
    assert left["2"] == left["1"]
    assert "r.mcap.part" in left["2"]
    assert not [n for n in left["2"] if n.endswith((".csv", ".csv.gz"))]
    _clean()
