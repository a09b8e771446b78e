"""Our MCAP writer (engine/mcap/chunks.py + engine/mcap/writer.py) against the mcap package's
reader: valid records, chunk CRCs, summary CRC, statistics, chunk and metadata indexes, every
compression; the vectorised fixed-size message path equals the one-by-one path."""

from __future__ import annotations

import struct
import zlib

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.stream_reader import StreamReader

from stillpoint.engine.mcap import records as rec
from stillpoint.engine.mcap.chunks import ChunkBuilder
from stillpoint.engine.mcap.writer import _WriterCore

SCHEMAS = {"a/Msg": ("ros2msg", b"int32 x\n"), "b/Other": ("ros2msg", b"float64 y\n")}


def _write(path, compression, plan, fixed=False):
    core = _WriterCore(str(path), compression, 1.0)
    cb = ChunkBuilder(SCHEMAS, chunk_size=1 << 20)
    core.execute("metadata", "device", {"k": "v"})
    for cell in plan:
        for topic, schema, t, data in cell:
            cb.add(cb.channel(topic, "cdr" if schema else "json", schema), t, data)
        c = cb.take()
        if c is not None:
            core.execute("chunk", *c, False)
    if fixed:  # 5 fixed-size messages at once
        cid = cb.channel("/fixed", "cdr", "a/Msg")
        pay = np.arange(5 * 8, dtype=np.uint8).reshape(5, 8)
        cb.add_fixed(cid, np.array([10, 11, 12, 13, 14]) * 10**9, pay)
        core.execute("chunk", *cb.take(), True)
    core.execute("metadata", "summary", {"n": "1"})
    core.execute("finish", cb.summary(metadata_count=2))


def _plan(rng, cells=7):
    plan = []
    t = 1_700_000_000 * 10**9
    for _c in range(cells):
        cell = []
        for _k in range(int(rng.integers(0, 5))):
            topic, schema = [("/raw", "a/Msg"), ("/other", "b/Other"), ("/qc", None)][int(rng.integers(3))]
            t += int(rng.integers(1, 10**9))
            cell.append((topic, schema, t, rng.bytes(int(rng.integers(0, 300)))))
        plan.append(cell)
    return plan


@pytest.mark.parametrize("compression", ["zstd", "lz4", "none"])
def test_written_file_reads_back_with_valid_crcs_and_summary(tmp_path, compression):
    rng = np.random.default_rng(1)
    plan = _plan(rng)
    p = tmp_path / "w.mcap"
    _write(p, compression, plan, fixed=True)
    want = [(topic, t, data) for cell in plan for topic, _s, t, data in cell]
    with open(p, "rb") as f:
        r = make_reader(f, validate_crcs=True)
        summ = r.get_summary()
        got = [(ch.topic, m.log_time, m.data) for _s, ch, m in r.iter_messages(log_time_order=False)]
        meta = {m.name: m.metadata for m in r.iter_metadata()}
    # messages of each topic in the order written; inside a chunk the CDR topics are grouped
    # between the JSON (/qc) messages and Channel records, which keep their places
    assert len(got) == len(want) + 5
    for topic in ("/raw", "/other", "/qc"):
        assert [m for m in got[:len(want)] if m[0] == topic] == [m for m in want if m[0] == topic]
    seen, at = set(), 0
    for cell in plan:
        segs = [[]]
        for topic, _s, t, data in cell:
            m = (topic, t, data)
            if topic == "/qc" or topic not in seen:  # a JSON message or a new Channel record
                segs.append([])
            seen.add(topic)
            segs[-1].append(m)
        for seg in segs:
            lead = [m for m in seg[:1] if m[0] == "/qc"]
            rest = seg[len(lead):]
            grouped = lead + [m for i in dict.fromkeys(m[0] for m in rest) for m in rest if m[0] == i]
            assert got[at:at + len(seg)] == grouped
            at += len(seg)
    assert got[:len(want)] != want  # the plan does interleave topics inside a chunk
    fixed = got[len(want):]
    assert [t for _tp, t, _d in fixed] == [k * 10**9 for k in range(10, 15)]
    assert [d for _tp, _t, d in fixed] == [bytes(range(8 * i, 8 * i + 8)) for i in range(5)]
    st = summ.statistics
    assert st.message_count == len(want) + 5
    per_topic = {}
    for topic, _t, _d in got:
        per_topic[topic] = per_topic.get(topic, 0) + 1
    assert {summ.channels[c].topic: n for c, n in st.channel_message_counts.items()} == per_topic
    assert st.chunk_count == len(summ.chunk_indexes) == sum(1 for c in plan if c) + 1
    assert st.message_start_time == min(t for _tp, t, _d in got)
    assert st.message_end_time == max(t for _tp, t, _d in got)
    assert meta == {"device": {"k": "v"}, "summary": {"n": "1"}}
    assert {c.compression for c in summ.chunk_indexes} == {"" if compression == "none" else compression}
    # the streaming reader (what recover uses) sees every record, chunk CRCs checked
    with open(p, "rb") as f:
        recs = list(StreamReader(f, validate_crcs=True).records)
    assert sum(type(x).__name__ == "Message" for x in recs) == len(want) + 5
    # the footer's summary CRC covers the summary through the footer's offsets
    data = p.read_bytes()
    foot = data.rfind(b"\x02" + struct.pack("<Q", 20), 0, len(data) - 8)
    start, _off, crc = struct.unpack_from("<QQI", data, foot + 9)
    assert crc == zlib.crc32(data[start:foot + 9 + 16]) != 0


