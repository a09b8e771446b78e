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
from stillpoint.engine.core.errors import CorruptRecordingError, StillpointError

FUZZ = Path(__file__).parents[1] / "data" / "fuzz"


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


# ----------------------------------------------------------------------------- fuzz3 reproducers
# The reliability campaign's reproducers: the ``fuzz3`` fixture (conftest.py).


def _whole_read(path, **opts):
    """Samples (times, counts, segments) and QC of a whole read, or the typed error's text."""
    try:
        with open_recording(path, **opts) as src:
            blocks = list(src)
    except StillpointError as e:
        return f"{type(e).__name__}: {e}"
    cat = np.concatenate
    t = cat([b.time_ns for b in blocks]).tolist() if blocks else []
    a = cat([b.accel for b in blocks]).tolist() if blocks else []
    seg = [b.segment for b in blocks for _ in range(b.n)]
    q = src.qc
    return t, a, seg, (q.total, q.valid, q.skipped, q.segments), [(e.index, e.reason) for e in q.events]


@pytest.mark.parametrize("name, samples, segments", [
    ("geneactiv_batch_pages_data_vs_error.bin", 300, 1),
    # page 11's Page Time '2013-05-30T10:12:54:500' was refused or read depending on its batch
    ("geneactiv_batch_pages_3531_vs_3231.bin", 3531, 5),
])
def test_geneactiv_damaged_file_reads_the_same_at_every_batch_size(fuzz3, name, samples, segments):
    path = fuzz3(name)
    ref = _whole_read(path)
    assert not isinstance(ref, str), ref
    assert len(ref[0]) == samples and ref[3][3] == segments
    pages = ref[3][0]
    for batch in range(1, pages + 2):
        assert _whole_read(path, batch_pages=batch) == ref, f"batch_pages={batch}"
    for batch in (1, 2, 3, 256):  # follow mode (a download read while it grows) as well
        assert _whole_read(path, batch_pages=batch, follow=True, follow_done=lambda: True,
                           follow_idle_s=0) == ref, f"follow, batch_pages={batch}"


def _no_warnings_read(path):
    import warnings
    with warnings.catch_warnings(record=True) as caught, np.errstate(all="warn"):
        warnings.simplefilter("always")
        with open_recording(path) as src:
            for b in src:
                b.accel_g()
    assert not caught, [str(w.message) for w in caught]
    return src


def test_geneactiv_lux_inf_is_a_qc_event(fuzz3, tmp_path):
    path = fuzz3("geneactiv_lux_inf.bin")
    src = _no_warnings_read(path)
    ev = [e for e in src.qc.events if e.reason == "header_value"]
    assert len(ev) == 1 and "Lux inf" in ev[0].detail and "light in lux unavailable" in ev[0].detail
    assert src.info.header["lux"] is None and src.qc.valid == 3
    rc, out, err = cli("export", path, "-o", tmp_path / "x.csv")
    assert rc == 0 and "1 QC event" in out, out + err
    assert "Warning" not in err and "Traceback" not in err, err
    rc, out, err = cli("inspect", "--json", path)
    assert rc == 0 and "header_value" in out and "Lux inf" in out, err


@pytest.mark.parametrize("line, what", [
    (b"Lux:nan", "Lux nan"), (b"Lux:-800", "Lux -800"), (b"Lux:0", "Lux 0"),
    (b"Volts:0", "Volts 0"), (b"Volts:-inf", "Volts -inf"), (b"Volts:abc", "Volts 'abc' is not a number"),
    (b"Volts:", "Volts missing"),
    (b"Volts:1e-308", "Volts 1e-308"), (b"Lux:1e-308", "Lux 1e-308"),  # lux overflow / underflow
])
def test_geneactiv_header_value_that_blanks_the_light_is_a_qc_event(fuzz3, tmp_path, line, what):
    data = fuzz3("geneactiv_lux_inf.bin").read_bytes().replace(b"Lux:inf", b"Lux:800")
    key = line.split(b":")[0] + b":"
    i = data.index(b"\n" + key) + 1
    j = data.index(b"\n", i)
    cr = b"\r" if data[j - 1:j] == b"\r" else b""
    p = tmp_path / "v.bin"
    p.write_bytes(data[:i] + line + cr + data[j:])
    src = _no_warnings_read(p)
    ev = [e for e in src.qc.events if e.reason == "header_value"]
    assert len(ev) == 1 and what in ev[0].detail, [e.detail for e in src.qc.events]
    assert src.qc.valid == 3  # the pages are still read


