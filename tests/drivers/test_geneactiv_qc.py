"""GENEActiv reader on damaged and unusual files: every problem is a typed error naming the file,
or a QC event at the right page with everything readable still returned."""

from __future__ import annotations

import os

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from stillpoint.engine.core.errors import (CorruptRecordingError, RecordingError, StillpointError,
                                       TruncatedRecordingError, UnsupportedFormatError)
from stillpoint.drivers.geneactiv import GeneactivReader, GeneactivWriter, read_header
from stillpoint.engine.core.blocks import Block

T0 = 1_600_000_000_000_000_000


def write(path, pages=6, rate=50.0, eol="\r\n", tz="+01:00"):
    n = pages * 300
    rng = np.random.default_rng(1)
    t = T0 + np.round(np.arange(n) * 1e9 / rate).astype(np.int64)
    a = rng.integers(-2048, 2048, (n, 3))
    w = GeneactivWriter(path, rate_hz=rate, line_ending=eol, timezone=tz)
    w.write(t, a, temperature_c=np.repeat(20 + np.arange(pages) / 10, 300))
    w.close()
    return t, a


def pages_of(data: bytes):
    """Byte offsets of every 'Recorded Data' line."""
    out, i = [], 0
    while True:
        i = data.find(b"Recorded Data", i)
        if i < 0:
            return out
        out.append(i)
        i += 1


def read(path, **kw):
    r = GeneactivReader(path, **kw)
    blocks = list(r)
    return r, blocks, (Block.concat(blocks) if blocks else None)


def events(r):
    return [(e.index, e.reason) for e in r.qc.events]


def test_desync_resynchronises_on_next_marker(tmp_path):
    p = tmp_path / "r.bin"
    t, a = write(p)
    data = p.read_bytes()
    pos = pages_of(data)
    data = data[:pos[3]] + b"garbage line\r\nmore: junk\r\n" + data[pos[3]:]
    p.write_bytes(data)
    r, blocks, b = read(p)
    assert events(r) == [(3, "desync")]
    assert "2 line(s)" in r.qc.events[0].detail
    assert b.n == 1800
    np.testing.assert_array_equal(b.accel, a)
    assert r.qc.segments == 2 and [bl.segment for bl in blocks] == [0, 1]


def test_page_with_broken_marker_is_skipped(tmp_path):
    p = tmp_path / "r.bin"
    t, a = write(p)
    data = p.read_bytes()
    pos = pages_of(data)
    data = data[:pos[2]] + b"Recorded Dat4" + data[pos[2] + 13:]
    p.write_bytes(data)
    r, blocks, b = read(p)
    assert events(r) == [(2, "desync"), (5, "page_count_mismatch")]
    assert b.n == 1500  # pages 0, 1, 3, 4, 5
    np.testing.assert_array_equal(b.accel, np.concatenate([a[:600], a[900:]]))
    # page positions: the lost page is not counted as a page (its marker is gone)
    assert r.qc.total == 5 and r.info.header["number_of_pages"] == 6


def test_bad_hex_page_is_skipped_and_logged(tmp_path):
    p = tmp_path / "r.bin"
    t, a = write(p)
    data = bytearray(p.read_bytes())
    pos = pages_of(bytes(data))
    hexstart = data.find(b"Frequency:50.0", pos[1]) + len(b"Frequency:50.0\r\n")
    data[hexstart + 100] = ord("G")
    p.write_bytes(bytes(data))
    r, blocks, b = read(p)
    assert events(r) == [(1, "bad_hex")]
    assert r.qc.events[0].samples == 300
    assert (r.qc.total, r.qc.valid, r.qc.skipped, r.qc.segments) == (6, 5, 1, 2)
    np.testing.assert_array_equal(b.accel, np.concatenate([a[:300], a[600:]]))
    # the page before the skipped one keeps the nominal step (6 s at 50 Hz), never zero-filled
    assert np.all(np.diff(blocks[0].time_ns) == 20_000_000)


