"""Batch `process` on two cores (a pipeline step's records framed on one thread when
$STILLPOINT_FRAMING_THREAD is 1, chunks compressed on another, engine/mcap/ordered.py and
engine/mcap/sink.py) writes the same bytes as on one core; a failure on either thread surfaces in the caller as the one-line error and exit
code 2 that one core gives, with everything written before kept and recoverable; an interrupt
leaves no thread running and the partial log recoverable."""

from __future__ import annotations

import errno
import os
import threading

import pytest
from log_messages import messages, recovers_to_prefix

import stillpoint.engine.mcap.sink as sink_mod
from stillpoint.engine.core.errors import StillpointError
from stillpoint.engine.core.prefetch import CORES_ENV, cores_available
from stillpoint.engine.run import RunSettings, process_file
from stillpoint.tools.cli import main as cli
from synthetic_recording import make_recording

THREADS = ("mcap-framing", "mcap-writer", "source-prefetch")
TOPICS = ("/raw/accel", "/corrected/accel", "/temperature", "/metrics/epoch", "/view/accel")


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    rec = tmp_path_factory.mktemp("two") / "rec.cwa"
    make_recording(rec, hours=2.0, rate=100.0, seed=21)  # ~12 pipeline steps of pass 2
    return rec


@pytest.fixture
def cores(monkeypatch):
    """Set the cores the sink sees (this machine may have one); returns the framing workers
    started."""
    started = []

    class Spy(sink_mod.OrderedWorker):
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            started.append(self)

    monkeypatch.setattr(sink_mod, "OrderedWorker", Spy)

    def use(n):
        monkeypatch.setattr(sink_mod, "cores_available", lambda: n)
        return started
    monkeypatch.setenv(sink_mod.FRAMING_THREAD_ENV, "1")  # off by default
    return use


def _messages(path):
    return messages(path, TOPICS)


def _alive():
    return [t.name for t in threading.enumerate() if t.name in THREADS and t.is_alive()]


@pytest.mark.parametrize("log", ["full", "lean"])
def test_two_cores_write_the_bytes_of_one(recording, tmp_path, cores, log):
    out = tmp_path / "r.mcap"  # the same name: the summary record names the output
    s = RunSettings(mode="batch", log=log)
    started = cores(2)
    two = process_file(recording, out, s, prefetch=True)
    assert len(started) == 1  # the step's records were framed on the framing thread
    two_bytes = out.read_bytes()
    out.unlink()
    cores(1)
    one = process_file(recording, out, s, prefetch=False)
    assert len(started) == 1  # one core: framed in the caller's thread
    assert out.read_bytes() == two_bytes
    assert one["mcap_flushes"] == two["mcap_flushes"] > 100  # chunk boundaries: the same bytes
    assert _alive() == []


def test_cores_env_caps_the_cores(monkeypatch):
    monkeypatch.delenv(CORES_ENV, raising=False)
    n = cores_available()
    monkeypatch.setenv(CORES_ENV, "1")
    assert cores_available() == 1
    monkeypatch.setenv(CORES_ENV, "64")
    assert cores_available() == n
    monkeypatch.setenv(CORES_ENV, "zero")
    assert cores_available() == n


def _cli_run(recording, out, capsys):
    rc = cli(["process", str(recording), "-o", str(out), "-q", "--no-tables"])
    err = capsys.readouterr().err
    lines = [ln for ln in err.strip().splitlines() if ln]
    return rc, lines


def _prefix_of(part, full, tmp_path):
    """``part`` (an unfinished log) recovers to a prefix of ``full``'s messages, not empty."""
    return recovers_to_prefix(part, full, tmp_path, TOPICS)


def test_disk_full_on_the_writer_thread(recording, tmp_path, cores, monkeypatch, capsys):
    full = tmp_path / "full.mcap"
    cores(1)
    process_file(recording, full, RunSettings(mode="batch"), writer="inline")
    real = os.writev
    lines = {}
    for n in (1, 2):
        cores(n)
        calls = [0]

        def writev(fd, parts):
            calls[0] += 1
            if calls[0] > 8:  # the header, metadata and a few steps' chunks are on disk
                raise OSError(errno.ENOSPC, "No space left on device")
            return real(fd, parts)

        monkeypatch.setattr(os, "writev", writev)
        out = tmp_path / f"{n}" / "r.mcap"
        out.parent.mkdir()
        rc, lines[n] = _cli_run(recording, out, capsys)
        monkeypatch.setattr(os, "writev", real)
        assert rc == 2 and len(lines[n]) == 1, lines[n]
        assert "no space left on device" in lines[n][0] and "stillpoint recover" in lines[n][0]
        assert _alive() == []
        part = out.parent / "r.mcap.part"
        assert not out.exists() and part.exists()
        _prefix_of(part, full, tmp_path / f"{n}")
    # the same line as on one core
    assert lines[2][0].replace(str(tmp_path / "2"), str(tmp_path / "1")) == lines[1][0]