def test_geneactiv_good_light_calibration_logs_nothing(fuzz3, tmp_path):
    p = tmp_path / "good.bin"
    p.write_bytes(fuzz3("geneactiv_lux_inf.bin").read_bytes().replace(b"Lux:inf", b"Lux:800"))
    src = _no_warnings_read(p)
    assert src.qc.events == [] and src.info.header["lux"] == 800.0


MCAP_COMMANDS = {"inspect": [], "replay": ["-o", "{tmp}/r.mcap"], "calibrate": [],
                 "discrepancy": ["-o", "{tmp}/d", "--no-plots"]}


@pytest.mark.parametrize("name", ["raw_accel_reversed.mcap", "raw_accel_two_messages_swapped.mcap"])
@pytest.mark.parametrize("cmd", list(MCAP_COMMANDS))
def test_raw_messages_out_of_order_are_one_typed_line(fuzz3, tmp_path, name, cmd):
    extra = [a.format(tmp=tmp_path) for a in MCAP_COMMANDS[cmd]]
    rc, out, err = cli(cmd, fuzz3(name), *extra)
    assert_one_line_error(rc, err, name)
    assert "out of order" in err and "/raw/accel, message 1" in err, err
    assert not (tmp_path / "r.mcap").exists()


def test_raw_messages_in_order_still_replay(fuzz3, tmp_path):
    """The same log with its messages in their order replays (the check refuses only disorder)."""
    from stillpoint.engine.mcap.replay import McapRawSource
    fixed = _rewrite(fuzz3("raw_accel_two_messages_swapped.mcap"), tmp_path / "fixed.mcap",
                     swap_raw=(0, 1))
    with McapRawSource(fixed) as src:
        n = sum(b.n for b in src)
    assert n > 0
    rc, out, err = cli("replay", fixed, "-o", tmp_path / "r.mcap")
    assert rc == 0, err


def _rewrite(src_path, out_path, *, settings=None, swap_raw=None, calibration=None, raw=None):
    """A copy of a log with its ``settings`` or ``calibration`` record changed (key -> value), two
    /raw/accel payloads swapped back, or fields of one /raw/accel message changed
    (``raw=(message, {field: values})``)."""
    import json
    from mcap.reader import make_reader
    from mcap.writer import Writer
    with open(src_path, "rb") as f:
        r = make_reader(f)
        msgs = list(r.iter_messages(log_time_order=False))
        meta = [(m.name, dict(m.metadata)) for m in r.iter_metadata()]
    payloads = [m.data for _s, _c, m in msgs]
    if swap_raw:
        raw_at = [j for j, (_s, ch, _m) in enumerate(msgs) if ch.topic == "/raw/accel"]
        a, b = raw_at[swap_raw[0]], raw_at[swap_raw[1]]
        payloads[a], payloads[b] = payloads[b], payloads[a]
    if raw:
        from stillpoint.engine.mcap.schemas import ACCEL_BATCH_RAW
        j = [j for j, (_s, ch, _m) in enumerate(msgs) if ch.topic == "/raw/accel"][raw[0]]
        values = ACCEL_BATCH_RAW.decode(payloads[j])
        for k, v in raw[1].items():
            values[k] = np.asarray(v, dtype=np.asarray(values[k]).dtype)
        payloads[j] = ACCEL_BATCH_RAW.encode(values)
    with open(out_path, "wb") as f:
        w = Writer(f)
        w.start()
        ids = {}
        for (sch, ch, m), data in zip(msgs, payloads):
            if ch.id not in ids:
                sid = w.register_schema(sch.name, sch.encoding, sch.data) if sch else 0
                ids[ch.id] = w.register_channel(ch.topic, ch.message_encoding, sid, dict(ch.metadata))
            w.add_message(ids[ch.id], m.log_time, data, m.publish_time)
        for name, md in meta:
            change = {"settings": settings, "calibration": calibration}.get(name)
            if change:
                d = json.loads(md["json"])
                d.update(change)
                md["json"] = json.dumps(d)
            w.add_metadata(name, md)
        w.finish()
    return out_path


