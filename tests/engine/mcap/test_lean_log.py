"""A lean log (``process --log lean``): no per-sample topics, everything else as the full log;
``replay LEAN --raw RECORDING --log full`` gives the full run's log and tables bit for bit; the
commands that need the raw samples say so in one line (exit 2)."""

from __future__ import annotations

import gzip
import json

import pytest

from stillpoint.engine.mcap.compare import compare
from stillpoint.engine.mcap.sink import LEAN_DROPPED
from stillpoint.engine.mcap.stream import read_metadata
from stillpoint.engine.sim.record import simulate_recording
from stillpoint.tools.cli import main

ZONE = ["--timezone", "Europe/London"]  # sleep and nights on: the /sleep topics are compared too


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    d = tmp_path_factory.mktemp("lean")
    cwa = d / "p7.cwa"
    simulate_recording(cwa, days=1.5, hz=25.0, seed=7, truth_path=False, labels_path=False)
    full, lean = d / "full.mcap", d / "lean.mcap"
    assert main(["process", str(cwa), "-o", str(full), "-q", *ZONE]) == 0
    assert main(["process", str(cwa), "-o", str(lean), "--log", "lean", "-q", *ZONE]) == 0
    return d, cwa, full, lean


def _meta(mcap) -> dict:
    with open(mcap, "rb") as f:
        return read_metadata(f)


def _tables(d, stem) -> dict:
    out = {}
    for suffix in ("epochs.csv.gz", "days.csv", "nights.csv"):
        p = d / f"{stem}.{suffix}"
        out[suffix] = gzip.decompress(p.read_bytes()) if suffix.endswith(".gz") else p.read_bytes()
    return out


def test_lean_log_keeps_everything_but_the_per_sample_streams(runs):
    d, _cwa, full, lean = runs
    res = compare(full, lean)
    for topic, r in res.items():
        if topic in LEAN_DROPPED:
            assert r["messages"][0] > 0 and r["messages"][1] == 0, (topic, r)
        else:
            assert r["identical"] and r["messages"][0] > 0, (topic, r)
    for topic in ("/metrics/epoch", "/view/accel", "/calibration", "/qc", "/sleep/night"):
        assert topic in res
    assert json.loads(_meta(lean)["settings"]["json"])["log"] == "lean"
    assert "log" not in json.loads(_meta(full)["settings"]["json"])  # full logs as before
    assert _meta(lean)["calibration"] == _meta(full)["calibration"]
    assert _tables(d, "lean") == _tables(d, "full")
    assert lean.stat().st_size * 2 < full.stat().st_size  # 25 Hz: the 1 Hz view stream is most of it


def test_replay_of_a_lean_log_with_the_recording_is_the_full_run(runs, capsys):
    d, cwa, full, lean = runs
    out = d / "rebuilt.mcap"
    assert main(["replay", str(lean), "--raw", str(cwa), "--log", "full", "-o", str(out),
                 "-q"]) == 0
    res = compare(full, out)
    assert all(r["identical"] for r in res.values()), res
    assert set(res) >= set(LEAN_DROPPED) - {"/raw/gyro"}
    a, b = _meta(full), _meta(out)
    for name in ("device", "settings", "calibration", "clock"):
        assert a[name] == b[name], name
    sa, sb = (json.loads(m["summary"]["json"]) if "json" in m["summary"] else dict(m["summary"])
              for m in (a, b))
    sa.pop("outputs"), sb.pop("outputs")
    # the tables' entry names the tables written (beside each log): the same but for the stem
    assert {k: str(v).replace(str(d / "full."), str(d / "rebuilt.")) for k, v in sa.items()} \
        == {k: str(v) for k, v in sb.items()}
    assert _tables(d, "rebuilt") == _tables(d, "full")
    # the lean log replayed as logged (lean) reproduces itself: --check exits 0
    capsys.readouterr()
    code = main(["replay", str(lean), "--raw", str(cwa), "-o", str(d / "again.mcap"), "--check",
                 "-q"])
    assert code == 0, capsys.readouterr().out


def _one_line_exit_2(capsys, argv, *words):
    capsys.readouterr()
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    for w in words:
        assert w in err, err


def test_what_a_lean_log_lacks_is_said_in_one_line(runs, capsys, tmp_path):
    d, cwa, _full, lean = runs
    _one_line_exit_2(capsys, ["replay", str(lean), "-o", str(tmp_path / "r.mcap"), "-q"],
                     "lean log", "--raw")
    _one_line_exit_2(capsys, ["process", str(lean), "-o", str(tmp_path / "p.mcap"), "-q"],
                     "lean log")
    _one_line_exit_2(capsys, ["export", str(lean), "-o", str(tmp_path / "c.csv"),
                              "--topic", "/corrected/accel"], "lean log", "/corrected/accel")
    _one_line_exit_2(capsys, ["export", str(lean), "-o", str(tmp_path / "e.csv.gz"),
                              "--table", "epochs"], "lean log")
    _one_line_exit_2(capsys, ["process", str(cwa), "-o", str(tmp_path / "q.mcap"), "--log", "lean",
                              "--report", "-q"], "--report", "lean")
    assert not (tmp_path / "q.mcap").exists()
    # what it has is exported: the epoch metrics (the CSV default) and the NPZ defaults it keeps
    assert main(["export", str(lean), "-o", str(tmp_path / "m.csv"), "--topic", "/metrics/epoch"]) == 0
    assert len((tmp_path / "m.csv").read_text().splitlines()) > 1000
    assert main(["export", str(lean), "-o", str(tmp_path / "m.npz"), "--topic", "/metrics/epoch"]) == 0
    import numpy as np
    with np.load(tmp_path / "m.npz") as z:
        assert "metrics/epoch/enmo" in "".join(z.files) or any("metrics" in f for f in z.files)
        assert not any("corrected" in f for f in z.files)
    assert main(["view", str(lean), "--layout-only"]) == 0


def test_replay_refuses_another_recording(runs, capsys, tmp_path):
    _d, _cwa, _full, lean = runs
    other = tmp_path / "other.cwa"
    simulate_recording(other, days=0.05, hz=25.0, seed=8, device_id=4321, truth_path=False,
                       labels_path=False)
    _one_line_exit_2(capsys, ["replay", str(lean), "--raw", str(other), "-o",
                              str(tmp_path / "x.mcap"), "-q"], "is not the recording")


def test_cohort_run_writes_lean_logs(tmp_path):
    src = tmp_path / "in"
    src.mkdir()
    simulate_recording(src / "a.cwa", days=0.3, hz=25.0, seed=2, truth_path=False,
                       labels_path=False)
    assert main(["cohort", "run", str(src), "-o", str(tmp_path / "out"), "--log", "lean", "-q"]) == 0
    [log] = list((tmp_path / "out").rglob("*.mcap"))
    assert json.loads(_meta(log)["settings"]["json"])["log"] == "lean"
    from stillpoint.engine.mcap.compare import topic_digests
    topics = set(topic_digests(log))
    assert "/metrics/epoch" in topics and not topics & set(LEAN_DROPPED), topics
