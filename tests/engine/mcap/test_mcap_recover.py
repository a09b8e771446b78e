"""Crash safety: SIGKILL `process` at a random point, `recover`, and get every flushed message;
torn files cut at random offsets recover to a prefix of the complete run; CDR layouts."""

from __future__ import annotations

import os
import random
import signal
import struct
import subprocess
import sys
import time

import numpy as np
import pytest
from mcap.reader import make_reader

from stillpoint.engine.mcap.schemas import (ACCEL_BATCH, ACCEL_BATCH_RAW, ALL_TYPES, EPOCH_METRICS,
                                            TEMPERATURE)
from stillpoint.engine.mcap.sink import epoch_messages
from stillpoint.engine.operators.metrics import EpochMetrics
from stillpoint.engine.recover import is_finished, recover
from stillpoint.engine.run import RunSettings, process_file
from stillpoint.tools.cli import main as cli
from mcap_layout import conforms
from synthetic_recording import make_recording

TOPICS = ["/raw/accel", "/corrected/accel", "/metrics/epoch", "/temperature"]


def messages(path):
    out = {t: [] for t in TOPICS}
    with open(path, "rb") as f:
        for _s, ch, m in make_reader(f).iter_messages(topics=TOPICS, log_time_order=False):
            out[ch.topic].append((m.log_time, m.data))
    return out


def assert_prefix(part, full):
    for t in TOPICS:
        n = len(part[t])
        assert part[t] == full[t][:n], t


@pytest.fixture(scope="module")
def long_recording(tmp_path_factory):
    d = tmp_path_factory.mktemp("kill")
    rec = d / "rec.cwa"
    make_recording(rec, hours=4.0, rate=100.0, seed=11)
    full = d / "full.mcap"
    process_file(rec, full, RunSettings(mode="online"))
    return rec, full


def test_sigkill_then_recover_keeps_everything_up_to_the_last_flush(long_recording, tmp_path):
    rec, full = long_recording
    out = tmp_path / "killed.mcap"
    rng = random.Random(os.getpid())
    # The per-file job that `stillpoint process` runs, in a child whose progress callback pauses
    # 50 ms per pipeline block: the run then lasts over a second on any machine, so the kill
    # lands mid-run however fast the engine is (a plain CLI run of 4 h finishes in well under a
    # second on a quiet machine, before a kill could reach it).
    child = ("import sys, time\n"
             "from stillpoint.engine.run import RunSettings, process_file\n"
             "process_file(sys.argv[1], sys.argv[2], RunSettings(mode='online'),\n"
             "             progress=lambda label, stats: time.sleep(0.05))\n")
    p = subprocess.Popen([sys.executable, "-c", child, str(rec), str(out)])
    part = tmp_path / "killed.mcap.part"  # an unfinished log never sits under its final name
    deadline = time.time() + 60
    while time.time() < deadline and (not part.exists() or part.stat().st_size < 200_000):
        time.sleep(0.005)
    time.sleep(rng.uniform(0.0, 0.4))
    p.send_signal(signal.SIGKILL)
    p.wait()
    assert p.returncode == -signal.SIGKILL, "process finished before it could be killed"
    assert not out.exists() and not is_finished(part)
    with pytest.raises(Exception):  # noqa: B017 - whatever the mcap package raises without a summary
        with open(part, "rb") as f:
            make_reader(f).get_summary()
    fixed = tmp_path / "killed.recovered.mcap"  # the default name for killed.mcap.part
    assert cli(["recover", str(part)]) == 0
    conforms(fixed)  # the recovered file is spec-complete too
    assert is_finished(fixed)
    with open(fixed, "rb") as f:
        r = make_reader(f)
        summ = r.get_summary()
        meta = {m.name for m in r.iter_metadata()}
    assert summ is not None and summ.statistics.message_count > 0
    assert {"device", "settings"} <= meta
    got, ref = messages(fixed), messages(full)
    assert 0 < len(got["/raw/accel"]) < len(ref["/raw/accel"])
    assert_prefix(got, ref)  # byte-identical to the complete run, no holes
    # the raw and corrected streams were flushed together: they end within two 10 s cells
    last_raw = got["/raw/accel"][-1][0]
    last_cor = got["/corrected/accel"][-1][0]
    assert abs(last_raw - last_cor) <= 20 * 10**9