def test_settings_value_of_the_wrong_type_is_one_typed_line(fuzz3, tmp_path):
    name = "settings_first_hours_string.mcap"
    for cmd in ("replay", "inspect", "calibrate"):
        extra = ["-o", tmp_path / "r.mcap"] if cmd == "replay" else []
        rc, out, err = cli(cmd, fuzz3(name), *extra)
        assert_one_line_error(rc, err, name)
        assert "first_hours is '48'" in err, err


@pytest.mark.parametrize("key, value", [
    ("first_hours", "nan"), ("first_hours", float("nan")), ("zstd_level", "nan"),
    ("compression", "brotli"), ("chunk_size", 2**70), ("bfen_band_hz", [1]), ("calibrate", "no"),
    ("mode", None), ("max_block_s", 1e308), ("epoch_s", -5), ("prior", {"offset": "x"}),
    ("view_hz", float("inf")), ("timezone", 5),
])
def test_every_settings_value_is_checked_when_read(fuzz3, tmp_path, key, value):
    from stillpoint.engine.mcap.replay import McapRawSource
    from stillpoint.engine.mcap.reading import McapReadError
    good = _rewrite(fuzz3("settings_first_hours_string.mcap"), tmp_path / "good.mcap",
                    settings={"first_hours": 72.0})
    McapRawSource(good).close()  # the record as logged, first_hours repaired, is accepted
    bad = _rewrite(good, tmp_path / "bad.mcap", settings={key: value})
    with pytest.raises(McapReadError, match=f"settings metadata: .*{key}"):
        McapRawSource(bad)


def test_settings_as_every_run_logs_them_are_accepted():
    from stillpoint.engine.run import RunSettings
    from stillpoint.engine.settings import settings_problem
    for s in (RunSettings(), RunSettings(mode="online", compression="lz4", chunk_s=30.0,
                                         timezone="Europe/London", view_hz=0.0,
                                         corrected_quantum_g=0.0, ggir_compatible=True)):
        assert settings_problem(s.to_dict()) is None


def test_raw_order_rule_covers_times_and_segments(fuzz3, tmp_path):
    """Sample numbers in order but times (or segments) going back are refused too."""
    import dataclasses
    from stillpoint.engine.mcap.replay import McapRawSource, _check_order
    from stillpoint.engine.mcap.reading import McapReadError
    fixed = _rewrite(fuzz3("raw_accel_two_messages_swapped.mcap"), tmp_path / "fixed.mcap",
                     swap_raw=(0, 1))
    with McapRawSource(fixed) as src:
        whole = next(iter(src))
    half = whole.n // 2
    a, b = whole.slice(0, half), whole.slice(half, whole.n)  # two consecutive pieces
    state = _check_order(None, a, fixed, 0)
    assert _check_order(state, b, fixed, 1)[1] == b.first_sample + b.n  # in order: accepted
    if b.segment == a.segment:
        back = dataclasses.replace(b, time_ns=b.time_ns - (b.time_ns[0] - a.time_ns[0]) - 1)
        with pytest.raises(McapReadError, match="before the previous message's last"):
            _check_order(state, back, fixed, 1)
    with pytest.raises(McapReadError, match="segment -1 after segment"):
        _check_order(state, dataclasses.replace(b, segment=-1), fixed, 1)
    inside = a.time_ns.copy()
    inside[[5, 6]] = inside[[6, 5]]
    with pytest.raises(McapReadError, match="time goes back .* after sample 5"):
        _check_order(None, dataclasses.replace(a, time_ns=inside), fixed, 0)