def test_fixed_size_messages_equal_one_by_one(tmp_path):
    cb1, cb2 = ChunkBuilder(SCHEMAS, 1 << 20), ChunkBuilder(SCHEMAS, 1 << 20)
    rng = np.random.default_rng(2)
    pay = rng.integers(0, 256, (9, 12), dtype=np.uint8)
    times = np.sort(rng.integers(0, 10**15, 9))
    c1 = cb1.channel("/e", "cdr", "a/Msg")
    for t, row in zip(times.tolist(), pay):
        cb1.add(c1, t, row.tobytes())
    cb2.add_fixed(cb2.channel("/e", "cdr", "a/Msg"), times, pay)
    assert cb1.take() == cb2.take()


def test_chunk_size_bound_and_lazy_channel_records():
    cb = ChunkBuilder(SCHEMAS, chunk_size=1000)
    cid = cb.channel("/x", "cdr", "a/Msg")
    assert not cb.add(cid, 5, b"\x00" * 100)
    assert cb.add(cid, 6, b"\x00" * 1000)  # the chunk reached its size: take it
    data, lo, hi, indexes = cb.take()
    assert [c for c, _r in indexes] == [cid]
    assert (lo, hi) == (5, 6)
    assert data.startswith(rec.schema(1, "a/Msg", "ros2msg", b"int32 x\n"))
    assert cb.take() is None


# ---------------------------------------------------------------------- the sink's fast paths
def _block(n_units=30, per=120, step_at=None, gyro=False):
    from stillpoint.engine.core.blocks import Block
    n = n_units * per
    t = 1_700_000_003 * 10**9 + np.arange(n, dtype=np.int64) * 10_000_000
    if step_at is not None:
        t[step_at:] += 5 * 10**9  # a 5 s clock step inside the segment (does not fit int32 ns)
    rng = np.random.default_rng(4)
    return Block(time_ns=t, accel=rng.integers(-500, 500, (n, 3)).astype(np.int16),
                 accel_counts_per_g=np.array([256.0, 256.0, 256.0]), accel_zero=np.zeros(3),
                 gyro=rng.integers(-900, 900, (n, 3)).astype(np.int16) if gyro else None,
                 gyro_dps_per_count=0.0076 if gyro else None,
                 unit_index=np.arange(n_units, dtype=np.int64) + 7,
                 unit_sequence=np.arange(n_units, dtype=np.int64) + 100,
                 unit_start=np.arange(n_units, dtype=np.int64) * per,
                 temperature_c=np.where(np.arange(n_units) % 5 == 1, np.nan, 25.0 + np.arange(n_units) / 8),
                 temperature_raw=np.arange(n_units, dtype=np.int32), light=np.arange(n_units, dtype=np.int32),
                 battery_v=np.full(n_units, 4.1), events=np.zeros(n_units, np.uint8), segment=3,
                 first_sample=1000)