def test_torn_files_recover_to_a_prefix(long_recording, tmp_path):
    _rec, full = long_recording
    data = full.read_bytes()
    ref = messages(full)
    rng = random.Random(5)
    summary_start = struct.unpack_from("<Q", data, len(data) - 8 - 20)[0]
    counts = []
    for k in range(6):
        cut = rng.randrange(2000, len(data) - 100)
        torn = tmp_path / f"torn{k}.mcap"
        torn.write_bytes(data[:cut])
        rep = recover(torn, tmp_path / f"fixed{k}.mcap")
        got = messages(tmp_path / f"fixed{k}.mcap")
        assert_prefix(got, ref)
        assert rep.stopped_at or cut >= summary_start  # a torn tail was reached
        counts.append((cut, len(got["/raw/accel"])))
    counts.sort()
    assert [c for _cut, c in counts] == sorted(c for _cut, c in counts)  # more bytes, more data
    assert counts[-1][1] > 0


def test_recover_of_a_finished_file_copies_everything(long_recording, tmp_path):
    _rec, full = long_recording
    rep = recover(full, tmp_path / "copy.mcap")
    assert rep.finished and not rep.stopped_at
    assert messages(tmp_path / "copy.mcap") == messages(full)


# ---------------------------------------------------------------------- CDR layouts
def test_cdr_layout_bytes_and_alignment():
    # Temperature: header, int32 sec, uint32 nanosec, float64 at offset 8 (aligned) -> 20 bytes
    b = TEMPERATURE.encode({"stamp": 1_700_000_001_500_000_000, "celsius": 25.5})
    assert len(b) == 20 and b[:4] == b"\x00\x01\x00\x00"
    assert np.frombuffer(b, "<i4", 1, 4)[0] == 1_700_000_001
    assert np.frombuffer(b, "<u4", 1, 8)[0] == 500_000_000
    assert np.frombuffer(b, "<f8", 1, 12)[0] == 25.5
    # odd-length int16 sequences force padding before the next uint32 count
    n = 11
    v = {"stamp": 0, "t0_ns": 5, "segment": 2, "first_sample": 7, "counts_per_g": [256.0] * 3,
         "zero_counts": [0.0] * 3, "dt_ns": np.arange(n, dtype=np.int32),
         "x": np.arange(n, dtype=np.int16), "y": -np.arange(n, dtype=np.int16),
         "z": np.full(n, 3, np.int16), "unit_index": np.array([4]), "unit_sequence": np.array([9]),
         "unit_start": np.array([0]), "temperature_c": np.array([21.25]),
         "temperature_raw": np.array([243]), "light": np.array([10]), "battery_v": np.array([4.0]),
         "events": np.array([1], np.uint8), "light_raw": np.zeros(0), "button": np.zeros(0)}
    raw = ACCEL_BATCH_RAW.encode(v)
    body = raw[4:]
    # stamp 0..8, t0 8, segment 16, first 24, cpg 32..56, zero 56..80, dt count @80, dt @84
    assert np.frombuffer(body, "<i8", 1, 8)[0] == 5
    assert np.frombuffer(body, "<u4", 1, 80)[0] == n
    xo = 84 + 4 * n
    assert np.frombuffer(body, "<u4", 1, xo)[0] == n
    yo = xo + 4 + 2 * n
    yo += (-yo) % 4
    assert np.frombuffer(body, "<u4", 1, yo)[0] == n
    assert np.array_equal(np.frombuffer(body, "<i2", n, yo + 4), -np.arange(n))
    d = ACCEL_BATCH_RAW.decode(raw)
    for k in ("dt_ns", "x", "y", "z", "unit_index", "temperature_c", "events"):
        assert np.array_equal(d[k], np.asarray(v[k])), k
    assert d["segment"] == 2 and d["first_sample"] == 7 and len(d["button"]) == 0


def test_schema_texts_are_ros2msg_with_time_dependency():
    for t in ALL_TYPES:
        text = t.schema_text()
        assert "builtin_interfaces/Time stamp" in text
        assert "MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec" in text
    assert "float32[] x" in ACCEL_BATCH.schema_text()


def test_vectorised_epoch_encoding_equals_the_generic_encoder():
    k = 4
    m = EpochMetrics(start_ns=np.arange(k, dtype=np.int64) * 5 * 10**9 + 1_700_000_000 * 10**9,
                     n=np.full(k, 500), enmo_mg=np.arange(k) * 1.5, bfen_mg=np.ones(k),
                     mad_mg=np.full(k, 2.0), mean=np.tile([0.1, 0.2, 0.97], (k, 1)),
                     temperature=np.full(k, 30.0), segment=np.zeros(k, np.int64))
    fast = epoch_messages(m)
    for i in range(k):
        slow = EPOCH_METRICS.encode({"stamp": int(m.start_ns[i]), "n": 500, "enmo_mg": m.enmo_mg[i],
                                     "bfen_mg": 1.0, "mad_mg": 2.0, "x": 0.1, "y": 0.2, "z": 0.97,
                                     "temperature_c": 30.0})
        assert fast[i] == slow