def test_bad_page_time_is_skipped(tmp_path):
    p = tmp_path / "r.bin"
    write(p)
    data = p.read_bytes()
    pos = pages_of(data)
    i = data.find(b"Page Time:", pos[4]) + len(b"Page Time:")
    data = data[:i] + b"2020-13-45 99:00:00:000" + data[i + 23:]
    p.write_bytes(data)
    r, _, b = read(p)
    assert events(r) == [(4, "bad_page_time")]
    assert "2020-13-45" in r.qc.events[0].detail
    assert b.n == 1500


def test_sequence_gap_starts_a_segment(tmp_path):
    p = tmp_path / "r.bin"
    write(p)
    data = p.read_bytes()
    data = data.replace(b"Sequence Number:3\r\n", b"Sequence Number:7\r\n")
    data = data.replace(b"Sequence Number:4\r\n", b"Sequence Number:8\r\n")
    data = data.replace(b"Sequence Number:5\r\n", b"Sequence Number:9\r\n")
    p.write_bytes(data)
    r, blocks, b = read(p)
    assert events(r) == [(3, "sequence_gap")]
    assert "2 -> 7" in r.qc.events[0].detail
    assert b.n == 1800 and r.qc.segments == 2
    assert blocks[1].unit_sequence.tolist() == [7, 8, 9]


def test_time_jump_starts_a_segment_but_drift_is_interpolated(tmp_path):
    p = tmp_path / "r.bin"
    write(p)
    data = p.read_bytes()
    # page 3 one hour later: a jump; page 5 +3 ms: clock drift within tolerance, interpolated
    for k, extra_ms in ((3, 0), (4, 0), (5, 3)):
        pos = pages_of(data)
        i = data.find(b"Page Time:", pos[k]) + len(b"Page Time:")
        old = data[i:i + 23].decode()
        hh = int(old[11:13]) + 1
        ms = int(old[20:23]) + extra_ms
        data = data[:i] + f"{old[:11]}{hh:02d}{old[13:20]}{ms:03d}".encode() + data[i + 23:]
    p.write_bytes(data)
    r, blocks, b = read(p)
    assert events(r) == [(3, "time_jump")]
    assert r.qc.segments == 2
    st = b.time_ns[b.unit_start]
    assert st[3] - st[2] == 3600 * 10**9 + 6 * 10**9
    assert st[5] - st[4] == 6 * 10**9 + 3_000_000


@pytest.mark.parametrize("cut", [1, 11, 12, 13, 1799, 3599, 3600, 3601, 3650])
def test_truncation_anywhere_in_the_last_page(tmp_path, cut):
    p = tmp_path / "r.bin"
    t, a = write(p, pages=3)
    data = p.read_bytes()
    hexstart = data.find(b"Frequency:50.0", pages_of(data)[2]) + len(b"Frequency:50.0\r\n")
    p.write_bytes(data[:hexstart + cut])
    r, _, b = read(p)
    whole = min(cut, 3600) // 12
    assert b.n == 600 + whole
    np.testing.assert_array_equal(b.accel, a[:600 + whole])
    if cut >= 3600:
        assert events(r) == []
    elif cut < 12:
        assert events(r) == [(2, "bad_page_length")]
    else:
        assert events(r) == [(2, "truncated_page")]
        assert f"{whole} of 300" in r.qc.events[0].detail


def test_truncated_inside_page_text(tmp_path):
    p = tmp_path / "r.bin"
    t, a = write(p, pages=3)
    data = p.read_bytes()
    cut = data.find(b"Temperature:", pages_of(data)[2])
    p.write_bytes(data[:cut])
    r, _, b = read(p)
    assert b.n == 600
    assert events(r)[0] == (2, "truncated_page")
    assert r.qc.skipped == 1