@pytest.mark.parametrize("step_at", [None, 1800])
def test_sink_raw_and_corrected_messages_reproduce_the_block(tmp_path, step_at):
    from stillpoint.engine.core.blocks import DeviceInfo
    from stillpoint.engine.mcap.schemas import (ACCEL_BATCH, ACCEL_BATCH_RAW, GYRO_BATCH_RAW,
                                                TEMPERATURE, times_from_deltas)
    from stillpoint.engine.mcap.sink import McapSink, quantize
    from stillpoint.engine.operators.correction import CorrectedBatch
    from stillpoint.engine.operators.metrics import EpochMetrics
    blk = _block(step_at=step_at, gyro=True)
    p = tmp_path / "s.mcap"
    sink = McapSink(p, DeviceInfo(path="x", device_type="AX6", device_id="1", session_id=0, firmware=0,
                                      sample_rate_nominal=100.0, accel_range_g=8.0), {}, writer="inline")
    g = blk.accel_g()
    half = blk.n // 2  # the corrected stream arrives in two batches (a cell spans both)
    cor = [CorrectedBatch(blk.time_ns[a:b], g[a:b], np.zeros(b - a), blk.segment)
           for a, b in ((0, half), (half, blk.n))]
    sink.write_slices(blk, cor, EpochMetrics.empty())
    sink.close()
    with open(p, "rb") as f:
        msgs = {}
        for _s, ch, m in make_reader(f).iter_messages(log_time_order=False):
            msgs.setdefault(ch.topic, []).append(m.data)
    raws = [ACCEL_BATCH_RAW.decode(d) for d in msgs["/raw/accel"]]
    assert len(raws) >= 3  # 10 s cells (and a split at the clock step)
    t = np.concatenate([times_from_deltas(r["t0_ns"], r["dt_ns"]) for r in raws])
    assert np.array_equal(t, blk.time_ns)
    xyz = np.concatenate([np.stack([r["x"], r["y"], r["z"]], 1) for r in raws])
    assert np.array_equal(xyz, blk.accel)
    us = np.concatenate([r["unit_start"] + (r["first_sample"] - 1000) for r in raws])
    assert np.array_equal(us, blk.unit_start)
    for name in ("unit_index", "unit_sequence", "temperature_raw", "light", "battery_v"):
        assert np.array_equal(np.concatenate([r[name] for r in raws]), getattr(blk, name)), name
    gy = [GYRO_BATCH_RAW.decode(d) for d in msgs["/raw/gyro"]]
    assert np.array_equal(np.concatenate([np.stack([r["x"], r["y"], r["z"]], 1) for r in gy]), blk.gyro)
    # temperature: mean of each raw message's finite unit temperatures
    temps = [TEMPERATURE.decode(d)["celsius"] for d in msgs["/temperature"]]
    want = [np.nanmean(r["temperature_c"]) for r in raws]
    assert np.allclose(temps, want, rtol=0, atol=1e-12)
    cs = [ACCEL_BATCH.decode(d) for d in msgs["/corrected/accel"]]
    tc = np.concatenate([times_from_deltas(c["t0_ns"], c["dt_ns"]) for c in cs])
    assert np.array_equal(tc, blk.time_ns)
    ac = np.concatenate([np.stack([c["x"], c["y"], c["z"]], 1) for c in cs])
    assert np.array_equal(ac, quantize(g, 2.0 ** -16))
    cells = {int(c["t0_ns"]) // 10**10 for c in cs}
    assert len(cs) == len(cells) + (step_at is not None)  # one message per cell (+ the split)


def test_encode_values_equals_encode_for_every_type():
    from stillpoint.engine.mcap.schemas import ALL_TYPES, _PRIM, _parse
    rng = np.random.default_rng(9)
    for typ in ALL_TYPES:
        vals = {}
        for f, t in typ.fields:
            if t == "time":
                vals[f] = int(rng.integers(0, 2**62))
                continue
            base, k = _parse(t)
            dt = np.dtype(_PRIM[base])
            n = 3 if k is None and rng.random() < 0.5 else (int(rng.integers(0, 7)) if k is None else k)
            arr = (rng.random(n) * 100).astype(dt)
            vals[f] = arr[0].item() if k == 0 and n else (arr if k != 0 else dt.type(1).item())
        want = typ.encode(vals)
        assert typ.encode_values([vals[f] for f, _t in typ.fields]) == want, typ.name


def test_writer_modes_write_the_same_messages(tmp_path):
    from stillpoint.engine.mcap.compare import compare
    from stillpoint.engine.run import RunSettings, process_file
    from stillpoint.tools.cli.commands.demo import make_recording
    rec_path = tmp_path / "r.cwa"
    make_recording(rec_path, hours=0.25, rate=50.0, seed=5)
    outs = {}
    for mode in ("inline", "thread", "process"):
        outs[mode] = tmp_path / f"{mode}.mcap"
        s = process_file(rec_path, outs[mode], RunSettings(mode="batch"), writer=mode)
        assert s["mcap_flushes"] >= 0.25 * 3600 / 60 - 2  # batch: 60 s chunks
    for mode in ("thread", "process"):
        res = compare(outs["inline"], outs[mode])
        assert all(r["identical"] for r in res.values()), (mode, res)
        assert res["/raw/accel"]["messages"][0] >= 80
    assert s["peak_rss_mb"]["writer"] is not None  # the process writer reports its own peak


@pytest.mark.parametrize("compression", ["zstd", "none"])
def test_layout_follows_the_specification(tmp_path, compression):
    """Message indexes after every chunk, chunk indexes pointing at them, data-section CRC,
    summary offsets: checked by a parser written against the MCAP specification and by the
    mcap package's indexed reader; also when the chunk index spool goes to disk."""
    from mcap_layout import conforms

    from stillpoint.engine.mcap import writer as w
    rng = np.random.default_rng(3)
    p = tmp_path / "w.mcap"
    old = w._ChunkIndexSpool.SPOOL_BYTES
    w._ChunkIndexSpool.SPOOL_BYTES = 300  # a few chunk index records, then the disk
    try:
        _write(p, compression, _plan(rng, cells=40), fixed=True)
    finally:
        w._ChunkIndexSpool.SPOOL_BYTES = old
    rep = conforms(p)
    assert rep["chunks"] > 10 and rep["data_crc"] != 0
    # the mcap package's own view of the same indexes
    with open(p, "rb") as f:
        summ = make_reader(f).get_summary()
    assert all(c.message_index_offsets and c.message_index_length for c in summ.chunk_indexes)


def test_layout_checker_catches_a_missing_message_index(tmp_path):
    """The checker is not a rubber stamp: a file whose message indexes are dropped fails."""
    from mcap_layout import check_layout
    rng = np.random.default_rng(4)
    p = tmp_path / "w.mcap"
    _write(p, "none", _plan(rng, cells=5))
    check_layout(p)
    buf = bytearray(p.read_bytes())
    at = buf.find(bytes([rec.OP_MESSAGE_INDEX]) + struct.pack("<Q", 6 + 16))
    assert at > 0
    buf[at] = 0x7F  # no longer a Message Index record
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(buf))
    with pytest.raises(AssertionError):
        check_layout(bad)


