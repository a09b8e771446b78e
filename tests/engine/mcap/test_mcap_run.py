"""End to end on written .cwa files: process -> MCAP (raw lossless, corrected, metrics,
estimates, QC), replay bit for bit, faults (corrupt sector, truncated file, unreadable file),
export, CLI."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys

import numpy as np
import pytest
from mcap.reader import make_reader

from stillpoint.drivers import open_recording
from stillpoint.drivers.cwa import corrupt_sector
from stillpoint.engine.mcap.replay import McapRawSource
from stillpoint.engine.core.blocks import Block
from stillpoint.engine.calibration.estimate import CalibrationEstimate
from stillpoint.engine.mcap.compare import compare
from stillpoint.engine.mcap.schemas import ACCEL_BATCH, times_from_deltas
from stillpoint.engine.run import RunSettings, process_file
from stillpoint.tools.cli import main as cli
from synthetic_recording import make_recording


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    d = tmp_path_factory.mktemp("rec")
    p = d / "rec.cwa"
    make_recording(p, hours=1.0, rate=50.0, seed=3)
    return p


def _blocks(src):
    by_seg = {}
    for b in src:
        by_seg.setdefault(b.segment, []).append(b)
    return {s: Block.concat(v) for s, v in by_seg.items()}


def _messages(path, topic):
    with open(path, "rb") as f:
        return [(m.log_time, m.data) for _s, _c, m in
                make_reader(f).iter_messages(topics=[topic], log_time_order=False)]


def _corrected(path):
    t, a = [], []
    for _lt, data in _messages(path, "/corrected/accel"):
        m = ACCEL_BATCH.decode(data)
        t.append(times_from_deltas(m["t0_ns"], m["dt_ns"]))
        a.append(np.stack([m["x"], m["y"], m["z"]], axis=1))
    return np.concatenate(t), np.concatenate(a)


def test_raw_channel_replays_exactly_the_logged_blocks(recording, tmp_path):
    out = tmp_path / "r.mcap"
    process_file(recording, out, RunSettings(mode="online"))
    with open_recording(recording) as src:
        ref = _blocks(src)
        info = src.info
    rs = McapRawSource(out)
    got = _blocks(rs)
    assert rs.info.device_key == info.device_key and rs.info.sample_rate_nominal == info.sample_rate_nominal
    assert rs.settings["mode"] == "online"
    assert set(got) == set(ref)
    for s in ref:
        a, b = ref[s], got[s]
        for name in ("time_ns", "accel", "accel_counts_per_g", "accel_zero", "unit_index",
                     "unit_sequence", "unit_start", "temperature_c", "temperature_raw", "light",
                     "battery_v", "events"):
            assert np.array_equal(getattr(a, name), getattr(b, name)), name
        assert a.first_sample == b.first_sample


@pytest.mark.parametrize("mode", ["batch", "online"])
def test_replay_is_bit_identical(recording, tmp_path, mode):
    first = tmp_path / "first.mcap"
    s = RunSettings(mode=mode, chunk_hours=0.25, first_hours=0.5)
    summary = process_file(recording, first, s)
    assert summary["samples"] > 150_000
    again = tmp_path / "again.mcap"
    assert cli(["replay", str(first), "-o", str(again), "-q"]) == 0
    res = compare(first, again)
    assert all(r["identical"] for r in res.values()), res
    assert res["/corrected/accel"]["messages"][0] > 10
    if mode == "online":  # several refits were published, with their effective times
        est = [json.loads(d) for _t, d in _messages(first, "/calibration")]
        assert len(est) >= 3 and all("effective_from_ns" in e for e in est)
    # different settings -> a different corrected stream (the check can fail)
    other = tmp_path / "other.mcap"
    assert cli(["replay", str(first), "-o", str(other), "-q", "--no-calibrate"]) == 0
    assert not compare(first, other)["/corrected/accel"]["identical"]
    assert cli(["replay", str(first), "-o", str(tmp_path / "o2.mcap"), "-q", "--no-calibrate",
                "--check"]) == 1


def test_batch_corrected_stream_is_the_logged_estimate_applied(recording, tmp_path):
    out = tmp_path / "b.mcap"
    summary = process_file(recording, out, RunSettings(mode="batch"))
    cal = summary["calibration"]
    assert cal["status"] in ("ok", "high_error")
    assert cal["error_after_mg"] < cal["error_before_mg"]
    logged = [json.loads(d) for _t, d in _messages(out, "/calibration")]
    assert len(logged) == 1 and logged[0]["applied"] is True
    est = CalibrationEstimate.from_dict(logged[0])
    with open_recording(recording) as src:
        ref = _blocks(src)[0]
    t, a = _corrected(out)
    assert np.array_equal(t, ref.time_ns)
    ends = np.append(ref.unit_start[1:], ref.n) - 1
    rel = (ref.time_ns - ref.time_ns[0]).astype(float)
    temp = np.interp(rel, rel[ends], ref.temperature_c)
    want = est.apply(ref.accel_g(), temp)
    q = 2.0 ** -16
    assert np.max(np.abs(a - want)) <= q / 2 + 1e-6
    # epoch metrics were logged for every 5 s of data, ENMO >= 0
    assert summary["epochs"] >= 3600 / 5
    assert summary["enmo_mean_mg"] > 0


def test_corrupt_sector_is_skipped_logged_and_run_goes_on(recording, tmp_path):
    bad = tmp_path / "bad.cwa"
    bad.write_bytes(recording.read_bytes())
    corrupt_sector(bad, 500, "checksum")
    out = tmp_path / "bad.mcap"
    s = process_file(bad, out, RunSettings(mode="online"))
    with open_recording(recording) as src:
        n_full = sum(b.n for b in src)
    assert s["samples"] == n_full - 80  # one unpacked AX3 sector of 80 samples skipped
    assert s["qc"]["skipped"] == 1 and s["segments"] == 2
    qc = [json.loads(d) for _t, d in _messages(out, "/qc")]
    assert any(e["reason"] == "checksum" and e["index"] == 500 and e["source"] == "reader" for e in qc)
    # after the corrupt sector, windows restart at the new segment and the stream continues
    t, _a = _corrected(out)
    assert t.shape[0] == s["samples"]


def test_file_ending_mid_sector_is_processed_to_the_last_whole_sector(recording, tmp_path):
    cut = tmp_path / "cut.cwa"
    data = recording.read_bytes()
    cut.write_bytes(data[: len(data) - 200])
    s = process_file(cut, tmp_path / "cut.mcap", RunSettings())
    with open_recording(recording) as src:
        n_full = sum(b.n for b in src)
    assert 0 < n_full - s["samples"] <= 80


def test_unreadable_input_exits_2_with_one_line(tmp_path):
    junk = tmp_path / "junk.cwa"
    junk.write_bytes(b"this is not a recording" * 10)
    r = subprocess.run([sys.executable, "-m", "stillpoint.tools", "process", str(junk)],
                       capture_output=True, text=True)
    assert r.returncode == 2
    assert len(r.stderr.strip().splitlines()) == 1 and "junk.cwa" in r.stderr
    r = subprocess.run([sys.executable, "-m", "stillpoint.tools", "recover", str(junk), "-o",
                        str(tmp_path / "x.mcap")], capture_output=True, text=True)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1


def test_process_cli_summary_and_export(recording, tmp_path, capsys):
    out, sj = tmp_path / "c.mcap", tmp_path / "s.json"
    assert cli(["process", str(recording), "-o", str(out), "--summary", str(sj)]) == 0
    text = capsys.readouterr().out
    assert "calibration:" in text and "ENMO mean" in text
    s = json.loads(sj.read_text())
    for k in ("samples", "duration_s", "windows", "nonmovement_windows", "calibration",
              "enmo_mean_mg", "outputs"):
        assert k in s, k
    for k in ("offset", "scale", "tempoffset", "temperature_ref", "error_before_mg",
              "error_after_mg", "hours_used", "status"):
        assert k in s["calibration"], k
    assert s["outputs"]["mcap"] == str(out)
    assert abs(s["duration_s"] - 3600) < 2
    # the MCAP carries device + settings metadata and well-known encodings
    with open(out, "rb") as f:
        r = make_reader(f)
        meta = {m.name: m.metadata for m in r.iter_metadata()}
        summ = r.get_summary()
    assert {"device", "settings", "summary", "calibration"} <= set(meta)
    assert json.loads(meta["settings"]["json"])["mode"] == "batch"
    enc = {c.topic: c.message_encoding for c in summ.channels.values()}
    assert enc["/raw/accel"] == enc["/corrected/accel"] == enc["/metrics/epoch"] == "cdr"
    assert enc["/calibration"] == enc["/qc"] == "json"
    assert {s.encoding for s in summ.schemas.values()} == {"ros2msg", "jsonschema"}
    by_id = {c.topic: summ.schemas[c.schema_id].encoding for c in summ.channels.values()}
    assert by_id["/calibration"] == by_id["/qc"] == "jsonschema"
    assert by_id["/view/accel"] == "ros2msg"
    # export: epoch metrics to CSV, corrected stream to NPZ
    csv = tmp_path / "m.csv"
    assert cli(["export", str(out), "-o", str(csv), "--topic", "/metrics/epoch"]) == 0
    lines = csv.read_text().splitlines()
    # a .cwa processed without a zone: the device clock, never labelled UTC
    assert lines[0].startswith("time_local,time_local_ns,n,enmo_mg,bfen_mg,mad_mg")
    assert len(lines) - 1 == s["epochs"] and not lines[1].split(",")[0].endswith("Z")
    npz = tmp_path / "c.npz"
    assert cli(["export", str(out), "-o", str(npz), "--topic", "/corrected/accel"]) == 0
    z = np.load(npz)
    assert z["corrected/accel/x"].shape[0] == s["samples"]
    t, _a = _corrected(out)
    assert np.array_equal(z["corrected/accel/time_ns"], t)


def test_no_output_overwrites_an_input_or_another_output(recording, tmp_path, capsys):
    """`--summary` naming the recording, or the MCAP, or a table; `-o` naming the input; align's
    JSON naming its MCAP: each is one line and exit 2 before any work, and nothing is touched
    (the summary used to replace the recording itself)."""
    import hashlib
    import shutil
    rec = tmp_path / "rec.cwa"
    shutil.copy(recording, rec)
    digest = hashlib.sha256(rec.read_bytes()).hexdigest()
    m = tmp_path / "m.mcap"
    for argv, msg in ((["process", str(rec), "-o", str(m), "--summary", str(rec)],
                       "summary would overwrite the input"),
                      (["process", str(rec), "-o", str(rec)], "the log is an MCAP file, name it NAME.mcap"),
                      (["process", str(rec), "-o", str(m), "--summary", str(m)],
                       "the summary and the MCAP output are the same file"),
                      (["process", str(rec), "-o", str(m), "--summary", str(tmp_path / "m.days.csv")],
                       "the day table and the summary are the same file"),
                      (["align", str(rec), str(rec), "-o", str(m), "--json-out", str(m)],
                       "the JSON output and the MCAP output are the same file")):
        assert cli(argv) == 2, argv
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and msg in err[0], err
    assert hashlib.sha256(rec.read_bytes()).hexdigest() == digest
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rec.cwa"]


def test_export_columns_empty_topics_and_foreign_logs(recording, tmp_path, capsys):
    """Every exportable topic's rows have the columns export.COLUMNS names (a CSV's header); a
    topic the log holds no message of is a CSV with its header only; an MCAP another program
    wrote is refused with one line, as replay and inspect refuse it, and nothing is written."""
    from mcap.writer import Writer

    from stillpoint.engine.mcap.export import COLUMNS, _rows
    out = tmp_path / "c.mcap"
    assert cli(["process", str(recording), "-o", str(out), "-q"]) == 0
    seen = set()
    for topic in COLUMNS:
        for _lt, data in _messages(out, topic)[:1]:
            assert tuple(_rows(topic, data, _lt, out, 0)) == COLUMNS[topic], topic
            seen.add(topic)
    assert seen == set(COLUMNS) - {"/raw/gyro"}  # an AX3: no gyro
    gyro = tmp_path / "gyro.csv"
    assert cli(["export", str(out), "-o", str(gyro), "--topic", "/raw/gyro"]) == 0
    assert gyro.read_text() == "time_local,time_local_ns,gx,gy,gz\n"  # zone unknown
    foreign = tmp_path / "foreign.mcap"
    with open(foreign, "wb") as f:
        w = Writer(f)
        w.start()
        cid = w.register_channel(topic="/metrics/epoch", message_encoding="json", schema_id=0)
        w.add_message(cid, log_time=1, data=b"{}", publish_time=1)
        w.finish()
    capsys.readouterr()
    for dest in ("f.csv", "f.npz"):
        assert cli(["export", str(foreign), "-o", str(tmp_path / dest), "--topic", "/metrics/epoch"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "not a stillpoint log" in err[0] and str(foreign) in err[0]
        assert not list(tmp_path.glob(dest + "*"))


def test_online_kill_loses_only_the_step_in_progress_and_the_open_cell(recording, tmp_path,
                                                                       monkeypatch):
    """Online chunks span up to 60 s but end at every pipeline step, before its last cell: what
    a kill right after a step leaves on disk recovers to every raw message before that cell."""
    import shutil

    from stillpoint.engine.mcap import sink as sink_mod
    from stillpoint.engine.recover import recover
    snaps = []
    real = sink_mod.McapSink.write_slices

    def write_slices(self, block, corrected, epochs):
        real(self, block, corrected, epochs)
        if block is not None and block.n:
            k = len(snaps)
            shutil.copy(self.part, tmp_path / f"kill{k}.mcap.part")  # a SIGKILL here leaves this
            open_cell = int(block.time_ns[-1]) // self.cell_ns * self.cell_ns
            snaps.append((recover(tmp_path / f"kill{k}.mcap.part", tmp_path / f"rec{k}.mcap"), open_cell))

    monkeypatch.setattr(sink_mod.McapSink, "write_slices", write_slices)
    out = tmp_path / "f.mcap"
    s = process_file(recording, out, RunSettings(mode="online", max_block_s=290.0))
    raw_times = np.array([t for t, _d in _messages(out, "/raw/accel")])
    assert len(snaps) >= 12
    for k, (_rep, open_cell) in enumerate(snaps):
        kept = np.array([t for t, _d in _messages(tmp_path / f"rec{k}.mcap", "/raw/accel")])
        want = raw_times[raw_times < open_cell]
        assert kept.shape[0] >= want.shape[0] and np.array_equal(kept[:want.shape[0]], want), k
    with open(out, "rb") as f:
        summ = make_reader(f).get_summary()
    spans = [(c.message_end_time - c.message_start_time) / 1e9 for c in summ.chunk_indexes]
    # 60 s chunks (+ the corrected tail of the cell before, <= one cell), cut at each step too
    assert max(spans) <= 70.0 and max(spans) > 40.0
    assert 3600 / 60 <= len(spans) <= 3600 / 60 + len(snaps) + 2 < 3600 / 10
    assert s["mcap_flushes"] >= len(spans) - 1  # the last chunk ends at close


def test_online_applies_each_accepted_estimate_from_its_boundary(recording, tmp_path):
    out = tmp_path / "on.mcap"
    process_file(recording, out, RunSettings(mode="online", chunk_hours=0.25))
    logged = [json.loads(d) for _t, d in _messages(out, "/calibration")]
    accepted = [CalibrationEstimate.from_dict(e) for e in logged if e["applied"]]
    assert accepted, logged
    assert all(e["effective_from_ns"] is not None for e in logged)
    with open_recording(recording) as src:
        ref = _blocks(src)[0]
    ends = np.append(ref.unit_start[1:], ref.n) - 1
    rel = (ref.time_ns - ref.time_ns[0]).astype(float)
    temp = np.interp(rel, rel[ends], ref.temperature_c)
    raw = ref.accel_g()
    want = raw.copy()  # identity before the first accepted estimate
    for e in accepted:
        sel = ref.time_ns >= e.effective_from_ns
        want[sel] = e.apply(raw[sel], temp[sel])
    t, a = _corrected(out)
    assert np.array_equal(t, ref.time_ns)
    assert np.max(np.abs(a - want)) <= 2.0 ** -17 + 1e-6
    first = accepted[0].effective_from_ns
    assert np.any(ref.time_ns < first) and np.any(ref.time_ns >= first)


def test_demo_command_runs_and_recovers_the_simulated_errors(tmp_path, capsys):
    assert cli(["demo", "--keep", str(tmp_path)]) == 0  # the README's main command, as is
    text = capsys.readouterr().out
    assert "sensor errors" in text
    assert (tmp_path / "demo.mcap").is_file() and (tmp_path / "demo.cwa").is_file()
    m = re.search(r"calibration error: ([\d.]+) mg before -> ([\d.]+) mg after", text)
    assert m and float(m.group(1)) > 20.0 and float(m.group(2)) < 1.0
    m = re.search(r"ENMO mean: uncorrected ([\d.]+) mg \| calibrated ([\d.]+) mg \| with the true "
                  r"parameters ([\d.]+) mg", text)
    raw, cal, true = map(float, m.groups())
    assert cal < raw and abs(cal - true) < 0.01 * true  # calibration removes the ENMO inflation


def test_store_feeds_the_online_prior_and_is_recorded(recording, tmp_path, capsys):
    store = tmp_path / "store"
    a = tmp_path / "a.mcap"
    assert cli(["process", str(recording), "-o", str(a), "-q", "--store", str(store)]) == 0
    from stillpoint.engine.calibration import CalibrationStore
    st = CalibrationStore(store)
    [key] = st.devices()
    stored = st.latest(key)
    assert stored is not None and stored.status == "ok"
    b = tmp_path / "b.mcap"
    assert cli(["process", str(recording), "-o", str(b), "-q", "--mode", "online", "--chunk-hours",
                "100", "--store", str(store), "--summary", str(tmp_path / "s.json")]) == 0
    with open(b, "rb") as f:
        meta = {m.name: m.metadata for m in make_reader(f).iter_metadata()}
    prior = json.loads(meta["settings"]["json"])["prior"]
    assert np.allclose(prior["offset"], stored.offset)
    # no refit within 100 h: the stored prior corrects the whole stream
    s = json.loads((tmp_path / "s.json").read_text())
    assert np.allclose(s["calibration"]["offset"], stored.offset)
    # the replay needs no store: the prior travels in the settings record
    c = tmp_path / "c.mcap"
    assert cli(["replay", str(b), "-o", str(c), "-q", "--check"]) == 0


def test_progress_plain_lines_off_a_terminal_and_silent_when_disabled():
    import io
    from stillpoint.engine.core.pipeline import PipelineStats
    from stillpoint.tools.cli.commands._runopts import Progress
    buf = io.StringIO()
    Progress(enabled=False, stream=buf)("pass 1/2", PipelineStats(samples=10, first_ns=0,
                                                                  last_ns=3600 * 10**9, fraction=1.0))
    assert buf.getvalue() == ""  # -q
    p = Progress(stream=buf)  # StringIO is not a terminal: plain lines
    p("pass 2/2", PipelineStats(samples=10, first_ns=0, last_ns=7200 * 10**9, fraction=0.5))
    out = buf.getvalue()
    # half of the second pass is 60 % of a batch run (engine/progress.py BATCH_PASS_SPANS)
    assert out.startswith("process:  60.0 %") and "pass 2/2" in out and "2.0 h" in out
    assert "\r" not in out and out.endswith("\n")


def test_empty_recording_and_bad_output_path(tmp_path, capsys):
    from stillpoint.drivers.cwa import CwaWriter
    empty = tmp_path / "empty.cwa"
    CwaWriter(empty).close()
    for mode in ("batch", "online"):
        s = process_file(empty, tmp_path / f"e_{mode}.mcap", RunSettings(mode=mode))
        assert s["samples"] == 0 and s["epochs"] == 0 and s["enmo_mean_mg"] is None
    assert cli(["process", str(empty), "-o", str(tmp_path / "no" / "such" / "dir.mcap")]) == 2
    assert "does not exist" in capsys.readouterr().err


def test_output_on_a_named_pipe_refused_with_one_line(recording, tmp_path, capsys):
    """`process -o` naming a device or pipe (/dev/null, a FIFO): exit 2, one line naming it,
    the pipe left as it was and no table written beside it."""
    import stat
    fifo = tmp_path / "out.mcap"
    os.mkfifo(fifo)
    assert cli(["process", str(recording), "-o", str(fifo)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(fifo) in err[0] and "a pipe" in err[0]
    assert "Traceback" not in err[0]
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.mcap"]


def _job(args):
    src, out = args
    return process_file(src, out, RunSettings(mode="online"))["samples"]


def test_per_file_job_runs_inside_a_process_pool(recording, tmp_path):
    """Cohort use: the job is a pure function run by pool workers (daemonic processes)."""
    import multiprocessing as mp
    with mp.get_context("spawn").Pool(2) as pool:
        n = pool.map(_job, [(str(recording), str(tmp_path / f"p{i}.mcap")) for i in range(2)])
    assert n[0] == n[1] > 0
    assert compare(tmp_path / "p0.mcap", tmp_path / "p1.mcap")["/corrected/accel"]["identical"]