class _Broken(StillpointError):
    pass


def test_error_in_a_framing_call(recording, tmp_path, cores, monkeypatch, capsys):
    real = sink_mod._frame_block
    lines = {}
    for n in (1, 2):
        started = cores(n)
        calls = [0]

        def frame(*a):
            calls[0] += 1
            if calls[0] == 4:
                raise _Broken("step 4 could not be framed")
            return real(*a)

        monkeypatch.setattr(sink_mod, "_frame_block", frame)
        out = tmp_path / f"{n}" / "r.mcap"
        out.parent.mkdir()
        rc, lines[n] = _cli_run(recording, out, capsys)
        assert rc == 2 and len(lines[n]) == 1, lines[n]
        assert "step 4 could not be framed" in lines[n][0]
        assert calls[0] == 4  # nothing framed after the failure
        assert _alive() == []
        assert (out.parent / "r.mcap.part").exists() and not out.exists()
        assert len(started) == (1 if n == 2 else 0)
    assert lines[2][0].replace(str(tmp_path / "2"), str(tmp_path / "1")) == lines[1][0]


def test_interrupt_leaves_no_thread_and_a_recoverable_log(recording, tmp_path, cores):
    full = tmp_path / "full.mcap"
    cores(1)
    process_file(recording, full, RunSettings(mode="batch"), writer="inline")
    started = cores(2)
    seen = [0]

    def progress(label, stats):
        if label == "pass 2/2":
            seen[0] += 1
            if seen[0] == 6:
                raise KeyboardInterrupt

    out = tmp_path / "r.mcap"
    with pytest.raises(KeyboardInterrupt) as e:
        process_file(recording, out, RunSettings(mode="batch"), progress=progress, prefetch=True)
    assert len(started) == 1
    assert _alive() == []
    part = tmp_path / "r.mcap.part"
    assert e.value.partial_output == str(part) and not out.exists()
    got = _prefix_of(part, full, tmp_path)
    assert len(got["/raw/accel"]) < len(_messages(full)["/raw/accel"])


def test_worker_runs_calls_in_order_and_hands_back_the_first_error():
    from stillpoint.engine.mcap.ordered import OrderedWorker
    w = OrderedWorker("t", depth=1)
    done = []
    for i in range(50):
        w.submit(done.append, i)
    w.drain()
    assert done == list(range(50)) and not w.running
    w = OrderedWorker("t", depth=1)
    boom = ValueError("boom")

    def fail():
        raise boom
    w.submit(fail)
    for _ in range(5):  # dropped, and the caller never blocks on a full queue
        try:
            w.submit(done.append, -1)
        except ValueError as e:
            assert e is boom
            break
    with pytest.raises(ValueError) as e:
        w.drain()
    assert e.value is boom and -1 not in done
    w = OrderedWorker("t", depth=1)
    gate = threading.Event()
    w.submit(gate.wait)
    w.submit(done.append, -2)
    threading.Timer(0.05, gate.set).start()
    w.stop()  # drops the waiting call once the running one returns
    assert -2 not in done and not w.running


def test_interrupt_while_closing_stops_the_thread_before_the_file(tmp_path, cores, monkeypatch):
    from stillpoint.engine.core.blocks import DeviceInfo
    started = cores(2)
    sink = sink_mod.McapSink(tmp_path / "s.mcap", DeviceInfo(
        path="x", device_type="AX3", device_id="1", session_id=0, firmware=0,
        sample_rate_nominal=100.0, accel_range_g=8.0), {}, writer="thread")
    assert len(started) == 1
    gate = threading.Event()
    running = threading.Event()
    ran = []
    sink._framer.submit(lambda: (running.set(), gate.wait(10), ran.append(1)))  # a step still being framed
    assert running.wait(10)  # being framed, not waiting: a waiting call is dropped by abort()

    def drain(self):  # Ctrl-C while close() waits for the framing thread
        raise KeyboardInterrupt
    monkeypatch.setattr(type(started[0]), "drain", drain)
    with pytest.raises(KeyboardInterrupt):
        sink.close()
    threading.Timer(0.05, gate.set).start()
    kept = sink.abort()
    assert ran == [1]  # the call running finished before the file was abandoned
    assert _alive() == []
    assert kept is not None and kept.exists() and not (tmp_path / "s.mcap").exists()


def test_framing_thread_is_off_by_default(recording, tmp_path, cores, monkeypatch):
    started = cores(2)
    monkeypatch.delenv(sink_mod.FRAMING_THREAD_ENV)
    out = tmp_path / "r.mcap"
    process_file(recording, out, RunSettings(mode="batch"))
    assert started == []  # the writer thread only, as measured best (docs/performance.md)
    b = out.read_bytes()
    out.unlink()
    process_file(recording, out, RunSettings(mode="batch"), writer="inline", prefetch=False)
    assert out.read_bytes() == b
