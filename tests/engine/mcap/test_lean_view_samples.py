"""A lean log's sink fed only the view's samples of each step's corrected batches
(``ViewDecimator.thin``: what the log's child process gets in a lean batch run,
engine/mcap/sinkproc.py) writes the same file, byte for byte, as the sink fed the whole batches:
same records, same order among the epochs, same chunk cuts and counters, whatever the view rate
(periods that divide the cells or not, longer than a cell), the chunk size, the framing path,
gaps that do not fit a corrected message's int32 steps, restarts and clocks that step back."""

from __future__ import annotations

import gzip
import os
import shutil

import numpy as np
import pytest

import stillpoint.engine.mcap.sinkproc as sinkproc
import stillpoint.engine.run.job as job_mod
from stillpoint.engine.core.blocks import DeviceInfo
from stillpoint.engine.mcap import sink as sink_mod
from stillpoint.engine.mcap.view import ViewDecimator
from stillpoint.engine.operators.correction import CorrectedBatch
from stillpoint.engine.operators.metrics import EpochMetrics
from stillpoint.engine.run import RunSettings, process_file, tuning
from stillpoint.engine.tables import TablesSettings
from synthetic_recording import make_recording

S = 10**9
T0 = 1_700_000_003 * S + 7_000_000  # off the cell and period grids
EPOCH_NS = 5 * S


def _epochs(starts: list) -> EpochMetrics:
    k = len(starts)
    v = np.linspace(1.0, 2.0, k)
    return EpochMetrics(np.asarray(starts, np.int64), np.full(k, 500, np.int64), v, v * 2, v * 3,
                        np.stack([v, -v, v / 2], axis=1), v + 20.0, np.zeros(k, np.int64))