@pytest.mark.parametrize("change, what", [
    ({"status": "ok", "scale": ["1", 1, 1]}, "scale"),
    ({"status": "ok", "offset": [float("nan"), 0, 0]}, "offset"),
    ({"status": "ok", "scale": [1, 1]}, "scale"),
    ({"status": 3}, "not an estimate"),
])
def test_calibration_record_is_checked_when_tables_are_made_from_a_log(fuzz3, tmp_path, change, what):
    good = _rewrite(fuzz3("settings_first_hours_string.mcap"), tmp_path / "good.mcap",
                    settings={"first_hours": 72.0})
    rc, out, err = cli("export", good, "-o", tmp_path / "g.epochs.csv.gz", "--table", "epochs")
    assert rc == 0, err
    bad = _rewrite(good, tmp_path / "bad.mcap", calibration=change)
    rc, out, err = cli("export", bad, "-o", tmp_path / "b.epochs.csv.gz", "--table", "epochs")
    assert_one_line_error(rc, err, "bad.mcap")
    assert "metadata 'calibration'" in err and what in err, err


@pytest.mark.parametrize("field, value, what", [
    ("zero_counts", [0.0, 0.0, 1e-310], "zero_counts"),  # underflowed in the float32 pipeline
    ("counts_per_g", [1e-306, 256.0, 256.0], "counts_per_g"),  # overflowed to inf g
    ("temperature_c", [2.9e78], r"temperature_c 2\.9e\+78"),  # overflowed the float32 epoch topic
    ("temperature_c", [float("inf")], "temperature_c inf"),
    ("battery_v", [-1e300], "battery_v"),
])
def test_raw_scale_and_unit_values_a_float32_run_cannot_hold_are_typed(fuzz3, tmp_path, field, value, what):
    """Found by the fuzz script as numpy warnings during replay; now refused where the message is
    read, with the message named."""
    import warnings
    from stillpoint.engine.mcap.replay import McapRawSource
    from stillpoint.engine.mcap.reading import McapReadError
    good = _rewrite(fuzz3("settings_first_hours_string.mcap"), tmp_path / "good.mcap",
                    settings={"first_hours": 72.0})
    bad = _rewrite(good, tmp_path / "bad.mcap", raw=(0, {field: _fill(good, field, value)}))
    with warnings.catch_warnings(), np.errstate(all="raise"):
        warnings.simplefilter("error")
        with pytest.raises(McapReadError, match=f"message 0.*{what}"):
            with McapRawSource(bad) as src:
                list(src)
    rc, out, err = cli("replay", bad, "-o", tmp_path / "r.mcap")
    assert_one_line_error(rc, err, "bad.mcap")


def _fill(log, field, head):
    """``head`` then the logged values of message 0's ``field`` (same length as logged)."""
    from mcap.reader import make_reader
    from stillpoint.engine.mcap.schemas import ACCEL_BATCH_RAW
    with open(log, "rb") as f:
        for _s, ch, m in make_reader(f).iter_messages(log_time_order=False):
            if ch.topic == "/raw/accel":
                logged = list(np.asarray(ACCEL_BATCH_RAW.decode(m.data)[field], np.float64))
                return head + logged[len(head):]