def test_header_ends_early(tmp_path):
    p = tmp_path / "r.bin"
    write(p)
    data = p.read_bytes()
    p.write_bytes(data[:data.find(b"y gain")])
    with pytest.raises(TruncatedRecordingError, match="header ends early") as e:
        GeneactivReader(p)
    assert str(p) in str(e.value) and "y gain" in str(e.value)
    with pytest.raises(TruncatedRecordingError):
        read_header(p)


def test_header_only_file_has_no_samples(tmp_path):
    p = tmp_path / "r.bin"
    write(p)
    data = p.read_bytes()
    p.write_bytes(data[:pages_of(data)[0]])
    r, blocks, _ = read(p)
    assert blocks == [] and r.qc.total == 0
    assert events(r) == [(0, "page_count_mismatch")]


@pytest.mark.parametrize("content,err,msg", [
    (b"", TruncatedRecordingError, "empty"),
    (bytes(range(256)) * 8, UnsupportedFormatError, "not a GENEActiv"),
    (b"GENEA/1.00\r\nSerial:01275\r\n", UnsupportedFormatError, "original GENEA"),
    (b"Device Identity\r\n" + b"x" * (1 << 21), CorruptRecordingError, "never ends"),
])
def test_bad_files_raise_typed_errors(tmp_path, content, err, msg):
    p = tmp_path / "bad.bin"
    p.write_bytes(content)
    with pytest.raises(err, match=msg) as e:
        GeneactivReader(p)
    assert str(p) in str(e.value)


def test_missing_file_and_directory(tmp_path):
    with pytest.raises(RecordingError, match="no such file"):
        GeneactivReader(tmp_path / "nope.bin")
    with pytest.raises(RecordingError, match="directory"):
        GeneactivReader(tmp_path)


def test_unreadable_time_zone_needs_override(tmp_path):
    p = tmp_path / "r.bin"
    write(p)
    p.write_bytes(p.read_bytes().replace(b"Time Zone:GMT +01:00", b"Time Zone:somewhere"))
    with pytest.raises(CorruptRecordingError, match="time zone"):
        GeneactivReader(p)
    r, _, b = read(p, timezone="+01:00")
    assert b.n == 1800


def test_comma_decimals(tmp_path):
    p = tmp_path / "r.bin"
    write(p, rate=600 / 7)
    data = p.read_bytes()
    data = data.replace(b"Frequency:85.7", b"Frequency:85,7")
    data = data.replace(b"Temperature:20.3", b"Temperature:20,3")
    data = data.replace(b"Battery voltage:4.0000", b"Battery voltage:4,0000")
    p.write_bytes(data)
    r, _, b = read(p)
    assert r.info.sample_rate_nominal == 600 / 7
    assert b.temperature_c[3] == 20.3 and np.all(b.battery_v == 4.0)
    assert events(r) == []


def test_header_parsed_by_section_not_line_number(tmp_path):
    p = tmp_path / "r.bin"
    write(p)
    data = p.read_bytes()
    data = data.replace(b"Config Notes:\r\n", b"Config Notes:first line\r\nsecond line of notes\r\n"
                                                b"third line\r\n")
    data = data.replace(b"Device Capabilities\r\n", b"Device Capabilities\r\nNew Capability:42\r\n")
    p.write_bytes(data)
    info = read_header(p)
    assert info.header["gains"] == (25600, 25600, 25600)
    assert info.metadata["Config Notes"] == "first line\nsecond line of notes\nthird line"
    assert info.header["New Capability"] == "42"
    assert info.timezone_offset_s == 3600


def test_page_frequency_mismatch_logged_once(tmp_path):
    p = tmp_path / "r.bin"
    write(p)
    p.write_bytes(p.read_bytes().replace(b"Measurement Frequency:50 Hz", b"Measurement Frequency:100 Hz"))
    r, _, b = read(p)
    assert events(r) == [(0, "frequency_mismatch")]
    assert b.n == 1800 and r.qc.segments == 1  # pages are timed with their own 50 Hz


