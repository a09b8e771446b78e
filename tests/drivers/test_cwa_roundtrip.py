"""Write -> read round trips of synthetic .cwa files: counts exact, times within the format's
resolution, aux channels, QC; batch-size invariance; fast path == reference path."""

from __future__ import annotations

import gzip
import shutil

import numpy as np
import pytest

from stillpoint.drivers import open_recording
from stillpoint.drivers.cwa import CwaReader, CwaWriter, read_header, read_sector
from stillpoint.engine.core.source import Source

from cwa_helpers import qc_reasons, read_all, synth

RES_NS = 1e9 / 32768  # anchor resolution


def _write(path, t, a, **kw):
    gyro = kw.pop("gyro_counts", None)
    aux = {k: kw.pop(k) for k in list(kw) if k in ("temperature_raw", "light_raw", "battery_raw", "events")}
    with CwaWriter(path, **kw) as w:
        w.write(t, a, gyro_counts=gyro, **aux)
    return w


def test_packed_ax3_roundtrip(tmp_path):
    n = 120 * 50 + 37  # ends with a short sector
    t, a = synth(n)
    temp = 250 + (np.arange(n) // 1000)
    p = tmp_path / "a.cwa"
    w = _write(p, t, a, device_id=70123, session_id=5, metadata={"_sc": "P01", "Body Location": "left wrist"},
               temperature_raw=temp, battery_raw=180, light_raw=300)
    assert w.sectors_written == 51
    r = read_all(p)
    info = r["reader"].info
    assert (info.device_type, info.device_id, info.session_id) == ("AX3", "70123", 5)
    assert info.sample_rate_nominal == 100.0 and info.accel_range_g == 8.0
    assert info.metadata == {"Subject Code": "P01", "Body Location": "left wrist"}
    assert r["n"] == n
    np.testing.assert_array_equal(r["accel"], a)
    err = np.abs(r["time"] - t)
    assert err.max() <= RES_NS  # every sample within the anchor resolution
    starts = np.arange(0, n, 120)
    np.testing.assert_array_equal(r["temperature_raw"], temp[starts])
    np.testing.assert_allclose(r["temperature_c"], temp[starts] * 75 / 256 - 50)
    np.testing.assert_allclose(r["battery_v"], (180 + 512) * 6 / 1024)
    assert (r["light"] == 300).all()
    assert r["events"][0] == 1 and not r["events"][1:].any()  # RESUME on the first sector
    assert r["reader"].qc.events == [] and r["reader"].qc.segments == 1
    assert r["blocks"][0].accel.dtype == np.int16
    np.testing.assert_array_equal(r["blocks"][0].accel_counts_per_g, [256, 256, 256])


def test_packed_saturates_and_drops_low_bits(tmp_path):
    t, _ = synth(240)
    a = np.zeros((240, 3), np.int64)
    a[0] = (5, -7, 100000)  # +-8 g: e=2 -> floor to multiples of 4, saturate at 511*4
    p = tmp_path / "s.cwa"
    _write(p, t, a)
    r = read_all(p)
    np.testing.assert_array_equal(r["accel"][0], [4, -8, 2044])


@pytest.mark.parametrize("range_g", [2, 4, 8, 16])
def test_packed_exponent_per_range(tmp_path, range_g):
    e = {2: 0, 4: 1, 8: 2, 16: 3}[range_g]
    t, a = synth(300, multiple=1 << e, seed=range_g)
    p = tmp_path / "r.cwa"
    _write(p, t, a, range_g=range_g)
    r = read_all(p)
    assert r["reader"].info.accel_range_g == range_g
    np.testing.assert_array_equal(r["accel"], a)


def test_unpacked_ax3_roundtrip(tmp_path):
    t, a = synth(80 * 20 + 5, rate=50.0, multiple=1, limit=4000)
    p = tmp_path / "u.cwa"
    _write(p, t, a, packed=False, rate_hz=50.0)
    r = read_all(p)
    assert read_sector(p, 0)["num_axes_bps"][0] == 0x32
    np.testing.assert_array_equal(r["accel"], a)
    assert np.abs(r["time"] - t).max() <= RES_NS


def test_ax6_gyro_roundtrip(tmp_path):
    n = 40 * 30 + 11
    t, a = synth(n, multiple=1, limit=30000, seed=3)
    g = np.random.default_rng(4).integers(-32768, 32767, (n, 3))
    p = tmp_path / "g.cwa"
    _write(p, t, a, device_type="AX6", range_g=16, gyro_range_dps=500, device_id=0x5BBB8A, gyro_counts=g)
    r = read_all(p)
    info = r["reader"].info
    assert info.device_type == "AX6" and info.device_id == str(0x5BBB8A)
    assert info.gyro_range_dps == 500 and info.channels[3:] == ("gyro_x", "gyro_y", "gyro_z")
    np.testing.assert_array_equal(r["accel"], a)
    np.testing.assert_array_equal(r["gyro"], g)
    b = r["blocks"][0]
    np.testing.assert_array_equal(b.accel_counts_per_g, [2048] * 3)
    assert b.gyro_dps_per_count == 500 / 32768
    assert np.abs(r["time"] - t).max() <= RES_NS


def test_ax6_accel_only_scale(tmp_path):
    t, a = synth(200, multiple=1, limit=30000)
    p = tmp_path / "a6.cwa"
    _write(p, t, a, device_type="AX6", range_g=4)
    r = read_all(p)
    assert r["blocks"][0].accel_counts_per_g[0] == 8192 and r["gyro"] is None
    np.testing.assert_array_equal(r["accel"], a)


@pytest.mark.parametrize("rate", [6.25, 12.5, 400.0, 3200.0])
def test_rates_roundtrip(tmp_path, rate):
    t, a = synth(1000, rate=rate, drift=1.013)
    p = tmp_path / "x.cwa"
    _write(p, t, a, rate_hz=rate)
    r = read_all(p)
    assert r["reader"].info.sample_rate_nominal == rate
    assert np.abs(r["time"] - t).max() <= RES_NS
    np.testing.assert_array_equal(r["accel"], a)


def test_no_fraction_timestamps(tmp_path):
    """Old firmware (no fractional timestamp): times good to about one sample."""
    t, a = synth(2400)
    p = tmp_path / "nf.cwa"
    _write(p, t, a, fractional=False)
    assert not read_sector(p, 3)["device_fractional"][0] & 0x8000
    r = read_all(p)
    assert np.abs(r["time"] - t).max() < 1.5e9 / 100


def test_restart_makes_two_segments(tmp_path):
    t, a = synth(1000)
    t2, a2 = synth(700, start_ns=int(t[-1]) + 244_000_000_000, seed=9)
    p = tmp_path / "rs.cwa"
    with CwaWriter(p) as w:
        w.write(t, a)
        w.restart()
        w.write(t2, a2)
    r = read_all(p)
    rd = r["reader"]
    k = int(np.ceil(1000 / 120))
    assert qc_reasons(rd) == [(k, "restart")]
    assert rd.qc.segments == 2
    np.testing.assert_array_equal(r["accel"], np.concatenate([a, a2]))
    assert np.abs(r["time"] - np.concatenate([t, t2])).max() <= RES_NS
    np.testing.assert_array_equal(np.bincount(r["segment"]), [1000, 700])
    assert r["unit_sequence"][k] == 0 and r["events"][k] & 1


def _file_with_anomalies(path):
    """A 40-sector file with corrupt, duplicated, gap, session, bad-timestamp and erased sectors."""
    n = 120 * 40
    t, a = synth(n, seed=11)
    k = np.arange(n) // 120
    _write(path, t, a, battery_raw=150 + k, temperature_raw=240 + 2 * k, light_raw=100 + 3 * k)
    raw = bytearray(path.read_bytes())
    hdr, body = raw[:1024], raw[1024:]
    secs = [bytes(body[i:i + 512]) for i in range(0, len(body), 512)]
    secs.insert(8, secs[7])  # exact duplicate of sector 7 at index 8
    del secs[20]  # sequence gap (19 -> 21 after the insert shift: original 19 missing)
    secs.append(b"\xff" * 512)
    secs.append(b"\xff" * 512)
    path.write_bytes(bytes(hdr) + b"".join(secs))
    from stillpoint.drivers.cwa import corrupt_sector, patch_sector
    corrupt_sector(path, 3)
    corrupt_sector(path, 12, "timestamp")
    patch_sector(path, 30, timestamp=0)  # valid checksum, unusable anchor
    for i in range(33, 40):
        patch_sector(path, i, session_id=77)
    return t, a


def test_anomalies_qc_and_segments(tmp_path):
    p = tmp_path / "an.cwa"
    _file_with_anomalies(p)
    r = read_all(p)
    rd = r["reader"]
    assert qc_reasons(rd) == [
        (3, "checksum"), (4, "sequence_gap"), (8, "duplicate"), (12, "checksum"),
        (13, "sequence_gap"), (20, "sequence_gap"), (30, "bad_timestamp"),
        (33, "session_change"), (40, "erased")]
    assert rd.qc.total == 42 and rd.qc.skipped == 5 and rd.qc.valid == 37
    times = [e.time_ns for e in rd.qc.events]
    assert None not in times and times == sorted(times)
    assert rd.qc.segments == 5
    assert r["n"] == 37 * 120
    # the sector with timestamp 0 keeps its samples, timed from its neighbours
    assert 30 in r["unit_index"]


@pytest.mark.parametrize("batch", [1, 2, 3, 5, 7, 16, 4096])
def test_batch_size_invariance(tmp_path, batch):
    p = tmp_path / "an.cwa"
    _file_with_anomalies(p)
    ref = read_all(p, batch_sectors=2048)
    got = read_all(p, batch_sectors=batch)
    for k in ("time", "accel", "segment", "unit_index", "unit_sequence", "temperature_raw",
              "temperature_c", "light", "battery_v", "events"):
        np.testing.assert_array_equal(got[k], ref[k], err_msg=k)
    assert qc_reasons(got["reader"]) == qc_reasons(ref["reader"])


@pytest.mark.parametrize("batch", [1, 4, 64, 2048])
def test_fast_path_equals_reference_path(tmp_path, batch):
    t, a = synth(120 * 300 + 17, drift=1.021, seed=5)
    p = tmp_path / "c.cwa"
    _write(p, t, a)
    fast = read_all(p, batch_sectors=batch)
    r = CwaReader(p, batch_sectors=batch)
    r._force_slow = True
    slow = list(r)
    np.testing.assert_array_equal(np.concatenate([b.time_ns for b in slow]), fast["time"])
    np.testing.assert_array_equal(np.concatenate([b.accel for b in slow]), fast["accel"])


def test_negative_timestamp_offset_ax6(tmp_path):
    """AX6 anchors with negative offsets (as real AX6 files have) round-trip."""
    n = 40 * 50
    t, a = synth(n, multiple=1, limit=2000, seed=8)
    g = np.zeros((n, 3), np.int64)
    p = tmp_path / "neg.cwa"
    _write(p, t, a, device_type="AX6", gyro_range_dps=2000, gyro_counts=g)
    offs = [int(read_sector(p, i)["timestamp_offset"][0]) for i in range(50)]
    assert min(offs) < 0
    for batch in (1, 3, 2048):
        r = read_all(p, batch_sectors=batch)
        assert np.abs(r["time"] - t).max() <= RES_NS


def test_truncated_mid_sector(tmp_path):
    t, a = synth(120 * 10)
    p = tmp_path / "tr.cwa"
    _write(p, t, a)
    data = p.read_bytes()
    p.write_bytes(data[:1024 + 512 * 7 + 200])
    r = read_all(p)
    assert qc_reasons(r["reader"]) == [(7, "truncated")]
    assert r["n"] == 7 * 120
    np.testing.assert_array_equal(r["accel"], a[:840])


def test_time_jump_breaks_segment(tmp_path):
    from stillpoint.drivers.cwa import patch_sector
    t, a = synth(120 * 12)
    p = tmp_path / "tj.cwa"
    _write(p, t, a)
    from stillpoint.drivers.cwa_layout import pack_timestamp, unpack_timestamp
    for i in range(6, 12):
        ts = unpack_timestamp(int(read_sector(p, i)["timestamp"][0]))
        patch_sector(p, i, timestamp=pack_timestamp(ts + 3600))
    r = read_all(p)
    assert qc_reasons(r["reader"]) == [(6, "time_jump")]
    assert r["reader"].qc.segments == 2
    shifted = t.copy()
    shifted[720:] += 3600 * 10**9
    assert np.abs(r["time"] - shifted).max() <= RES_NS


def test_all_sectors_corrupt_raises_after_qc(tmp_path):
    from stillpoint.drivers.cwa import corrupt_sector
    from stillpoint.engine.core.errors import CorruptRecordingError
    t, a = synth(120 * 4)
    p = tmp_path / "bad.cwa"
    _write(p, t, a)
    for i in range(4):
        corrupt_sector(p, i)
    r = CwaReader(p)
    with pytest.raises(CorruptRecordingError, match=r"bad\.cwa.*none of the 4 data sectors.*checksum x4"):
        list(r)
    assert r.qc.total == 4 and r.qc.skipped == 4 and r.qc.valid == 0


def test_header_only_file_yields_nothing(tmp_path):
    p = tmp_path / "h.cwa"
    CwaWriter(p).close()
    r = CwaReader(p)
    assert list(r) == [] and r.qc.total == 0


def test_gzip_equals_plain(tmp_path):
    t, a = synth(120 * 30 + 3)
    p = tmp_path / "z.cwa"
    _write(p, t, a)
    gz = tmp_path / "z.cwa.gz"
    with open(p, "rb") as src, gzip.open(gz, "wb") as dst:
        shutil.copyfileobj(src, dst)
    a1, a2 = read_all(p, batch_sectors=7), read_all(gz, batch_sectors=7)
    np.testing.assert_array_equal(a1["time"], a2["time"])
    np.testing.assert_array_equal(a1["accel"], a2["accel"])


def test_damaged_gzip_keeps_what_was_read(tmp_path):
    t, a = synth(120 * 200)
    p = tmp_path / "z.cwa"
    _write(p, t, a)
    gz = tmp_path / "z.cwa.gz"
    gz.write_bytes(gzip.compress(p.read_bytes())[:-5000])
    r = read_all(gz, batch_sectors=16)
    assert r["reader"].qc.events[-1].reason in ("read_error", "truncated")
    assert 0 < r["n"] < 120 * 200
    np.testing.assert_array_equal(r["accel"], a[:r["n"]])


def test_timezone_and_api(tmp_path):
    t, a = synth(500)
    p = tmp_path / "tz.cwa"
    _write(p, t, a)
    utc = read_all(p)
    r = read_all(p, timezone="+01:00")
    assert r["reader"].info.timezone_offset_s == 3600
    np.testing.assert_array_equal(r["time"], utc["time"] - 3600 * 10**9)
    assert read_all(p, timezone=-1800)["time"][0] == utc["time"][0] + 1800 * 10**9
    with pytest.raises(ValueError):
        CwaReader(p, timezone="Mars/Olympus")
    src = open_recording(p)
    assert isinstance(src, Source) and isinstance(src, CwaReader)
    info = read_header(p)
    assert info.device_type == "AX3" and info.header["data_format"] == "0x30"
    with CwaReader(p, decode=False) as nd:
        blocks = list(nd)
    assert blocks[0].accel.shape == (blocks[0].n, 0)
    np.testing.assert_array_equal(np.concatenate([b.time_ns for b in blocks]), utc["time"])


def test_block_invariants(tmp_path):
    p = tmp_path / "an.cwa"
    _file_with_anomalies(p)
    r = read_all(p, batch_sectors=5)
    pos = 0
    for b in r["blocks"]:
        assert b.first_sample == pos
        pos += b.n
        assert b.unit_start[0] == 0 and (np.diff(b.unit_start) > 0).all()
        assert b.m == b.unit_index.shape[0] == b.temperature_c.shape[0]
        assert (np.diff(b.time_ns) > 0).all()
    # a block never mixes segments
    segs = [b.segment for b in r["blocks"]]
    assert segs == sorted(segs)


def test_format_change_count_legacy_overflow(tmp_path):
    from stillpoint.drivers.cwa import patch_sector
    t, a = synth(120 * 12)
    p = tmp_path / "f.cwa"
    _write(p, t, a, events=0)
    patch_sector(p, 3, events=0x10)  # device reports a FIFO overflow
    patch_sector(p, 5, sample_count=500)  # above the 120 capacity: clamped
    patch_sector(p, 7, tag=0x4255)  # legacy "UB" sector
    for i in range(9, 12):
        patch_sector(p, i, rate_code=0x0A)  # +-16 g from here on (same rate)
    r = read_all(p)
    assert qc_reasons(r["reader"]) == [(3, "device_overflow"), (5, "bad_count"), (7, "legacy_sector"),
                                       (8, "sequence_gap"), (9, "format_change")]
    assert r["n"] == 11 * 120 and r["reader"].qc.segments == 3
    np.testing.assert_array_equal(r["accel"], np.delete(a, np.s_[840:960], axis=0))
    assert r["events"][3] == 0x10


def test_segment_without_timestamps_is_dropped_and_logged(tmp_path):
    from stillpoint.drivers.cwa import patch_sector
    t, a = synth(120 * 6)
    t2, a2 = synth(120 * 4, start_ns=int(t[-1]) + 60 * 10**9, seed=2)
    p = tmp_path / "u.cwa"
    with CwaWriter(p) as w:
        w.write(t, a)
        w.restart()
        w.write(t2, a2)
    for i in range(6, 10):
        patch_sector(p, i, timestamp=0)
    r = read_all(p)
    reasons = qc_reasons(r["reader"])
    assert reasons.count((6, "bad_timestamp")) == 1 and (6, "restart") in reasons
    untimed = [e for e in r["reader"].qc.events if e.reason == "untimed"]
    assert len(untimed) == 1 and untimed[0].samples == 480
    assert r["n"] == 720 and r["reader"].qc.valid == 6 and r["reader"].qc.skipped == 4
    np.testing.assert_array_equal(r["accel"], a)


def test_writer_to_gzip_fileobj(tmp_path):
    t, a = synth(1000)
    gz = tmp_path / "w.cwa.gz"
    with gzip.open(gz, "wb") as f:
        with CwaWriter(f) as w:
            w.write(t[:400], a[:400])
            w.write(t[400:], a[400:])
        assert not f.closed  # a caller's file object is flushed, not closed
    r = read_all(gz)
    np.testing.assert_array_equal(r["accel"], a)


def test_writer_rejects_bad_arguments(tmp_path):
    with pytest.raises(ValueError, match="rate"):
        CwaWriter(tmp_path / "x.cwa", rate_hz=99.0)
    with pytest.raises(ValueError, match="AX6"):
        CwaWriter(tmp_path / "x.cwa", gyro_range_dps=250)
    w = CwaWriter(tmp_path / "x.cwa")
    t, a = synth(300)
    with pytest.raises(ValueError, match="shape"):
        w.write(t, a[:10])
    w.write(t, a)
    with pytest.raises(ValueError, match="increase"):
        w.write(t, a)  # times went backwards
    w.close()


try:
    from hypothesis import HealthCheck, example, given, settings
    from hypothesis import strategies as st
except ImportError:  # pragma: no cover
    given = None


if given is not None:
    @settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
    @given(ops=st.lists(st.tuples(st.sampled_from(["checksum", "timestamp", "dup", "drop", "ts0", "session"]),
                                  st.integers(0, 29)), max_size=6),
           batch=st.integers(1, 40), seed=st.integers(0, 1000))
    @example(ops=[("checksum", 1), ("ts0", 0)], batch=1, seed=0)  # QC order once depended on it
    def test_property_batch_invariance(tmp_path, ops, batch, seed):
        """Any mix of damaged sectors: results do not depend on batch_sectors, nothing is imputed."""
        from stillpoint.drivers.cwa import corrupt_sector, patch_sector
        p = tmp_path / f"p{seed}_{batch}.cwa"
        t, a = synth(120 * 30 + 50, seed=seed, drift=0.98 + (seed % 40) / 1000)
        _write(p, t, a)
        for op, i in ops:
            if i >= (p.stat().st_size - 1024) // 512:
                continue  # an earlier "drop" removed this sector: nothing to damage
            if op in ("checksum", "timestamp"):
                corrupt_sector(p, i, op)
            elif op == "ts0":
                patch_sector(p, i, timestamp=0)
            elif op == "session":
                patch_sector(p, i, session_id=99)
            else:
                raw = bytearray(p.read_bytes())
                s = slice(1024 + 512 * i, 1024 + 512 * (i + 1))
                chunk = bytes(raw[s])
                if op == "dup":
                    raw[s.stop:s.stop] = chunk
                else:
                    del raw[s]
                p.write_bytes(bytes(raw))
        try:
            ref = read_all(p, batch_sectors=4096)
        except Exception as e:  # every sector damaged: must be the typed error
            from stillpoint.engine.core.errors import CorruptRecordingError
            assert isinstance(e, CorruptRecordingError)
            return
        got = read_all(p, batch_sectors=batch)
        np.testing.assert_array_equal(got["time"], ref["time"])
        np.testing.assert_array_equal(got["accel"], ref["accel"])
        assert qc_reasons(got["reader"]) == qc_reasons(ref["reader"])
        # every returned sample is a written sample (nothing zero-filled or invented)
        rows = {tuple(x) for x in a.tolist()}
        assert all(tuple(x) in rows for x in ref["accel"][::37].tolist())
        assert (np.diff(ref["time"])[np.diff(ref["segment"]) == 0] > 0).all()


def test_blocks_are_bounded_by_the_batch(tmp_path):
    """Memory proxy (CI-sized): no Block holds more than about one batch of sectors, however long
    the file, and every sector is yielded once (the benchmark measures RSS on a 7/14-day file)."""
    t, a = synth(120 * 300)
    p = tmp_path / "long.cwa"
    _write(p, t, a)
    r = read_all(p, batch_sectors=16)
    assert max(b.n for b in r["blocks"]) <= (16 + 2) * 120
    assert len(r["blocks"]) >= 300 // 16
    np.testing.assert_array_equal(r["unit_index"], np.arange(300))
