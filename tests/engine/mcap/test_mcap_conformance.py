"""Every MCAP the project writes follows the MCAP specification: checked by a layout parser
written against the specification (tests/mcap_layout.py) and by the mcap package's indexed
reader. Also: nothing is logged before the first sample (online prior), the view topic has one
message per sample at the asked rate, JSON topics carry JSON schemas, and replay of a log
written with the view topic reproduces it. (align -o: tests/engine/alignment/test_align_apply_cli.py; a
recovered SIGKILLed run: tests/engine/mcap/test_mcap_recover.py.)"""

from __future__ import annotations

import json
import os
import signal
import time

import numpy as np
import pytest
from mcap.reader import make_reader

from mcap_layout import conforms
from stillpoint.engine.calibration.estimate import CalibrationEstimate
from stillpoint.engine.mcap.schemas import VIEW_SAMPLE
from stillpoint.engine.mcap.view import TOPIC_VIEW
from stillpoint.engine.recover import recover
from stillpoint.engine.run import RunSettings, process_file
from stillpoint.tools.cli import main as cli
from synthetic_recording import make_recording


@pytest.fixture(scope="module")
def rec(tmp_path_factory):
    d = tmp_path_factory.mktemp("conf")
    p = d / "rec.cwa"
    make_recording(p, hours=1.0, rate=50.0, seed=3)
    return p


def _first_sample_ns(path) -> int:
    from stillpoint.drivers import open_recording
    with open_recording(path) as src:
        return int(next(iter(src)).time_ns[0])