def test_reader_is_single_pass_and_closes(tmp_path):
    p = tmp_path / "r.bin"
    write(p)
    r = GeneactivReader(p)
    list(r)
    with pytest.raises(RuntimeError, match="single-pass"):
        list(r)
    with GeneactivReader(p) as r2:
        next(iter(r2))
    assert r2._f.closed


def test_random_garbage_inside_data_keeps_earlier_pages(tmp_path):
    p = tmp_path / "r.bin"
    t, a = write(p, pages=4)
    data = p.read_bytes()
    pos = pages_of(data)
    p.write_bytes(data[:pos[2]] + os.urandom(5000).replace(b"\n", b"x"))
    r, _, b = read(p)
    assert b.n == 600
    np.testing.assert_array_equal(b.accel, a[:600])
    assert events(r)[0][1] == "desync"


def test_long_garbage_without_line_breaks_is_bounded_and_skipped(tmp_path):
    p = tmp_path / "r.bin"
    t, a = write(p, pages=4)
    data = p.read_bytes()
    pos = pages_of(data)
    junk = b"Z" * (6 << 20)  # 6 MB without a newline, then the rest of the file
    p.write_bytes(data[:pos[2]] + junk + b"\r\n" + data[pos[2]:])
    r, blocks, b = read(p, batch_pages=4)
    assert b.n == 1200
    np.testing.assert_array_equal(b.accel, a)
    assert [e.reason for e in r.qc.events] == ["desync"] and r.qc.segments == 2


def test_follow_refuses_gzip(tmp_path):
    p = tmp_path / "r.bin.gz"
    write(p)
    with pytest.raises(ValueError, match="follow"):
        GeneactivReader(p, follow=True)


def _blocks_and_qc(path, slow: bool, **kw):
    r = GeneactivReader(path, **kw)
    if slow:
        r._fast_pages = lambda *a: 0  # force the general per-page parser
    blocks = list(r)
    return blocks, r.qc.as_dict()


@pytest.mark.parametrize("damage", ["none", "bad_hex", "bad_time", "comma", "desync", "lf", "data_eol",
                                    "data_eol_tab", "time_ms_space",
                                    "long_key_line"])
def test_fast_path_equals_general_parser(tmp_path, damage):
    p = tmp_path / "r.bin"
    write(p, pages=9, eol="\n" if damage == "lf" else "\r\n")
    data = p.read_bytes()
    pos = pages_of(data)
    if damage == "bad_hex":
        i = data.find(b"Frequency:50.0", pos[4]) + 20
        data = data[:i] + b"x" + data[i + 1:]
    elif damage == "bad_time":
        i = data.find(b"Page Time:", pos[6]) + 10
        data = data[:i] + b"2021-02-30" + data[i + 10:]
    elif damage == "comma":
        data = data.replace(b"Temperature:20.5", b"Temperature:20,5")
    elif damage == "desync":
        data = data[:pos[5]] + b"noise\r\n" + data[pos[5]:]
    elif damage.startswith("data_eol"):  # the CR ending page 4's data line -> 0x0F or a tab (one
        i = pos[5] - 2                    # bit each): a 3601-character line, not padding
        assert data[i:i + 2] == b"\r\n"
        data = data[:i] + (b"\t" if damage == "data_eol_tab" else b"\x0f") + data[i + 1:]
    elif damage == "long_key_line":  # page 4's Device Status line padded to 513 bytes: not a key line
        i = data.find(b"Device Status:", pos[4]) + 14
        data = data[:i] + b"\x00" * 489 + data[i:]
    elif damage == "time_ms_space":  # page 6's last millisecond digit -> a space: ":000" -> ":00 "
        i = data.find(b"Page Time:", pos[6]) + 32
        assert data[i:i + 1] == b"0"
        data = data[:i] + b" " + data[i + 1:]
    p.write_bytes(data)
    for bp in (2, 3, 256):
        fast_blocks, fast_qc = _blocks_and_qc(p, False, batch_pages=bp)
        slow_blocks, slow_qc = _blocks_and_qc(p, True, batch_pages=bp)
        assert fast_qc == slow_qc
        assert len(fast_blocks) == len(slow_blocks)
        for a, b in zip(fast_blocks, slow_blocks):
            for f in ("time_ns", "accel", "unit_index", "unit_sequence", "unit_start", "temperature_c",
                      "battery_v", "light"):
                np.testing.assert_array_equal(getattr(a, f), getattr(b, f))
            assert a.segment == b.segment and a.first_sample == b.first_sample
            for k in a.per_sample:
                np.testing.assert_array_equal(a.per_sample[k], b.per_sample[k])
    if damage.startswith("data_eol"):
        assert [(e["index"], e["reason"]) for e in fast_qc["events"]] == [(4, "bad_page_length")]
    if damage == "time_ms_space":
        assert [(e["index"], e["reason"]) for e in fast_qc["events"]] == [(6, "bad_page_time")]
    if damage == "long_key_line":
        assert [(e["index"], e["reason"]) for e in fast_qc["events"]] == [(4, "bad_page_length"),
                                                                            (5, "desync")]
    if damage in ("bad_hex", "bad_time", "desync", "data_eol", "data_eol_tab", "time_ms_space",
                  "long_key_line"):
        assert fast_qc["events"]
    else:
        assert fast_qc["events"] == [] and 20.5 in np.concatenate([b.temperature_c for b in fast_blocks])