# ----------------------------------------------------------------------------- fuzz4 reproducers
# The resource-bounds campaign's reproducers: the ``fuzz4`` fixture (conftest.py), README there.
def test_logged_flush_interval_below_its_bound_is_one_line(fuzz4, tmp_path):
    name = "settings_flush_every_s_1e-9.mcap"
    rc, out, err = cli("replay", fuzz4(name), "-o", tmp_path / "r.mcap")
    assert_one_line_error(rc, err, name)
    assert "flush_every_s is 1e-09, expected a number in [1, 600] s" in err, err
    assert not (tmp_path / "r.mcap").exists()


@pytest.mark.parametrize("key, value", [
    ("flush_every_s", 1e-5), ("flush_every_s", 601.0), ("max_block_s", 0.01), ("max_block_s", 86_400.0),
    ("epoch_s", 0.01), ("epoch_s", 86_400.0), ("window_s", 1e5), ("chunk_hours", 1e-9),
    ("first_hours", 0.0), ("chunk_s", 1e-3), ("chunk_size", 1), ("chunk_size", 1 << 30), ("view_hz", 1e-6),
])
def test_every_bounded_setting_is_refused_outside_its_bounds(key, value):
    """One table of bounds (engine.settings.BOUNDS): the record check and RunSettings agree."""
    from stillpoint.engine.settings import BOUNDS, RunSettings, SettingsError, settings_problem
    lo, hi, _unit = BOUNDS[key]
    assert not lo <= value <= hi
    assert settings_problem({key: value}).startswith(f"{key} is ")
    with pytest.raises(SettingsError, match=key):
        RunSettings(**{key: value})
    for inside in (lo, hi):  # both ends are usable
        assert settings_problem({key: inside}) is None
        RunSettings(**{key: inside})


@pytest.mark.parametrize("option, value", [("--flush-every-s", "1e-9"), ("--flush-every-s", "1e-5"),
                                           ("--flush-every-s", "3600"), ("--chunk-hours", "1e-6"),
                                           ("--epoch-s", "0.01"), ("--view-hz", "1e-9")])
def test_command_line_takes_the_same_bounds(option, value, tmp_path):
    rc, out, err = cli("process", tmp_path / "none.cwa", "-o", tmp_path / "o.mcap", option, value)
    assert rc == 2 and "Traceback" not in err
    assert f"argument {option}: {value} is outside [" in err, err


def test_profile_nested_thousands_deep_is_one_line(fuzz4, tmp_path):
    name = "profile_deep_nest.toml"
    rc, out, err = cli("station", tmp_path / "out", "--profile", fuzz4(name), "--once")
    assert_one_line_error(rc, err, name)
    assert "nested too deeply" in err, err


def test_profile_larger_than_a_profile_is_one_line(tmp_path):
    p = tmp_path / "big.toml"
    p.write_text("[study]\n" + "# filler\n" * 200_000)
    rc, out, err = cli("station", tmp_path / "out", "--profile", p, "--once")
    assert_one_line_error(rc, err, "big.toml")
    assert "KiB, not a study profile" in err, err


def test_long_file_name_template_is_refused_at_profile_load(tmp_path):
    from stillpoint.engine.station.profile import ProfileError, load_profile
    from stillpoint.engine.station.study import MAX_TEMPLATE_CHARS
    base = "[station]\nfile_name = \"{}\"\n"
    ok = "x" * (MAX_TEMPLATE_CHARS - len("{device}_{session}")) + "{device}_{session}"
    (tmp_path / "ok.toml").write_text(base.format(ok))
    load_profile(tmp_path / "ok.toml")
    (tmp_path / "long.toml").write_text(base.format("a" * 5000 + "{device}_{session}"))
    with pytest.raises(ProfileError, match="5,018 characters, at most"):
        load_profile(tmp_path / "long.toml")


