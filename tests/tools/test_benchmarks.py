"""The speed benchmarks' own pieces: the realistic recording they run on first is exactly
``stillpoint simulate``'s output with the default wearer, and the per-stage profiler times stages
that exist and accounts for the run's CPU without double counting."""

from __future__ import annotations

import importlib
import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

TOOLS = Path(__file__).resolve().parents[2] / "tools" / "benchmarks"


def _load(path: Path, name: str):
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture()
def benchlib(monkeypatch):
    monkeypatch.syspath_prepend(str(TOOLS))
    return _load(TOOLS / "benchlib.py", "benchlib")


@pytest.fixture()
def stage_profile():
    return _load(TOOLS / "stage_profile.py", "stage_profile")


def test_realistic_recording_is_the_simulate_command_output_and_is_reused(benchlib, tmp_path):
    p = benchlib.realistic_recording(tmp_path, 0.01, 100.0)
    assert p.name == "wear_0.01d_100hz_s3.cwa"
    cli = tmp_path / "cli.cwa"
    subprocess.run([sys.executable, "-m", "stillpoint.tools", "simulate", "-o", str(cli), "--days",
                    "0.01", "--hz", "100", "--seed", "3"], check=True, capture_output=True)
    assert cli.read_bytes() == p.read_bytes()
    assert p.with_suffix(".truth.json").is_file() and p.with_suffix(".labels.csv").is_file()
    before = p.stat().st_mtime_ns
    assert benchlib.realistic_recording(tmp_path, 0.01, 100.0) == p
    assert p.stat().st_mtime_ns == before  # written once, then reused
    assert not list(tmp_path.glob("*.part*"))


def test_real_recordings_lists_recordings_only(benchlib, tmp_path, monkeypatch):
    for name in ("a.cwa", "b.cwa.gz", "c.bin", "PROVENANCE.md", "d.csv"):
        (tmp_path / name).write_bytes(b"x")
    monkeypatch.setenv("STILLPOINT_REAL_DATA", str(tmp_path))
    assert [p.name for p in benchlib.real_recordings()] == ["a.cwa", "b.cwa.gz", "c.bin"]
    monkeypatch.delenv("STILLPOINT_REAL_DATA")
    assert benchlib.real_recordings() == []


def test_profiled_stages_exist(stage_profile):
    for _label, mod, cls, attr in stage_profile.MAIN_STAGES:
        owner = importlib.import_module(mod)
        if cls:
            owner = getattr(owner, cls)
        assert callable(getattr(owner, attr)), (mod, cls, attr)


def test_stage_profile_accounts_for_the_run(stage_profile, benchlib, tmp_path):
    p = benchlib.realistic_recording(tmp_path, 0.02, 100.0)
    r = subprocess.run([sys.executable, str(TOOLS / "stage_profile.py"), "--child",
                        str(p), "batch", "600"], check=True, capture_output=True, text=True)
    import json
    res = json.loads(r.stdout)
    st = res["stages"]
    for label in ("MCAP framing of a step", "correction (affine, temperature, quantisation)",
                  "BFEN band-pass (sosfilt)", "tables: anglez", "tables: CSV rows + gzip", "zstd"):
        assert st.get(label, 0.0) > 0.0, label
    main_stages = sum(v for k, v in st.items() if k != "zstd")
    # exclusive times: the main thread's stages never add up to more than the main thread's CPU
    assert main_stages <= res["main"] + 1e-3
    assert res["threads"].get("mcap-writer", 0.0) >= st["zstd"] - 1e-3
    assert res["main"] + sum(res["threads"].values()) <= res["cpu"] + 0.05


def test_realistic_recording_of_the_still_wearer_is_the_simulate_command_output(benchlib, tmp_path):
    p = benchlib.realistic_recording(tmp_path, 0.01, 25.0, wearer="still")
    assert p.name == "wear_still_0.01d_25hz_s3.cwa"
    cli = tmp_path / "cli.cwa"
    subprocess.run([sys.executable, "-m", "stillpoint.tools", "simulate", "-o", str(cli), "--days",
                    "0.01", "--hz", "25", "--seed", "3", "--wearer", "still"], check=True,
                   capture_output=True)
    assert cli.read_bytes() == p.read_bytes()
    assert benchlib.realistic_recording(tmp_path, 0.01, 25.0) != p  # the default wearer's own


def test_bench_targets_runs_every_command_on_both_wearers_and_prints_the_ratios(tmp_path):
    r = subprocess.run([sys.executable, str(TOOLS / "bench_targets.py"), "--days", "0.02",
                        "--rate", "25", "--repeat", "1", "--online-days", "0.01",
                        "--workdir", str(tmp_path), "--skdh", "none", "--actipy", "none"],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    out = r.stdout
    assert "skdh skipped" in out and "actipy skipped" in out
    rows = {line.split(" | ")[0].strip(): line.split(" | ")[1:] for line in out.splitlines()
            if " | " in line}
    for label in ("plain decode (reader, whole file)", "process --mode batch (full log)",
                  "process --mode batch --log lean", "process --mode online (full log)",
                  "process --mode online --no-tables"):
        cells = rows[label]
        assert len(cells) == 2, label  # default and still wearer
        for c in cells:
            wall, cpu, rss = (float(x) for x in c.split())
            assert wall > 0 and cpu > 0 and rss > 10
    assert [c.strip() for c in rows["skdh read + autocalibration + ENMO"]] == ["skipped"] * 2
    assert all("x (<= 1.1x: " in c for c in rows["online / batch, CPU (0.02 days)"])
    assert all("x (<= 1.1x: " in c for c in rows["online / batch, CPU (0.01 days)"])
    assert all(c.strip() == "n/a" for c in rows["skdh / full, wall"])
    assert all("MB (< 300 MB: met)" in c for c in rows["peak RSS of process, every run"])
    assert all(int(c) >= 1 for c in rows["online estimates published"])
    assert not [p for p in tmp_path.iterdir() if p.name.startswith("bt_")]  # outputs removed


def test_bench_refits_replays_the_calibrator_with_and_without_the_fit_set(tmp_path):
    r = subprocess.run([sys.executable, str(TOOLS / "bench_refits.py"), "--days", "0.6",
                        "--rate", "12.5", "--repeat", "1", "--per-cell", "2", "--wearers",
                        "still", "--workdir", str(tmp_path)],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    out = r.stdout
    assert "still wearer, 0.6 days" in out and "fit set (2 a cell)" in out
    diffs = [float(x) for x in out.split("every window| max per estimate (mg):")[1]
             .splitlines()[0].split()]
    assert len(diffs) >= 2 and max(diffs) < 5.0 and diffs[-1] < 1e-2  # the last: every window


def test_bench_tables_pass_runs_each_step_and_checks_the_tables_are_the_same(tmp_path):
    """The tables' own pass at a step of the output passes' size and at a far smaller one (other
    block cuts): both rows printed, and the script's own check that every step wrote the same
    tables, byte for byte, says yes."""
    r = subprocess.run([sys.executable, str(TOOLS / "bench_tables_pass.py"), "--days", "0.05",
                        "--steps", "500:600,7:30", "--repeat", "1", "--workdir", str(tmp_path)],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout + r.stderr
    rows = [line for line in r.stdout.splitlines() if " | " in line and "x" in line.split("|")[-1]]
    assert [line.split("|")[0].strip() for line in rows] == ["500 : 600", "7 : 30"]
    assert "tables the same at every step: yes" in r.stdout
