"""Every damaged input in tests/data/fuzz/ (README there: what each is and what stillpoint used to
do) as a regression test: what is readable is read, the defect is logged as QC, or the file is
refused with one clear line (exit 2) - never a traceback, never silent wrong values."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from stillpoint.drivers import open_recording
from stillpoint.drivers.errors import CorruptRecordingError, StillpointError

FUZZ = Path(__file__).parent / "data" / "fuzz"


def cli(*args, cwd=None):
    r = subprocess.run([sys.executable, "-m", "tools", *map(str, args)], capture_output=True,
                       text=True, cwd=cwd, timeout=300)
    return r.returncode, r.stdout, r.stderr


def read(name, **kw):
    with open_recording(FUZZ / name, **kw) as src:
        blocks = list(src)
    return src, blocks


def reasons(src):
    return [e.reason for e in src.qc.events]


def assert_one_line_error(rc, err, name):
    assert rc == 2, err
    assert "Traceback" not in err
    lines = [ln for ln in err.strip().splitlines() if ln]
    assert len(lines) == 1 and name in lines[0], err


# ----------------------------------------------------------------------------- gzip damage
def test_truncated_cwa_gz_returns_everything_before_the_cut():
    src, blocks = read("ax3_truncated.cwa.gz")
    assert src.qc.valid == 77  # every complete sector before the cut
    assert sum(b.n for b in blocks) == 77 * 120
    assert "read_error" in reasons(src)


def test_truncated_bin_gz_returns_everything_before_the_cut():
    src, blocks = read("geneactiv_truncated.bin.gz")
    assert sum(b.n for b in blocks) == 33 * 300 + 175
    assert "read_error" in reasons(src) and "truncated_page" in reasons(src)


def test_corrupt_deflate_is_one_clear_line():
    with pytest.raises(CorruptRecordingError, match="damaged gzip data"):
        read("ax3_corrupt_deflate.cwa.gz")
    rc, _, err = cli("inspect", FUZZ / "ax3_corrupt_deflate.cwa.gz")
    assert_one_line_error(rc, err, "ax3_corrupt_deflate.cwa.gz")


def test_gzip_damage_mid_stream_keeps_the_prefix(tmp_path):
    """Damage in the middle of the deflate data: the bytes before it still come out."""
    import gzip
    from stillpoint.drivers.byteio import open_bytes, read_exact, stream_damage
    rng = np.random.default_rng(0)
    plain = rng.integers(0, 4, 400_000, dtype=np.uint8).tobytes()
    z = bytearray(gzip.compress(plain))
    mid = len(z) // 2
    for i in range(mid, mid + 20):
        z[i] ^= 0x55
    p = tmp_path / "d.gz"
    p.write_bytes(bytes(z))
    with open_bytes(p) as f:
        got = read_exact(f, len(plain))
        why = stream_damage(f)
    assert why and "damaged gzip" in why
    assert len(got) < len(plain)
    # deflate cannot say where damage starts, only where it is detected: the bytes up to the
    # damaged spot are exact (what follows it until detection may be garbled; the .cwa sector
    # checksums reject such sectors)
    a = np.frombuffer(got, np.uint8)
    first_diff = int(np.flatnonzero(a != np.frombuffer(plain[:len(got)], np.uint8))[0]) \
        if (a != np.frombuffer(plain[:len(got)], np.uint8)).any() else len(got)
    assert first_diff > 0.4 * len(plain)


# ----------------------------------------------------------------------------- AX3/AX6
def test_ax6_mixed_sector_formats_read_both_and_log_the_change():
    src, blocks = read("ax6_mixed_0x62_0x32_sector.cwa")
    assert sum(b.n for b in blocks) == 800
    assert reasons(src).count("format_change") == 2
    assert [b.gyro is None for b in blocks] == [False, True, False]


# ----------------------------------------------------------------------------- GENEActiv
@pytest.mark.parametrize("name, what", [
    ("geneactiv_gain_inf.bin", "x gain is inf"),
    ("geneactiv_pagetime_2300.bin", "bad_page_time"),
    ("geneactiv_pagetime_1600.bin", "bad_page_time"),
    ("geneactiv_rate_tiny.bin", "not a plausible rate"),
    ("geneactiv_rate_milli.bin", "not a plausible rate"),
    ("geneactiv_rate_huge.bin", "not a plausible rate"),
    ("geneactiv_rate_inf.bin", "not a plausible rate"),
])
def test_geneactiv_refused_with_a_clear_line(name, what):
    with pytest.raises(StillpointError, match=what):
        read(name)
    rc, _, err = cli("inspect", FUZZ / name)
    assert_one_line_error(rc, err, name)


@pytest.mark.parametrize("name, reason", [
    ("geneactiv_seq_overflow.bin", "bad_page_header"),
    ("geneactiv_temperature_inf.bin", "bad_value"),
    ("geneactiv_pagetime_1960.bin", "implausible_time"),
    ("geneactiv_page_freq_tiny.bin", "bad_page_frequency"),
    ("geneactiv_serial_non_latin1.bin", "serial_mismatch"),
])
def test_geneactiv_defect_logged_as_qc(name, reason):
    src, blocks = read(name)
    assert reason in reasons(src)
    t = np.concatenate([b.time_ns for b in blocks])
    assert (np.diff(t) > 0).all()
    for b in blocks:
        assert not np.isinf(b.temperature_c).any() and not np.isinf(b.battery_v).any()


def test_geneactiv_page_rate_tiny_is_timed_with_the_header_rate():
    src, blocks = read("geneactiv_page_freq_tiny.bin")
    t = np.concatenate([b.time_ns for b in blocks])
    dt = np.diff(t[-300:])
    assert np.allclose(dt, 1e9 / src.info.sample_rate_nominal, atol=1)


def test_anchor_going_back_in_time_starts_a_segment():
    src, blocks = read("ax3_3200hz_anchor_back_52ms.cwa")
    assert "time_jump" in reasons(src)
    for b in blocks:  # inside a segment time only moves forward
        assert (np.diff(b.time_ns) > 0).all()
    seg = np.concatenate([np.full(b.n, b.segment) for b in blocks])
    t = np.concatenate([b.time_ns for b in blocks])
    for s in np.unique(seg):
        assert (np.diff(t[seg == s]) > 0).all()


def test_header_rate_differs_from_sector_rate_uses_the_sectors(tmp_path):
    src, blocks = read("ax3_header_6p25hz_sectors_3200hz.cwa")
    assert src.info.sample_rate_nominal == 3200
    assert "rate_mismatch" in reasons(src)
    rc, out, err = cli("process", FUZZ / "ax3_header_6p25hz_sectors_3200hz.cwa", "-o", tmp_path / "o.mcap")
    assert rc == 0, err
    assert "rate_mismatch" in out


# ----------------------------------------------------------------------------- MCAP
@pytest.mark.parametrize("cmd", [["inspect"], ["export", "--topic", "/raw/gyro"], ["replay", "--check"]])
def test_flipped_bit_in_a_chunk_is_never_read_silently(cmd, tmp_path):
    name = "ax6_one_flipped_byte_in_middle_chunk.mcap"
    extra = ["-o", tmp_path / ("o.csv" if cmd[0] == "export" else "o.mcap")] if cmd[0] != "inspect" else []
    rc, out, err = cli(cmd[0], FUZZ / name, *cmd[1:], *extra)
    assert_one_line_error(rc, err, name)
    assert "crc" in err.lower() and "chunk 23" in err


def test_recover_salvages_good_chunks_around_a_bad_one(tmp_path):
    from stillpoint.engine.mcap.compare import topic_digests
    from stillpoint.engine.recover import recover
    rep = recover(FUZZ / "ax6_one_flipped_byte_in_middle_chunk.mcap", tmp_path / "r.mcap")
    assert len(rep.bad_records) == 1 and "chunk 23" in rep.bad_records[0]
    assert rep.stopped_at == ""
    # one chunk of 45 lost: everything else (incl. the chunks after it) is kept
    assert rep.per_topic["/raw/accel"] == 44 and rep.per_topic["/raw/gyro"] == 44
    assert topic_digests(tmp_path / "r.mcap")["/raw/gyro"][0] == 44
    rc, out, err = cli("recover", FUZZ / "ax6_one_flipped_byte_in_middle_chunk.mcap", "-o", tmp_path / "r2.mcap")
    assert rc == 0 and "chunk 23" in out


def test_recover_torn_tail_still_works(tmp_path):
    from stillpoint.engine.recover import recover
    rep = recover(FUZZ / "ax6_torn_tail_mid_chunk.mcap", tmp_path / "r.mcap")
    assert rep.per_topic["/raw/accel"] == 22 and "runs past the end" in rep.stopped_at


def test_replay_check_compares_every_topic(tmp_path):
    """Every topic is compared, /raw/gyro included (it used to be skipped), and a difference on
    /raw/gyro alone is reported."""
    from stillpoint.engine.mcap.compare import compare
    from stillpoint.engine.recover import recover
    recover(FUZZ / "ax6_one_flipped_byte_in_middle_chunk.mcap", tmp_path / "a.mcap")
    res = compare(tmp_path / "a.mcap", tmp_path / "a.mcap")
    assert {"/raw/gyro", "/raw/accel", "/qc", "/temperature", "/corrected/accel",
            "/metrics/epoch", "/calibration"} <= set(res)
    assert all(r["identical"] for r in res.values())
    # b: the same log with one /raw/gyro message left out
    from mcap.reader import make_reader
    from mcap.writer import Writer
    with open(tmp_path / "a.mcap", "rb") as fa, open(tmp_path / "b.mcap", "wb") as fb:
        r = make_reader(fa)
        w = Writer(fb)
        w.start()
        ids, dropped = {}, False
        for sch, ch, m in r.iter_messages(log_time_order=False):
            if ch.id not in ids:
                sid = w.register_schema(sch.name, sch.encoding, sch.data) if sch else 0
                ids[ch.id] = w.register_channel(ch.topic, ch.message_encoding, sid)
            if ch.topic == "/raw/gyro" and not dropped:
                dropped = True
                continue
            w.add_message(ids[ch.id], m.log_time, m.data, m.publish_time)
        w.finish()
    res = compare(tmp_path / "a.mcap", tmp_path / "b.mcap")
    assert [t for t, r in res.items() if not r["identical"]] == ["/raw/gyro"]


@pytest.mark.parametrize("name, what", [
    ("qc_message_not_json.mcap", "channel /qc, message 0"),
    ("qc_message_not_utf8.mcap", "channel /qc, message 0"),
    ("raw_unit_start_int32_min.mcap", "channel /raw/accel, message 0"),
    ("device_rate_1hz.mcap", "sample_rate_nominal"),
])
@pytest.mark.parametrize("cmd", ["inspect", "replay", "export", "calibrate"])
def test_damaged_mcap_fields_are_typed_errors(name, what, cmd, tmp_path):
    extra = {"replay": ["-o", tmp_path / "o.mcap"], "export": ["--topic", "/qc", "-o", tmp_path / "o.csv"]
             if "qc" in name else ["--topic", "/raw/accel", "-o", tmp_path / "o.csv"]}.get(cmd, [])
    rc, out, err = cli(cmd, FUZZ / name, *extra)
    if cmd == "export" and name in ("device_rate_1hz.mcap", "qc_message_not_json.mcap"):
        # export copies messages as text: it does not use the device record or parse /qc
        assert rc == 0, err
        return
    assert_one_line_error(rc, err, name)
    assert what in err