def test_qc_log_is_capped(tmp_path, monkeypatch):
    import stillpoint.drivers.geneactiv as g
    monkeypatch.setattr(g, "MAX_QC_EVENTS", 3)
    p = tmp_path / "r.bin"
    write(p, pages=12)
    data = p.read_bytes()
    for k in range(1, 12, 2):  # every other page has a bad character: 6 bad_hex events
        pos = pages_of(data)
        i = data.find(b"Frequency:50.0", pos[k]) + 20
        data = data[:i] + b"x" + data[i + 1:]
    p.write_bytes(data[:pages_of(data)[11]])  # and 11 pages where the header says 12
    r, _, b = read(p)
    reasons = [e.reason for e in r.qc.events]
    assert reasons == ["bad_hex"] * 3 + ["qc_log_truncated", "page_count_mismatch"]
    assert (r.qc.total, r.qc.valid, r.qc.skipped) == (11, 6, 5) and b.n == 1800


def test_capped_qc_log_is_the_same_at_every_batch_size(tmp_path, monkeypatch):
    """Pages are parsed a batch at a time before their segment checks run, so events are not
    logged in file order; the capped list must still be the first events in file order."""
    import stillpoint.drivers.geneactiv as g
    monkeypatch.setattr(g, "MAX_QC_EVENTS", 3)
    p = tmp_path / "r.bin"
    write(p, pages=12)
    data = p.read_bytes()
    for k in (2, 5, 8):  # sequence gaps (segment checks) at pages 2, 5, 8 ...
        data = data.replace(b"Sequence Number:%d\r" % k, b"Sequence Number:%d\r" % (k + 100))
    for k in (3, 6, 9):  # ... and bad hex (found while parsing) at pages 3, 6, 9
        i = data.find(b"Frequency:50.0", pages_of(data)[k]) + 20
        data = data[:i] + b"x" + data[i + 1:]
    p.write_bytes(data)
    want = [(2, "sequence_gap"), (3, "bad_hex"), (4, "sequence_gap"), (5, "qc_log_truncated")]
    for bp in (1, 2, 3, 5, 256):
        r, _, b = read(p, batch_pages=bp)
        assert events(r) == want, bp
        assert (r.qc.total, r.qc.valid, r.qc.skipped) == (12, 9, 3) and b.n == 2700


