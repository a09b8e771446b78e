"""Bad input gives one clear typed error naming the file; follow mode reads a growing file."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from stillpoint.drivers import open_recording
from stillpoint.drivers.cwa import CwaReader, CwaWriter
from stillpoint.engine.core.errors import (CorruptRecordingError, RecordingError, StillpointError,
                                       TruncatedRecordingError, UnsupportedFormatError)

from cwa_helpers import read_all, synth


def _header(tmp_path):
    p = tmp_path / "h.cwa"
    CwaWriter(p).close()
    return p.read_bytes()


@pytest.mark.parametrize("content,error,message", [
    (b"", TruncatedRecordingError, "empty"),
    (b"MD\xfc\x03" + b"\x00" * 96, TruncatedRecordingError, "ends after 100 bytes, inside the 1024-byte header"),
    (bytes(np.random.default_rng(1).integers(0, 256, 5000, dtype=np.uint8)), UnsupportedFormatError,
     "not an AX3/AX6 .cwa recording"),
    (b"time,x,y,z\n0,1,2,3\n" * 100, UnsupportedFormatError, "text file"),
    (b"MD\x10\x00" + b"\x00" * 2000, CorruptRecordingError, "header length field is 16"),
])
def test_bad_input_errors(tmp_path, content, error, message):
    p = tmp_path / "bad.cwa"
    p.write_bytes(content)
    with pytest.raises(error, match=message) as ei:
        CwaReader(p)
    assert str(p) in str(ei.value) and "\n" not in str(ei.value)
    assert isinstance(ei.value, StillpointError)


def test_missing_file(tmp_path):
    with pytest.raises(RecordingError, match="no such file"):
        CwaReader(tmp_path / "nope.cwa")


def test_open_recording_rejects_text(tmp_path):
    p = tmp_path / "notes.cwa"
    p.write_text("hello, this is not a recording\n" * 20)
    with pytest.raises(UnsupportedFormatError, match="notes.cwa"):
        open_recording(p)


def test_header_then_garbage_keeps_nothing_but_reports(tmp_path):
    p = tmp_path / "g.cwa"
    p.write_bytes(_header(tmp_path) + bytes(np.random.default_rng(2).integers(0, 256, 512 * 6, dtype=np.uint8)))
    r = CwaReader(p)
    with pytest.raises(CorruptRecordingError, match="none of the 6 data sectors"):
        list(r)
    assert r.qc.skipped == 6 and len(r.qc.events) >= 1


def test_good_sectors_before_garbage_are_returned(tmp_path):
    t, a = synth(120 * 10)
    p = tmp_path / "ok.cwa"
    with CwaWriter(p) as w:
        w.write(t, a)
    with open(p, "ab") as f:
        f.write(bytes(np.random.default_rng(3).integers(0, 256, 512 * 3, dtype=np.uint8)))
    r = read_all(p)
    assert r["n"] == 1200 and r["reader"].qc.skipped == 3
    np.testing.assert_array_equal(r["accel"], a)


def test_follow_reads_a_growing_file(tmp_path):
    p = tmp_path / "live.cwa"
    t, a = synth(120 * 60)
    got_first = threading.Event()
    w = CwaWriter(p)
    w.write(t[:120 * 20], a[:120 * 20])
    reader = CwaReader(p, follow=True, follow_idle_s=1.0, batch_sectors=64)

    def writer():
        # the rest is written only once the reader has yielded data from the first part
        ok = got_first.wait(10)
        for i in range(20, 60, 10):
            w.write(t[120 * i:120 * (i + 10)], a[120 * i:120 * (i + 10)])
        w.close()
        writer.ok = ok

    th = threading.Thread(target=writer)
    th.start()
    blocks = []
    for b in reader:
        blocks.append(b)
        got_first.set()
    th.join()
    assert writer.ok, "the follower yielded nothing before the writer finished"
    time_ns = np.concatenate([b.time_ns for b in blocks])
    np.testing.assert_array_equal(np.concatenate([b.accel for b in blocks]), a)
    assert np.abs(time_ns - t).max() <= 1e9 / 32768
    assert reader.qc.valid == 60
    # the idle stop (at a sector boundary) is logged, never silent
    assert [(e.index, e.reason) for e in reader.qc.events] == [(60, "follow_idle_stop")]


def test_qc_log_is_capped_but_counts_stay_exact(tmp_path, monkeypatch):
    import stillpoint.drivers.cwa_reader as cr
    from stillpoint.drivers.cwa import corrupt_sector
    monkeypatch.setattr(cr, "MAX_QC_EVENTS", 3)
    t, a = synth(120 * 20)
    p = tmp_path / "many.cwa"
    with CwaWriter(p) as w:
        w.write(t, a)
    for i in range(0, 20, 2):
        corrupt_sector(p, i)
    r = read_all(p)
    rd = r["reader"]
    assert rd.qc.skipped == 10 and rd.qc.valid == 10 and r["n"] == 1200
    assert len(rd.qc.events) == 4 and rd.qc.events[-1].reason == "qc_log_truncated"


def test_legacy_byte_sum_checksum_is_accepted(tmp_path):
    """cwa-format.md §5.5: a stored checksum equal to the byte sum of the first 510 bytes is valid."""
    from stillpoint.drivers.cwa import read_sector
    t, a = synth(120 * 3)
    p = tmp_path / "legacy.cwa"
    with CwaWriter(p) as w:
        w.write(t, a)
    sec = read_sector(p, 1)
    raw = sec.view(np.uint8)
    sec["checksum"] = int(raw[:510].sum()) & 0xFFFF
    assert sec.view("<u2").sum(dtype=np.uint16) != 0  # not a valid word-sum checksum any more
    with open(p, "r+b") as f:
        f.seek(1024 + 512)
        f.write(sec.tobytes())
    r = read_all(p)
    assert r["reader"].qc.events == [] and r["n"] == 360


def test_follow_refuses_gzip(tmp_path):
    import gzip
    p = tmp_path / "x.cwa.gz"
    p.write_bytes(gzip.compress(b"MD" + b"\x00" * 2000))
    with pytest.raises(UnsupportedFormatError, match="gzip file cannot be followed"):
        CwaReader(p, follow=True)