def test_sleep_log_cell_over_the_csv_field_limit_is_one_line(real_file, tmp_path):
    rec = real_file("ax3_ggirread_testfile_100hz_145blocks.cwa")
    sl = tmp_path / "sl.csv"
    sl.write_text("ID,on,wk\np01," + "1" * 200_000 + ",07:00\n")
    rc, out, err = cli("process", rec, "-o", tmp_path / "o.mcap", "--timezone", "UTC",
                       "--sleep-log", sl, "--sleep-log-id", "p01")
    assert_one_line_error(rc, err, "sl.csv")
    assert "field larger than field limit" in err, err


def test_manifest_without_a_path_column_names_the_columns_found(fuzz4, tmp_path):
    import shutil
    name = "manifest_no_path_column.csv"
    shutil.copy(fuzz4(name), tmp_path / name)
    (tmp_path / "p01.cwa").write_bytes(b"")
    rc, out, err = cli("cohort", "run", tmp_path / name, "-o", tmp_path / "co")
    assert_one_line_error(rc, err, name)
    assert "no 'path' column (columns found: file, timezone)" in err, err


def test_manifest_cell_over_the_csv_field_limit_is_one_line(tmp_path):
    m = tmp_path / "m.csv"
    m.write_text("path,timezone\n" + "a" * 200_000 + ".cwa,UTC\n")
    rc, out, err = cli("cohort", "run", m, "-o", tmp_path / "co")
    assert_one_line_error(rc, err, "m.csv")


def test_manifest_of_plain_paths_still_reads_without_a_header(tmp_path):
    from stillpoint.engine.cohort import discover_inputs
    (tmp_path / "a.cwa").write_bytes(b"")
    (tmp_path / "m.csv").write_text("a.cwa\nb.bin\n")
    assert [p.name for p in discover_inputs([tmp_path / "m.csv"])] == ["a.cwa", "b.bin"]


def test_cohort_run_exits_2_when_every_file_failed(tmp_path):
    for n in ("a.cwa", "b.cwa"):
        (tmp_path / n).write_bytes(b"\x00" * 2048)
    rc, out, err = cli("cohort", "run", tmp_path / "a.cwa", tmp_path / "b.cwa", "-o", tmp_path / "co",
                       "--scheduler", "serial", "-q")
    assert rc == 2 and "Traceback" not in err
    assert "every file failed (2)" in err, err


def test_profile_integer_of_thousands_of_digits_is_one_line(tmp_path):
    from stillpoint.engine.station.profile import ProfileError, load_profile
    p = tmp_path / "p.toml"
    p.write_text("[station]\nerase = " + "9" * 200_000 + "\n")
    with pytest.raises(ProfileError, match="not a study profile"):
        load_profile(p)


@pytest.mark.parametrize("text, what", [
    ("{" * 5000 + ",UTC\n", "no 'path' column"),  # a first row naming no file, too long to stat
    ("path,timezone\na.cwa," + "Z" * 5000 + "\n", "neither an IANA name"),  # a zone too long to open
])
def test_manifest_names_too_long_for_the_system_are_one_line(tmp_path, text, what):
    from stillpoint.engine.cohort import discover_inputs
    from stillpoint.engine.cohort.plan import CohortInputError
    m = tmp_path / "m.csv"
    m.write_text(text)
    with pytest.raises(CohortInputError, match=what):
        discover_inputs([m], {})


def test_manifest_path_of_an_unknown_user_is_kept_as_written(tmp_path):
    from stillpoint.engine.cohort import discover_inputs
    (tmp_path / "m.csv").write_text("path\n~no_such_user_here_x/a.cwa\n")
    [p] = discover_inputs([tmp_path / "m.csv"], {})
    assert p.name == "a.cwa" and "~no_such_user_here_x" in str(p)


def test_refused_manifest_leaves_no_cohort_folder(fuzz4, tmp_path):
    rc, out, err = cli("cohort", "run", fuzz4("manifest_no_path_column.csv"), "-o", tmp_path / "co")
    assert rc == 2 and not (tmp_path / "co").exists()