def test_long_desync_after_a_segment_check_is_one_event(tmp_path):
    """Text that is not a page, longer than a read, after a page with a sequence gap: one desync
    event however many reads it takes."""
    p = tmp_path / "r.bin"
    write(p, pages=6)
    data = p.read_bytes().replace(b"Sequence Number:1\r", b"Sequence Number:7\r")
    pos = pages_of(data)
    junk = b"".join(b"junk line %d\r\n" % k for k in range(3000))  # 46,890 bytes
    p.write_bytes(data[:pos[2]] + junk + data[pos[2]:])
    for bp in (1, 2, 3, 256):
        r, _, b = read(p, batch_pages=bp)
        assert events(r) == [(1, "sequence_gap"), (2, "desync")], bp
        assert "3000 line(s), 46890 bytes" in r.qc.events[1].detail and b.n == 1800


# ---------------------------------------------------------------------------- random damage


@pytest.fixture(scope="module")
def clean_file(tmp_path_factory):
    p = tmp_path_factory.mktemp("clean") / "r.bin"
    t, a = write(p, pages=6)
    return p.read_bytes(), t, a


def _read_or_error(path, **kw):
    try:
        r = GeneactivReader(path, **kw)
        blocks = list(r)
    except StillpointError:
        return None
    return r, blocks


@settings(max_examples=int(os.environ.get("STILLPOINT_FUZZ_EXAMPLES", "60")), deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(pos=st.integers(0, 23_000), kind=st.sampled_from(["flip", "delete", "insert", "cut"]),
       length=st.integers(1, 5000), byte=st.integers(0, 255))
@example(pos=1297, kind="insert", length=489, byte=0)  # page 0's Device Status line -> 513 bytes
def test_random_damage_never_crashes_and_keeps_what_precedes_it(tmp_path, clean_file, pos, kind, length,
                                                                 byte):
    data, t, a = clean_file
    pos = min(pos, len(data) - 1)
    if kind == "flip":
        bad = data[:pos] + bytes([byte]) + data[pos + 1:]
    elif kind == "delete":
        bad = data[:pos] + data[pos + length:]
    elif kind == "insert":
        bad = data[:pos] + bytes([byte]) * length + data[pos:]
    else:
        bad = data[:pos]
    p = tmp_path / "bad.bin"
    p.write_bytes(bad)
    got = _read_or_error(p)
    other = _read_or_error(p, batch_pages=1)
    assert (got is None) == (other is None)  # the same verdict whatever the batch size
    starts = pages_of(data)
    if got is None:
        assert pos < starts[1] + 10 or kind == "cut"  # only damage reaching early bytes may fail
        return
    r, blocks = got
    for b in blocks:
        assert np.all(np.diff(b.time_ns) > 0)
        assert b.accel.min() >= -2048 and b.accel.max() <= 2047
    # every page that ends before the damage comes back exactly as written
    intact = sum(1 for k in range(6) if (starts[k + 1] if k + 1 < 6 else len(data)) <= pos)
    if pos > starts[0] and intact:
        b = Block.concat(blocks)
        n = 300 * intact
        np.testing.assert_array_equal(b.accel[:n], a[:n])
        assert np.abs(b.time_ns[:n] - t[:n]).max() <= 1_000_000
    # batch size never changes the samples
    r2, blocks2 = other
    n1, n2 = sum(b.n for b in blocks), sum(b.n for b in blocks2)
    assert n1 == n2 and r.qc.as_dict() == r2.qc.as_dict()


def test_page_from_another_device_is_logged_once(tmp_path):
    p = tmp_path / "r.bin"
    t, a = write(p, pages=6)
    data = p.read_bytes()
    head = pages_of(data)[0]
    body = data[head:].replace(b"Serial Code:012345\r\nSequence Number:3\r\n",
                               b"Serial Code:099999\r\nSequence Number:3\r\n")
    body = body.replace(b"Serial Code:012345\r\nSequence Number:4\r\n",
                        b"Serial Code:099999\r\nSequence Number:4\r\n")
    p.write_bytes(data[:head] + body)
    for bp in (1, 256):
        r, _, b = read(p, batch_pages=bp)
        assert [(e.index, e.reason) for e in r.qc.events] == [(3, "serial_mismatch")]
        assert b.n == 1800 and "099999" in r.qc.events[0].detail