@pytest.mark.parametrize("few", [-1, 1 << 20])
def test_message_indexes_of_small_and_large_chunks_agree(tmp_path, monkeypatch, few):
    """Chunks with few index entries take a plain-Python path: the file must be the same,
    regrouped chunks (several cells of interleaved topics, out-of-order times) included."""
    from stillpoint.engine.mcap import chunks
    rng = np.random.default_rng(5)
    plan = _plan(rng, cells=12)
    for cell in plan[::3]:  # out-of-order log times inside a chunk
        cell.reverse()
    a, b = tmp_path / "a.mcap", tmp_path / "b.mcap"
    _write(a, "none", plan, fixed=True)
    monkeypatch.setattr(chunks, "_FEW_ENTRIES", few)
    _write(b, "none", plan, fixed=True)
    assert a.read_bytes() == b.read_bytes()


def _whole_chunk_records(rng, cids, nchunks, seq):
    """Message records of ``nchunks`` chunks, each channel's records of a chunk in one run
    (times in any order), with their channel, log time and offset from the start."""
    data, bounds, mc, mt, mo = [], [0], [], [], []
    at = 0
    t = 1_700_000_000 * 10**9
    for _k in range(nchunks):
        for cid in rng.permutation(cids)[:int(rng.integers(1, len(cids) + 1))].tolist():
            for _m in range(int(rng.integers(1, 6))):
                tm = t + int(rng.integers(-10**9, 10**10))
                r = rec.message(cid, seq[cid], tm, tm, rng.bytes(int(rng.integers(0, 200))))
                seq[cid] += 1
                data.append(r)
                mc.append(cid)
                mt.append(tm)
                mo.append(at)
                at += len(r)
        t += 10**10
        bounds.append(at)
    return (b"".join(data), np.array(bounds, np.int64), np.array(mc, np.int64),
            np.array(mt, np.int64), np.array(mo, np.int64))