def _stream(seed: int, events: tuple, rate: float = 50.0, steps: int = 14):
    """Pipeline steps (corrected batches, epochs) of a made-up recording: each step 20-130 s in
    1-3 batches, with the ``events`` put at random samples: "gap" (1.5 s: fits int32 ns),
    "long_gap" (3 s: does not), "back" (the clock steps back 4 s), "restart" (a new segment
    40 s later), "join_back" (the next batch starts 2 s before the previous one ends)."""
    rng = np.random.default_rng(seed)
    dt = int(round(S / rate))
    t, seg = T0, 0
    out, open_epochs = [], []
    for _ in range(steps):
        batches = []
        for _b in range(int(rng.integers(1, 4))):
            n = int(rng.integers(int(7 * rate), int(45 * rate)))
            steps_ns = np.full(n, dt, np.int64)
            steps_ns[0] = 0
            ev = events[int(rng.integers(len(events)))] if events and rng.random() < 0.6 else None
            cut = int(rng.integers(1, n))
            if ev == "gap":
                steps_ns[cut] = 3 * S // 2
            elif ev == "long_gap":
                steps_ns[cut] = 3 * S
            elif ev == "back":
                steps_ns[cut] = -4 * S
            times = t + np.cumsum(steps_ns)
            if ev == "restart":
                seg += 1
                times = times + 40 * S
            elif ev == "join_back":
                times = times - 2 * S
            accel = rng.normal(0.0, 0.4, (n, 3)) + np.array([0.0, 0.0, 1.0])
            batches.append(CorrectedBatch(times, accel, np.full(n, 25.0), seg))
            t = int(times[-1]) + dt
        starts = sorted({int(x) for b in batches for x in (b.time_ns // EPOCH_NS) * EPOCH_NS})
        done = [s for s in open_epochs + starts[:-1] if s not in starts[-1:]]
        open_epochs = starts[-1:]
        out.append((batches, _epochs(sorted(set(done)))))
    out.append(([], _epochs(open_epochs)))
    return out


def _write(path, stream, thin: bool, view_hz: float, **kw):
    info = DeviceInfo(path="x", device_type="AX3", device_id="1", session_id=0, firmware=0,
                      sample_rate_nominal=50.0, accel_range_g=8.0)
    sink = sink_mod.McapSink(path, info, {"log": "lean"}, view_hz=view_hz, **kw)
    dec = ViewDecimator(view_hz) if view_hz else None
    sent = 0
    for i, (batches, epochs) in enumerate(stream):
        at = int(batches[0].time_ns[0]) if batches else T0
        if thin:
            batches = dec.thin(batches) if dec is not None else []
        sent += sum(b.n for b in batches)
        sink.write_slices(None, batches, epochs)
        if i % 5 == 2:  # the engine's other calls come between steps
            sink.write_qc({"kind": "note", "i": i}, at)
    sink.close()
    return path.read_bytes(), sink.messages, sink.flushes, sent


EVENTS = {"plain": (), "gaps": ("gap", "long_gap"), "restarts": ("restart", "gap"),
          "clock_back": ("back", "join_back", "gap")}


@pytest.mark.parametrize("events", list(EVENTS))
@pytest.mark.parametrize("view_hz,chunk_size,chunk_s,step_chunks", [
    (1.0, 1 << 20, 60.0, False),  # the batch run's defaults
    (1.0, 1500, 60.0, False),  # chunks ended by their size, inside a step
    (3.0, 1 << 20, 60.0, True),  # periods that do not divide the cells; the online chunking
    (0.07, 4000, None, False),  # a period longer than a cell: cells without a view sample
    (0.3, 1 << 20, 30.0, False),  # view samples further apart than an int32 step
    (0.0, 1 << 20, 60.0, False),  # no view: nothing is sent
])
@pytest.mark.parametrize("block_framing", [True, False])
def test_view_samples_only_write_the_same_lean_log(tmp_path, monkeypatch, events, view_hz,
                                                   chunk_size, chunk_s, step_chunks, block_framing):
    monkeypatch.setattr(sink_mod.McapSink, "block_framing", block_framing)
    stream = _stream(sum(map(ord, events)), EVENTS[events])
    kw = dict(chunk_size=chunk_size, chunk_s=chunk_s, step_chunks=step_chunks)
    whole = _write(tmp_path / "whole.mcap", stream, False, view_hz, **kw)
    thin = _write(tmp_path / "thin.mcap", stream, True, view_hz, **kw)
    assert thin[:3] == whole[:3]  # bytes, messages, flushes
    assert whole[2] > 3
    n = sum(b.n for batches, _e in stream for b in batches)
    if events != "clock_back":  # time goes forward: only the view's samples are sent
        assert thin[3] <= view_hz * n / 50.0 + 2 * len(stream) * 3
    if view_hz and events == "plain":
        assert thin[3] > 0


def test_a_step_whose_clock_steps_back_is_sent_whole():
    dec = ViewDecimator(1.0)
    t = T0 + np.arange(500, dtype=np.int64) * 20_000_000
    a = CorrectedBatch(t, np.zeros((500, 3)), np.zeros(500), 0)
    b = CorrectedBatch(t[:250] + 10 * S, np.zeros((250, 3)), np.zeros(250), 0)
    thinned = dec.thin([a, b])
    assert [x.n for x in thinned] == [10, 5]  # 10 s, then 5 s
    assert thinned[0].time_ns[1] - thinned[0].time_ns[0] <= S
    back = CorrectedBatch(t - 3 * S, np.zeros((500, 3)), np.zeros(500), 0)
    step = [back, a]
    assert dec.thin(step) == step  # the same batches, whole
    fresh = ViewDecimator(1.0)  # and its state is what picking them gives
    for x in (a, b, back, a):
        fresh.pick(x.time_ns)
    assert dec._last == fresh._last


def test_block_framing_runs_on_thinned_steps(tmp_path, monkeypatch):
    """The per-step framing path takes the thinned steps (not only the cell-by-cell one)."""
    framed = []
    frame = sink_mod._frame_block

    def counting(*a):
        done = frame(*a)
        framed.append(done)
        return done
    monkeypatch.setattr(sink_mod, "_frame_block", counting)
    _write(tmp_path / "thin.mcap", _stream(3, ()), True, 1.0)
    assert sum(framed) >= len(framed) - 2


# ---------------------------------------------------------------------------- whole runs
@pytest.fixture
def child(monkeypatch):
    """Batch runs write their log in the child process whatever the input's size, unless
    $STILLPOINT_CORES is "1"; returns the samples of the corrected batches the engine had and
    of those it sent (lean runs)."""
    monkeypatch.setattr(tuning, "SINK_PROCESS_MIN_BYTES", 0)
    monkeypatch.setattr(job_mod, "cores_available",
                        lambda: 1 if os.environ.get("STILLPOINT_CORES") == "1" else 2)
    monkeypatch.delenv(sinkproc.ENV, raising=False)
    monkeypatch.delenv("STILLPOINT_CORES", raising=False)
    seen = {"had": 0, "sent": 0}
    thin = ViewDecimator.thin

    def counting(self, batches):
        out = thin(self, batches)
        seen["had"] += sum(b.n for b in batches)
        seen["sent"] += sum(b.n for b in out)
        return out
    monkeypatch.setattr(ViewDecimator, "thin", counting)
    return seen


def _same_as_one_core(src, tmp_path, monkeypatch, settings):
    out = tmp_path / "r.mcap"  # the same names: the summary record names the outputs
    tables = TablesSettings(tmp_path / "r.epochs.csv.gz", tmp_path / "r.days.csv")
    two = process_file(src, out, settings, tables=tables)
    got = {p: p.read_bytes() for p in (out, tables.epochs_path, tables.days_path)}
    for p in got:
        p.unlink()
    monkeypatch.setenv("STILLPOINT_CORES", "1")
    one = process_file(src, out, settings, tables=tables)
    monkeypatch.delenv("STILLPOINT_CORES")
    for p, b in got.items():
        assert p.read_bytes() == b, p.name
    assert (one["mcap_messages"], one["mcap_flushes"]) == (two["mcap_messages"], two["mcap_flushes"])


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    rec = tmp_path_factory.mktemp("lean") / "rec.cwa"
    make_recording(rec, hours=2.0, rate=100.0, seed=23)
    return rec


@pytest.mark.parametrize("kw", [dict(view_hz=3.0, chunk_size=20000), dict(view_hz=0.07),
                                dict(view_hz=0.0)], ids=["3hz-small-chunks", "long-period", "no-view"])
def test_lean_child_gets_the_view_samples_and_writes_the_bytes_of_one_core(
        recording, tmp_path, child, monkeypatch, kw):
    _same_as_one_core(recording, tmp_path, monkeypatch, RunSettings(mode="batch", log="lean", **kw))
    if kw["view_hz"]:  # two hours at 100 Hz, of which the view's samples were sent
        assert child["had"] > 700_000
        assert child["sent"] <= kw["view_hz"] * 2 * 3600 + 100
    else:  # no view: no corrected sample is sent
        assert child == {"had": 0, "sent": 0}


@pytest.mark.parametrize("name", ["ax3_oxwearables_tiny_sample_3h_with_restart.cwa.gz",
                                  "ax6_ggirread_testfile_100hz_16g_gyro250dps.cwa",
                                  "geneactiv_actfast_cmi_60hz_20pages_LF_fw0617.bin"])
def test_lean_child_real_files(real_data_dir, tmp_path, child, monkeypatch, name):
    """A restart (two segments), gyro (AX6), GENEActiv pages."""
    src = real_data_dir / name
    if name.endswith(".gz"):
        plain = tmp_path / name[:-3]
        with gzip.open(src) as f, open(plain, "wb") as g:
            shutil.copyfileobj(f, g)
        src = plain
    for view_hz in (1.0, 7.0):
        _same_as_one_core(src, tmp_path, monkeypatch,
                          RunSettings(mode="batch", log="lean", view_hz=view_hz))
    assert 0 < child["sent"] < child["had"] / 5


@pytest.mark.parametrize("view_hz", [1.0, 3.0, 7.0, 0.07, 60.0])
def test_pick_sorted_is_pick(view_hz):
    """The binary-search pick of nondecreasing times (gaps over several periods, repeated times,
    batches of one sample) picks what the per-sample one picks, with the same state."""
    rng = np.random.default_rng(int(view_hz * 100))
    a, b = ViewDecimator(view_hz), ViewDecimator(view_hz)
    t = T0
    for _ in range(60):
        n = int(rng.integers(1, 3000))
        steps = rng.choice([0, 10_000_000, 20_000_000, 3 * S, 40 * S], size=n,
                           p=[0.05, 0.8, 0.14, 0.007, 0.003]).astype(np.int64)
        times = t + np.cumsum(steps)
        t = int(times[-1])
        assert np.array_equal(a.pick_sorted(times), b.pick(times))
        assert a._last == b._last