def test_process_batch_replay_and_recover_conform(rec, tmp_path):
    out = tmp_path / "b.mcap"
    assert cli(["process", str(rec), "-o", str(out), "-q"]) == 0
    rep = conforms(out)
    assert 3600 / 60 - 2 <= rep["chunks"] <= 3600 / 60 + 3  # batch: 60 s chunks of 10 s cells
    assert rep["channel_schema"]["/calibration"] == "stillpoint.CalibrationEstimate"
    assert rep["channel_schema"]["/qc"] == "stillpoint.QcEvent"
    assert rep["schemas"]["stillpoint.CalibrationEstimate"] == "jsonschema"
    assert rep["schemas"][VIEW_SAMPLE.name] == "ros2msg"
    assert not (tmp_path / "b.mcap.part").exists()
    # replay writes through the same path, and reproduces every topic
    again = tmp_path / "b2.mcap"
    assert cli(["replay", str(out), "-o", str(again), "--check", "-q"]) == 0
    assert conforms(again)["topics"] == rep["topics"]
    # a torn copy recovers into a conforming file
    data = out.read_bytes()
    torn = tmp_path / "t.mcap.part"
    torn.write_bytes(data[:len(data) // 2])
    r = recover(torn, tmp_path / "t.recovered.mcap")
    assert r.messages > 0 and r.stopped_at
    got = conforms(tmp_path / "t.recovered.mcap")
    assert 0 < got["messages"] < rep["messages"]
    # nothing before the first sample
    t0 = _first_sample_ns(rec)
    with open(out, "rb") as f:
        st = make_reader(f).get_summary().statistics
    assert st.message_start_time == t0


def test_online_prior_is_logged_at_the_first_sample(rec, tmp_path):
    prior = CalibrationEstimate(offset=np.array([0.01, -0.02, 0.03]), scale=np.ones(3),
                                status="ok", method="autocal-c1", fit_start_ns=10**18,
                                fit_end_ns=10**18 + 3600 * 10**9)
    out = tmp_path / "o.mcap"
    process_file(rec, out, RunSettings(mode="online", prior=prior.to_dict()))
    conforms(out)
    t0 = _first_sample_ns(rec)
    with open(out, "rb") as f:
        r = make_reader(f)
        assert r.get_summary().statistics.message_start_time == t0
        cal = [(m.log_time, json.loads(m.data)) for _s, _c, m in r.iter_messages(topics=["/calibration"])]
    assert cal[0][0] == t0 and cal[0][1]["prior"] is True
    assert cal[0][1]["fitted_at_ns"] == prior.fit_end_ns  # when it was fitted, kept apart
    assert cal[0][1]["offset"] == pytest.approx([0.01, -0.02, 0.03])


@pytest.mark.parametrize("hz", [0.0, 4.0])
def test_view_topic_one_message_per_sample_at_the_asked_rate(rec, tmp_path, hz):
    out = tmp_path / "v.mcap"
    process_file(rec, out, RunSettings(view_hz=hz))
    rep = conforms(out)
    if hz == 0:
        assert TOPIC_VIEW not in rep["topics"]
        return
    with open(out, "rb") as f:
        msgs = [(m.log_time, VIEW_SAMPLE.decode(m.data))
                for _s, _c, m in make_reader(f).iter_messages(topics=[TOPIC_VIEW])]
    t = np.array([lt for lt, _ in msgs])
    period = int(1e9 / hz)
    # one message per period of the UTC grid, each the first sample of its period
    assert np.all(np.diff(t // period) >= 1)
    assert abs(len(t) - 3600 * hz) <= 2
    for lt, d in msgs[:50]:
        assert d["stamp"] == lt
        n = np.sqrt(np.float32(d["x"]) ** 2 + np.float32(d["y"]) ** 2 + np.float32(d["z"]) ** 2)
        assert d["norm"] == pytest.approx(float(n), rel=1e-6)
    # the view values are the corrected stream's own samples
    from stillpoint.engine.mcap.export import _rows
    with open(out, "rb") as f:
        _s, _c, m = next(make_reader(f).iter_messages(topics=["/corrected/accel"]))
    cor = _rows("/corrected/accel", m.data, m.log_time)
    k = np.searchsorted(cor["time_ns"], t[0])
    assert cor["time_ns"][k] == t[0] and cor["x"][k] == np.float32(msgs[0][1]["x"])


def test_interrupt_while_the_command_loads_is_one_line(tmp_path, capsys, monkeypatch):
    """A Ctrl-C while the command's modules import (before any run starts): exit 130 and one
    line, no traceback."""
    import stillpoint.tools.cli as cli_mod

    # a fresh process starts with Python's own SIGINT handler; an earlier test in the same process
    # (a Dask cluster, a station) may have left another one, which the command leaves alone
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        _interrupt_while_loading(cli_mod, tmp_path, capsys, monkeypatch)
    finally:
        signal.signal(signal.SIGINT, previous)


def _interrupt_while_loading(cli_mod, tmp_path, capsys, monkeypatch):

    def interrupt(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(cli_mod, "build_parser", interrupt)
    assert cli(["process", str(tmp_path / "x.cwa"), "-o", str(tmp_path / "x.mcap")]) == 130
    err = capsys.readouterr().err
    assert err == "stillpoint: interrupted\n"

    def converted(*a, **k):  # an extension's initialisation turns the interrupt into ImportError
        try:
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(5)  # the handler raises here
        except KeyboardInterrupt:
            raise ImportError("PyCapsule_Import could not import module \"datetime\"") from None
        raise AssertionError("no SIGINT arrived")

    monkeypatch.setattr(cli_mod, "build_parser", converted)
    assert cli(["process", str(tmp_path / "x.cwa"), "-o", str(tmp_path / "x.mcap")]) == 130
    assert capsys.readouterr().err == "stillpoint: interrupted\n"
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # given back

    def missing(*a, **k):  # an ImportError without an interrupt is not an interruption
        raise ImportError("No module named 'nothing'")

    monkeypatch.setattr(cli_mod, "build_parser", missing)
    with pytest.raises(ImportError):
        cli(["process", str(tmp_path / "x.cwa"), "-o", str(tmp_path / "x.mcap")])


def test_interrupt_while_the_command_line_imports_is_one_line(capsys, monkeypatch):
    """The `stillpoint` entry point: a Ctrl-C while stillpoint.tools.cli itself is imported."""
    import sys
    import types

    import stillpoint

    class Loading(types.ModuleType):
        def __getattr__(self, name):
            raise KeyboardInterrupt

    monkeypatch.setitem(sys.modules, "stillpoint.tools.cli", Loading("stillpoint.tools.cli"))
    assert stillpoint.main() == 130
    assert capsys.readouterr().err == "stillpoint: interrupted\n"


def test_interrupted_run_names_its_partial_file(rec, tmp_path, capsys, monkeypatch):
    """An interrupt mid-run leaves OUT.mcap.part (never OUT.mcap) and says how to salvage it."""
    from stillpoint.engine.mcap import sink as sink_mod
    calls = {"n": 0}
    orig = sink_mod.McapSink.write_slices

    def interrupt(self, *a, **k):
        calls["n"] += 1
        if calls["n"] == 3:
            raise KeyboardInterrupt
        return orig(self, *a, **k)

    monkeypatch.setattr(sink_mod.McapSink, "write_slices", interrupt)
    out = tmp_path / "i.mcap"
    assert cli(["process", str(rec), "-o", str(out), "-q"]) == 130
    err = capsys.readouterr().err
    part = tmp_path / "i.mcap.part"
    assert not out.exists() and part.exists()
    assert f"stillpoint recover {part}" in err
    monkeypatch.undo()
    assert cli(["recover", str(part)]) == 0
    conforms(tmp_path / "i.recovered.mcap")


def test_foxglove_layout_names_fields_the_log_has(rec, tmp_path):
    """docs/foxglove_layout.json: every plotted path is a numeric field of a logged topic's
    schema, every Raw Messages panel a logged topic; it is the layout generated from the log's
    topics (engine/live/layouts.py; `stillpoint view LOG --layout-only` writes it)."""
    from pathlib import Path

    from stillpoint.engine.mcap.schemas import ALL_TYPES
    layout = json.loads((Path(__file__).resolve().parents[3] / "docs" / "foxglove_layout.json")
                        .read_text())
    out = tmp_path / "l.mcap"
    process_file(rec, out, RunSettings())
    with open(out, "rb") as f:
        summ = make_reader(f).get_summary()
    schema_of = {c.topic: summ.schemas[c.schema_id].name for c in summ.channels.values() if c.schema_id}
    fields = {t.name: {f for f, kind in t.fields if kind not in ("time",) and not kind.endswith("]")}
              for t in ALL_TYPES}
    plotted = raw = 0
    for pid, cfg in layout["configById"].items():
        if pid.startswith("Plot!"):
            for p in cfg["paths"]:
                topic, field = p["value"].rsplit(".", 1)
                assert field in fields[schema_of[topic]], p["value"]
                plotted += 1
        elif pid.startswith("RawMessages!"):
            assert cfg["topicPath"] in schema_of
            raw += 1
    assert plotted >= 6 and raw >= 2
    from stillpoint.engine.live.layouts import recording_layout
    from stillpoint.engine.mcap.stream import read_channels
    with open(out, "rb") as f:
        assert layout == recording_layout(read_channels(f))


def test_public_log_api_writes_json_estimates_atomically(tmp_path):
    """McapLog: JSON estimates with their schema, the file appears only when finished, a second
    writer is refused, an aborted log stays as .part and recovers."""
    from stillpoint.engine.core.outputs import OutputError
    from stillpoint.engine.mcap import STATIC_CALIBRATION, McapLog
    out = tmp_path / "s.mcap"
    t0 = 1_700_000_000 * 10**9
    with McapLog(out) as log:
        with pytest.raises(OutputError, match="another stillpoint run"):
            McapLog(out)
        for k in range(3):
            log.write_json("/static_calibration", t0 + k, {"offset": [0.01 * k, 0, 0],
                                                          "scale": [1, 1, 1], "status": "ok"},
                           schema=STATIC_CALIBRATION)
        log.write_metadata("device", {"id": "1234"})
        assert not out.exists() and (tmp_path / "s.mcap.part").exists()
    rep = conforms(out)
    assert rep["topics"] == {"/static_calibration": 3}
    assert rep["channel_schema"]["/static_calibration"] == STATIC_CALIBRATION.name
    log = McapLog(tmp_path / "a.mcap", chunk_size=1)
    log.write_json("/x", t0, {"a": 1})
    part = log.abort()
    assert part == tmp_path / "a.mcap.part" and not (tmp_path / "a.mcap").exists()
    rep2 = recover(part, tmp_path / "a.recovered.mcap")
    assert rep2.messages == 1 and conforms(tmp_path / "a.recovered.mcap")["messages"] == 1


def test_view_topic_does_not_depend_on_block_cuts(rec, tmp_path):
    """Small pipeline blocks (several corrected batches per step) give the same view messages."""
    from stillpoint.engine.mcap.compare import compare
    a, b = tmp_path / "a.mcap", tmp_path / "b.mcap"
    process_file(rec, a, RunSettings(view_hz=5.0))
    process_file(rec, b, RunSettings(view_hz=5.0, max_block_s=7.0))
    res = compare(a, b, topics=("/view/accel", "/corrected/accel", "/metrics/epoch"))
    assert all(r["identical"] for r in res.values()), res
    assert res["/view/accel"]["messages"][0] >= 3600 * 5 - 2


def test_replay_of_a_damaged_chunk_is_one_line_exit_2(rec, tmp_path, capsys):
    out = tmp_path / "d.mcap"
    process_file(rec, out, RunSettings(view_hz=0, compression="none"))
    buf = bytearray(out.read_bytes())
    mid = len(buf) // 3
    buf[mid:mid + 64] = bytes(64)  # zero a stretch of a chunk: its CRC no longer matches
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(buf))
    assert cli(["replay", str(bad), "-o", str(tmp_path / "r.mcap"), "-q"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "bad.mcap" in err[0]


def test_a_killed_runs_partial_log_is_kept_aside(rec, tmp_path):
    out = tmp_path / "k.mcap"
    (tmp_path / "k.mcap.part").write_bytes(b"\x89MCAP0\r\n left by a killed run")
    s = process_file(rec, out, RunSettings(view_hz=0))
    kept = s["outputs"]["earlier_partial_log"]
    assert kept.startswith(str(tmp_path / "k.mcap.part.")) and open(kept, "rb").read().endswith(b"run")
    conforms(out)


def test_replay_keeps_reader_events_where_the_run_logged_them(tmp_path):
    """A truncated GENEActiv file: the reader's events at the end of the file have no time of
    their own and are pinned to the data time they were logged at. Replay joins raw messages
    into larger blocks, yet logs every reader event where the run did (replay --check compares
    every topic, /qc included)."""
    from stillpoint.engine.sim import simulate_recording
    p = tmp_path / "g.bin"
    simulate_recording(p, device="geneactiv", days=0.05, hz=25, seed=4, truth_path=False)
    data = p.read_bytes()
    p.write_bytes(data[:len(data) - 1500])  # the last page torn
    out = tmp_path / "g.mcap"
    s = process_file(p, out, RunSettings(mode="online"))
    assert s["qc"].get("events", 0) >= 1
    assert cli(["replay", str(out), "-o", str(tmp_path / "g2.mcap"), "--check", "-q"]) == 0
