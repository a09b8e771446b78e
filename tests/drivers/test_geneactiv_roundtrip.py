"""GENEActiv writer -> reader: exact counts, light, button, per-page values, times within 1 ms,
for CR LF and LF files, gzip, fractional rates, time zones and any batch size; follow mode."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stillpoint.drivers import open_recording, sniff_format
from stillpoint.drivers.geneactiv import GeneactivReader, GeneactivWriter, decode_hex_samples, read_header
from stillpoint.drivers.geneactiv_writer import encode_hex_samples
from stillpoint.engine.core.blocks import PER_SAMPLE_BUTTON, PER_SAMPLE_LIGHT_RAW, Block
from stillpoint.engine.core.source import Source

T0 = 1_700_000_000_123_456_789


def make_signal(n, rate, seed=0, t0=T0):
    rng = np.random.default_rng(seed)
    t = t0 + np.round(np.arange(n) * 1e9 / rate).astype(np.int64)
    a = rng.integers(-2048, 2048, (n, 3))
    a[:3] = [[-2048, 2047, 0], [2047, -2048, -1], [2048 - 4096, 1, -2047]]  # edges of 12 bits
    light = rng.integers(0, 1024, n)
    button = rng.integers(0, 2, n)
    temp = np.round(20 + 10 * rng.random(n), 1)
    batt = np.round(3.6 + 0.5 * rng.random(n), 4)
    return t, a, light, button, temp, batt


def write_file(path, n=1000, rate=100.0, tz="+00:00", eol="\r\n", seed=0, chunks=3, **kw):
    t, a, light, button, temp, batt = make_signal(n, rate, seed)
    w = GeneactivWriter(path, rate_hz=rate, timezone=tz, line_ending=eol,
                        gains=(25000, 25100, 25200), offsets=(100, -200, 300), **kw)
    edges = np.linspace(0, n, chunks + 1).astype(int)
    for s, e in zip(edges[:-1], edges[1:]):
        w.write(t[s:e], a[s:e], light_raw=light[s:e], button=button[s:e], temperature_c=temp[s:e],
                battery_v=batt[s:e])
    w.close()
    return t, a, light, button, temp, batt


def read_all(path, **kw):
    r = GeneactivReader(path, **kw)
    blocks = list(r)
    return r, blocks, Block.concat(blocks)


@pytest.mark.parametrize("rate", [100.0, 600 / 7, 50.0, 12.5])
@pytest.mark.parametrize("eol", ["\r\n", "\n"])
def test_roundtrip_exact(tmp_path, rate, eol):
    p = tmp_path / "rec.bin"
    n = 2000
    t, a, light, button, temp, batt = write_file(p, n=n, rate=rate, eol=eol)
    r, blocks, b = read_all(p)
    assert isinstance(r, Source)
    assert b.n == n
    np.testing.assert_array_equal(b.accel, a)
    assert b.accel.dtype == np.int16
    np.testing.assert_array_equal(b.per_sample[PER_SAMPLE_LIGHT_RAW], light)
    np.testing.assert_array_equal(b.per_sample[PER_SAMPLE_BUTTON], button)
    assert np.abs(b.time_ns - t).max() <= 1_000_000  # Page Time has ms resolution
    firsts = np.arange(0, n, 300)
    np.testing.assert_array_equal(b.unit_start, firsts)
    np.testing.assert_allclose(b.temperature_c, temp[firsts])
    np.testing.assert_allclose(b.battery_v, batt[firsts])
    np.testing.assert_array_equal(b.unit_sequence, np.arange(len(firsts)))
    # accel_g is the vendor formula (raw*100 - offset)/gain
    expect = (a * 100.0 - np.array([100, -200, 300])) / np.array([25000, 25100, 25200])
    np.testing.assert_allclose(b.accel_g(), expect, rtol=0, atol=1e-12)
    assert r.info.sample_rate_nominal == pytest.approx(rate)
    # one partial last page (2000 = 6*300 + 200), logged as such, nothing else
    assert [(e.index, e.reason) for e in r.qc.events] == [(6, "partial_page")]
    assert (r.qc.total, r.qc.valid, r.qc.skipped, r.qc.segments) == (7, 7, 0, 1)


def test_85p7_is_600_over_7(tmp_path):
    p = tmp_path / "r.bin"
    write_file(p, n=3000, rate=600 / 7)
    assert b"Measurement Frequency:85.7 Hz" in p.read_bytes()
    r, _, b = read_all(p)
    assert r.info.sample_rate_nominal == 600 / 7
    # sample spacing follows the 3.5 s page steps, not 1/85.7 s
    d = np.diff(b.time_ns)
    assert abs(d.mean() - 7e9 / 600) < 1000
    assert b.time_ns[-1] - b.time_ns[0] == pytest.approx(2999 * 7e9 / 600, abs=1e6)


def test_block_cuts_do_not_change_the_stream(tmp_path):
    p = tmp_path / "r.bin"
    write_file(p, n=4321, rate=100.0)
    ref = read_all(p, batch_pages=256)[2]
    for bp in (1, 2, 5):
        r, blocks, b = read_all(p, batch_pages=bp)
        assert all(bl.m <= bp for bl in blocks)
        np.testing.assert_array_equal(b.time_ns, ref.time_ns)
        np.testing.assert_array_equal(b.accel, ref.accel)
        assert [bl.first_sample for bl in blocks] == list(np.cumsum([0] + [bl.n for bl in blocks[:-1]]))


@pytest.mark.parametrize("tz,offset", [("+01:00", 3600), ("-04:00", -14400), ("+05:30", 19800),
                                       ("GMT -09:45", -35100)])
def test_timezone_hours_and_minutes(tmp_path, tz, offset):
    p = tmp_path / "r.bin"
    t, *_ = write_file(p, n=600, tz=tz)
    r, _, b = read_all(p)
    assert r.info.timezone_offset_s == offset
    assert abs(int(b.time_ns[0]) - int(t[0])) <= 1_000_000
    # an override shifts all times by the difference
    r2, _, b2 = read_all(p, timezone="+00:00")
    assert r2.info.timezone_offset_s == 0
    np.testing.assert_array_equal(b2.time_ns - b.time_ns, offset * 10**9)


def test_gzip_is_transparent(tmp_path):
    plain, gz = tmp_path / "r.bin", tmp_path / "r.bin.gz"
    write_file(plain, n=1500)
    write_file(gz, n=1500)
    assert gz.read_bytes()[:2] == b"\x1f\x8b"
    assert sniff_format(gz) == "geneactiv"
    a = read_all(plain)[2]
    src = open_recording(gz)
    assert isinstance(src, GeneactivReader)
    b = Block.concat(list(src))
    np.testing.assert_array_equal(a.time_ns, b.time_ns)
    np.testing.assert_array_equal(a.accel, b.accel)


def test_partial_page_drop_option(tmp_path):
    p = tmp_path / "r.bin"
    write_file(p, n=1000, partial_page="drop")
    r, _, b = read_all(p)
    assert b.n == 900 and r.qc.events == [] and r.info.header["number_of_pages"] == 3


def test_header_fields_and_metadata(tmp_path):
    p = tmp_path / "r.bin"
    write_file(p, n=300, header_fields={"Subject Code": "P01", "Device Location Code": "left wrist"},
               serial="000042")
    info = read_header(p)
    assert info.device_id == "000042"  # leading zeros kept
    assert info.metadata["Subject Code"] == "P01"
    assert info.metadata["Device Location Code"] == "left wrist"
    with pytest.raises(ValueError, match="unknown header field"):
        GeneactivWriter(tmp_path / "x.bin", header_fields={"Nope": 1})


def test_writer_rejects_out_of_range_counts(tmp_path):
    w = GeneactivWriter(tmp_path / "x.bin")
    with pytest.raises(ValueError, match="12-bit"):
        w.write(np.array([T0]), np.array([[2048, 0, 0]]))
    with pytest.raises(ValueError, match="light"):
        w.write(np.array([T0]), np.array([[0, 0, 0]]), light_raw=1024)


@settings(max_examples=50, deadline=None)
@given(st.lists(st.tuples(st.integers(-2048, 2047), st.integers(-2048, 2047), st.integers(-2048, 2047),
                          st.integers(0, 1023), st.integers(0, 1)), min_size=1, max_size=40))
def test_hex_codec_roundtrip(samples):
    arr = np.array(samples)
    hexm = encode_hex_samples(arr[:, :3], arr[:, 3], arr[:, 4])
    acc, light, button, bad = decode_hex_samples(hexm.tobytes(), len(arr))
    np.testing.assert_array_equal(acc, arr[:, :3])
    np.testing.assert_array_equal(light, arr[:, 3])
    np.testing.assert_array_equal(button, arr[:, 4])
    assert not bad.any()
    # lower-case hex decodes the same
    acc2 = decode_hex_samples(hexm.tobytes().lower(), len(arr))[0]
    np.testing.assert_array_equal(acc2, acc)


def test_sign_extension_at_2048():
    # 0x800 is -2048 (actipy reads +2048); 0x7FF is +2047; 0xFFF is -1
    acc = decode_hex_samples(b"8007FFFFF000", 1)[0]
    assert acc.tolist() == [[-2048, 2047, -1]]


def test_follow_mode_reads_a_file_being_written(tmp_path):
    p = tmp_path / "live.bin"
    t, a, light, button, temp, batt = make_signal(3000, 100.0)
    w = GeneactivWriter(p, rate_hz=100.0)
    w.write(t[:600], a[:600])
    w._f.flush()
    done = threading.Event()

    def writer():
        for s in range(600, 3000, 600):
            time.sleep(0.15)
            w.write(t[s:s + 600], a[s:s + 600])
            w._f.flush()
        w.close()
        done.set()

    th = threading.Thread(target=writer)
    th.start()
    r = GeneactivReader(p, follow=True, follow_done=done.is_set, follow_idle_s=5.0, batch_pages=2)
    b = Block.concat(list(r))
    th.join()
    assert b.n == 3000
    np.testing.assert_array_equal(b.accel, a)
    assert r.qc.skipped == 0 and r.qc.segments == 1


def test_writer_header_start_time_and_page_count(tmp_path):
    p = tmp_path / "r.bin"
    start = T0 - 5 * 10**9
    w = GeneactivWriter(p, rate_hz=50.0, timezone="-04:00", start_time=start)
    w.write(T0 + np.arange(1500) * 20_000_000, np.zeros((1500, 3), int))
    w.close()
    info = read_header(p)
    assert info.header["start_time_ns"] == (start + 500_000) // 1_000_000 * 1_000_000
    assert info.header["number_of_pages"] == 5
    assert info.header["Time Zone"] == "GMT -04:00"
    text = p.read_bytes().decode()
    assert text.count("Recorded Data") == 5 and text.count("\r\n") == text.count("\n")