@pytest.mark.parametrize("compression", ["zstd", "none"])
def test_whole_chunks_at_once_equal_one_chunk_at_a_time(tmp_path, compression):
    """ChunkBuilder.whole_chunks + the writer's "chunks" operation (an online run's cells,
    many at once, more than one writev's worth) write the bytes that add_framed + take + "chunk"
    write chunk by chunk; the file follows the specification."""
    from mcap_layout import conforms
    outs = []
    for how in ("one", "many"):
        p = tmp_path / f"{how}.mcap"
        core = _WriterCore(str(p), compression, 1.0)
        cb = ChunkBuilder(SCHEMAS, chunk_size=1 << 20)
        cids = [cb.channel(f"/t{i}", "cdr", "a/Msg") for i in range(4)]
        cb.add(cids[0], 5, b"first")  # the Channel records go into a chunk of their own
        core.execute("chunk", *cb.take(), False)
        seq = {c: cb.sequence(c) for c in cids}
        data, bounds, mc, mt, mo = _whole_chunk_records(np.random.default_rng(7), cids, 400, seq)
        if how == "one":
            for i in range(bounds.shape[0] - 1):
                sel = (mo >= bounds[i]) & (mo < bounds[i + 1])
                c, o = mc[sel], mo[sel]
                runs = np.flatnonzero(np.r_[True, c[1:] != c[:-1]])  # one run per channel
                edges = np.append(o[runs], bounds[i + 1]).tolist()
                parts = [data[a:b] for a, b in zip(edges[:-1], edges[1:])]
                counts = dict(zip(*[a.tolist() for a in np.unique(c, return_counts=True)]))
                cb.add_framed(parts, int(bounds[i + 1] - bounds[i]), c, mt[sel], o - bounds[i],
                              counts, c[runs].tolist())
                core.execute("chunk", *cb.take(), False)
        else:
            counts = dict(zip(*[a.tolist() for a in np.unique(mc, return_counts=True)]))
            core.execute("chunks", *cb.whole_chunks(data, bounds, mc, mt, mo, counts), False)
        cb.add(cids[1], 10**19 // 10, b"last")
        core.execute("chunk", *cb.take(), True)
        core.execute("finish", cb.summary(metadata_count=0))
        outs.append(p.read_bytes())
        rep = conforms(p)
        assert rep["chunks"] == 402
    assert outs[0] == outs[1]
