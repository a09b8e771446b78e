"""Cohort runs: a folder of short simulated recordings plus a corrupt and an unreadable file, on
the default process pool of 2 workers; resume after SIGKILL of the whole run; a worker killed
mid-task, on the process pool and on a real Dask LocalCluster; the scheduler chosen when none is
named; new keys for new settings; shards that cover the plan exactly once."""

from __future__ import annotations

import csv
import hashlib
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from stillpoint.engine.cohort import collate, discover_inputs, make_plan, run_cohort, status
from stillpoint.engine.cohort.job import DONE, FAILED, RUNNING
from stillpoint.engine.cohort.plan import read_plan
from stillpoint.engine.run import RunSettings
from stillpoint.engine.sim import simulate_recording
from stillpoint.tools.cli import main as cli

pytest.importorskip("distributed", reason="the cohort tests need the test extra (dask, distributed)")

N_GOOD = 8


def _sim(path: Path, seed: int, days: float = 0.04, device: str = "ax3") -> None:
    simulate_recording(path, device=device, days=days, hz=25, seed=seed, truth_path=False,
                       labels_path=False)


@pytest.fixture(scope="module")
def cohort_dir(tmp_path_factory) -> Path:
    """8 good recordings (one GENEActiv, one gzipped, one in a sub-folder), a corrupt one (header
    overwritten), an unreadable one (a broken link: the file vanished) and a non-recording."""
    d = tmp_path_factory.mktemp("cohort_in")
    (d / "site2").mkdir()
    for i in range(N_GOOD - 2):
        _sim(d / ("site2" if i == 0 else ".") / f"p{i:02d}.cwa", seed=10 + i)
    _sim(d / "g07.bin", seed=7, device="geneactiv")
    import gzip
    _sim(d / "z08.cwa", seed=8)
    with open(d / "z08.cwa", "rb") as f, gzip.open(d / "z08.cwa.gz", "wb") as g:
        g.write(f.read())
    (d / "z08.cwa").unlink()
    b = bytearray((d / "p01.cwa").read_bytes())
    b[:1024] = b"\x00" * 1024
    (d / "corrupt.cwa").write_bytes(bytes(b))
    os.symlink(d / "no-such-file.cwa", d / "vanished.cwa")
    (d / "notes.txt").write_text("not a recording")
    return d


def _markers(out: Path, name: str) -> dict:
    """Markers of finished folders (a ``.tmp`` folder may hold a _DONE.json not yet renamed)."""
    return {p.parent.name: p for p in (out / "files").glob(f"*/*/{name}")
            if not p.parent.name.endswith(".tmp")}


def _output_hashes(out: Path) -> dict:
    res = {}
    for m in _markers(out, DONE).values():
        for f in ("recording.mcap", "summary.json"):
            res[f"{m.parent.name}/{f}"] = hashlib.sha256((m.parent / f).read_bytes()).hexdigest()
    return res


def test_folder_with_bad_files_on_the_default_pool(cohort_dir, tmp_path, capsys):
    out = tmp_path / "out"
    # exit 1: some files failed (the failure table lists them), the others are done
    assert cli(["cohort", "run", str(cohort_dir), "-o", str(out), "-j", "2"]) == 1
    err = capsys.readouterr().err
    assert "on processes (2 worker(s))" in err
    assert "FAILED" in err and "corrupt.cwa (corrupt_input)" in err
    assert len(_markers(out, DONE)) == N_GOOD
    rows = list(csv.DictReader(open(out / "cohort_summary.csv")))
    fails = {Path(r["file"]).name: r for r in csv.DictReader(open(out / "cohort_failures.csv"))}
    assert len(rows) == N_GOOD and set(fails) == {"corrupt.cwa", "vanished.cwa"}
    assert fails["corrupt.cwa"]["class"] == "corrupt_input" and "not a recognised" in fails["corrupt.cwa"]["error"]
    assert fails["vanished.cwa"]["class"] == "corrupt_input" and "no such file" in fails["vanished.cwa"]["error"]
    by = {Path(r["file"]).name: r for r in rows}
    assert by["g07.bin"]["device_type"] == "GENEActiv" and by["z08.cwa.gz"]["device_type"] == "AX3"
    r = by["p00.cwa"]
    assert int(r["samples"]) > 80_000 and 0.9 < float(r["duration_h"]) < 1.0
    assert r["calibration_status"] and r["qc_total"] == r["qc_valid"] and float(r["enmo_mean_mg"]) > 0
    assert Path(r["mcap"]).is_file()
    # a .cwa without a zone: its start is the device clock, never in a UTC column
    assert r["start_utc"] == "" and r["start_local"] and not r["start_local"].endswith("Z")
    assert by["g07.bin"]["start_utc"].endswith("Z")  # GENEActiv: the header's zone
    # a rerun does nothing; --strict (the default now) still exits 1
    assert cli(["cohort", "run", str(cohort_dir), "-o", str(out), "--strict", "-q"]) == 1
    assert "0 done now, 8 already done" in capsys.readouterr().err
    st = status(out)
    assert (st.done, st.failed, st.pending) == (N_GOOD, {"corrupt_input": 2}, 0)
    # an output that went bad goes to the failure table; the collation goes on
    victim = Path(by["p02.cwa"]["summary"])
    victim.write_text("{ not json")
    col = collate(out)
    assert len(col.rows) == N_GOOD - 1
    bad = [f for f in col.failures if f["class"] == "unreadable_output"]
    assert len(bad) == 1 and bad[0]["file"].endswith("p02.cwa")
    assert cli(["cohort", "status", str(out)]) == 0
    assert "corrupt_input 2" in capsys.readouterr().out


def test_resume_after_sigkill_of_the_whole_run(cohort_dir, tmp_path):
    out = tmp_path / "out"
    reference = run_cohort(make_plan(discover_inputs([cohort_dir]), RunSettings()), out,
                           scheduler="serial", progress=False)
    assert reference.done == N_GOOD
    want = _output_hashes(out)
    import shutil
    shutil.rmtree(out)
    cmd = [sys.executable, "-m", "stillpoint.tools", "cohort", "run", str(cohort_dir), "-o", str(out),
           "-j", "2", "--max-in-flight", "2", "-q"]
    p = subprocess.Popen(cmd, start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 60
    while len(_markers(out, DONE)) < 2 and time.monotonic() < deadline and p.poll() is None:
        time.sleep(0.01)
    os.killpg(p.pid, signal.SIGKILL)  # the client, its scheduler and its workers
    p.wait()
    finished = {k: v.stat().st_mtime_ns for k, v in _markers(out, DONE).items()}
    assert 2 <= len(finished) < N_GOOD, "the kill must land mid-run"
    # nothing half-written: every folder without .tmp is complete (all its outputs, marker last)
    for folder in (out / "files").glob("*/*"):
        if folder.is_dir() and not folder.name.endswith(".tmp"):
            assert (folder / DONE).exists() or (folder / FAILED).exists(), folder
            if (folder / DONE).exists():
                outs = json.loads((folder / DONE).read_text())["outputs"]
                assert all((folder / n).stat().st_size == m["bytes"] for n, m in outs.items())
    r = subprocess.run(cmd[:-1], capture_output=True, text=True, timeout=120)
    assert r.returncode == 1, r.stderr  # the corrupt and vanished files failed
    assert f"{N_GOOD - len(finished)} done now, {len(finished)} already done" in r.stderr
    after = _markers(out, DONE)
    assert len(after) == N_GOOD
    assert all(after[k].stat().st_mtime_ns == t for k, t in finished.items()), "recomputed"
    assert _output_hashes(out) == want  # byte-identical to an uninterrupted (serial) run
    assert not list((out / "files").glob("*/*.tmp"))


def test_scheduler_named_or_chosen():
    from stillpoint.tools.cli.commands.cohort import scheduler_of
    assert scheduler_of(None, None) == "processes"  # the default: a process pool
    assert scheduler_of(None, 4 * 10**9) == "local"  # a memory limit is a LocalCluster's
    assert scheduler_of(None, "auto") == "local"
    assert scheduler_of("serial", 4 * 10**9) == "serial"
    assert scheduler_of("tcp://h:8786", None) == "tcp://h:8786"


@pytest.mark.parametrize("scheduler", ["processes", "local"])
def test_worker_killed_mid_task_is_retried(tmp_path, scheduler):
    src = tmp_path / "in"
    src.mkdir()
    for i in range(3):
        _sim(src / f"long{i}.cwa", seed=30 + i, days=0.12)
    out = tmp_path / "out"
    killed = []

    def killer():
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not killed:
            for m in (out / "files").glob(f"*/*.tmp/{RUNNING}") if out.exists() else []:
                try:
                    pid = json.loads(m.read_text())["pid"]
                except (OSError, ValueError, KeyError):
                    continue
                os.kill(pid, signal.SIGKILL)
                killed.append((m.parent.name[: -len(".tmp")], pid))
                return
            time.sleep(0.005)

    t = threading.Thread(target=killer)
    res = run_cohort(make_plan(discover_inputs([src]), RunSettings()), out, jobs=2, progress=False,
                     scheduler=scheduler, on_start=lambda backend: t.start())
    t.join()
    assert killed, "no worker was caught mid-task"
    assert res.done == 3 and not res.failed and res.retried >= 1
    done = json.loads(_markers(out, DONE)[killed[0][0]].read_text())
    assert done["attempts"] == 2 and done["pid"] != killed[0][1]


def test_a_new_setting_makes_new_keys_and_leaves_old_outputs(cohort_dir, tmp_path, capsys):
    files = [cohort_dir / "p02.cwa", cohort_dir / "g07.bin"]
    out = tmp_path / "out"
    args = ["cohort", "run", *map(str, files), "-o", str(out), "--scheduler", "serial", "-q"]
    assert cli(args) == 0
    old = {k: v.stat().st_mtime_ns for k, v in _markers(out, DONE).items()}
    assert cli(args + ["--epoch-s", "10"]) == 0
    new = _markers(out, DONE)
    assert len(old) == 2 and len(new) == 4 and set(old) < set(new)
    assert all(new[k].stat().st_mtime_ns == t for k, t in old.items())
    plan = read_plan(out)
    assert plan.settings["epoch_s"] == 10.0 and {e.folder.rsplit("/", 1)[1] for e in plan.entries} == set(new) - set(old)
    assert status(out).done == 2  # status and collate follow the last plan
    assert cli(["cohort", "collate", str(out)]) == 0
    rows = list(csv.DictReader(open(out / "cohort_summary.csv")))
    assert len(rows) == 2 and all("-" in Path(r["folder"]).name for r in rows)


def test_shards_cover_the_plan_exactly_once(cohort_dir, tmp_path, capsys):
    plan = make_plan(discover_inputs([cohort_dir]), RunSettings())
    a, b = plan.shard(0, 2).entries, plan.shard(1, 2).entries
    assert a and b and len(a) + len(b) == len(plan.entries) == N_GOOD + 2
    assert {e.key for e in a}.isdisjoint(e.key for e in b)
    out = tmp_path / "out"
    for k, entries in ((0, a), (1, b)):
        bad = any(Path(e.path).name in ("corrupt.cwa", "vanished.cwa") for e in entries)
        assert cli(["cohort", "run", str(cohort_dir), "-o", str(out), "--shard", f"{k}/2",
                    "--scheduler", "serial", "-q"]) == (1 if bad else 0)
    err = capsys.readouterr().err
    assert "shard 0/2" in err and "shard 1/2" in err and "cohort collate" in err
    assert len(_markers(out, DONE)) == N_GOOD and len(_markers(out, FAILED)) == 2
    assert all(json.loads(m.read_text())["attempts"] == 1 for m in _markers(out, DONE).values())
    assert cli(["cohort", "run", str(cohort_dir), "-o", str(out), "--shard", "2/2"]) == 2


def test_process_pool_without_dask_and_retry(cohort_dir, tmp_path, capsys, monkeypatch):
    from stillpoint.engine.cohort import execute
    monkeypatch.setattr(execute, "have_dask", lambda: False)
    out = tmp_path / "out"
    files = [str(cohort_dir / "p03.cwa"), str(cohort_dir / "corrupt.cwa")]
    assert cli(["cohort", "run", *files, "-o", str(out), "-j", "2", "--scheduler", "local"]) == 1
    err = capsys.readouterr().err
    assert "Dask is not installed: running on a local process pool" in err
    assert "pip install 'stillpoint[cohort]'" in err
    assert status(out).done == 1
    failed = next(iter(_markers(out, FAILED).values()))
    t0 = failed.stat().st_mtime_ns
    assert cli(["cohort", "retry", str(out), "--class", "transient_io", "-q"]) == 1
    assert failed.stat().st_mtime_ns == t0  # another class: left alone
    assert cli(["cohort", "retry", str(out), "--class", "corrupt_input", "--scheduler", "serial", "-q"]) == 1
    assert failed.stat().st_mtime_ns > t0 and status(out).failed == {"corrupt_input": 1}


def test_unusable_output_folder_is_one_line_exit_2(cohort_dir, tmp_path, capsys):
    assert cli(["cohort", "run", str(cohort_dir), "-o", str(tmp_path / "no" / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "does not exist" in err[0]
    assert cli(["cohort", "status", str(tmp_path)]) == 2
    assert "not a cohort folder" in capsys.readouterr().err
    assert cli(["cohort", "run", str(tmp_path / "missing"), "-o", str(tmp_path / "o")]) == 2


def test_transient_failure_is_retried_three_times(cohort_dir, tmp_path, monkeypatch):
    from stillpoint.engine.cohort import execute
    monkeypatch.setattr(execute, "TRANSIENT_DELAY_S", 0.01)
    f = tmp_path / "growing.cwa"
    f.write_bytes((cohort_dir / "p03.cwa").read_bytes())
    plan = make_plan([f], RunSettings())
    with open(f, "ab") as g:  # the file changes after it was planned (a copy still running)
        g.write(b"\0" * 512)
    out = tmp_path / "out"
    res = run_cohort(plan, out, scheduler="serial", progress=False)
    assert res.failed == {"transient_io": 1} and res.retried == 2
    marker = json.loads(next(iter(_markers(out, FAILED).values())).read_text())
    assert marker["attempts"] == 3 and "changed since the run was planned" in marker["error"]


def test_ctrl_c_stops_cleanly_and_a_rerun_finishes(cohort_dir, tmp_path):
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "stillpoint.tools", "cohort", "run", str(cohort_dir), "-o", str(out),
           "-j", "1", "--max-in-flight", "1"]  # one file at a time: work is left when the first finishes
    p = subprocess.Popen(cmd, start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                         text=True)
    deadline = time.monotonic() + 60
    while not _markers(out, DONE) and time.monotonic() < deadline and p.poll() is None:
        time.sleep(0.01)
    os.killpg(p.pid, signal.SIGINT)  # what a terminal sends to the whole process group
    err = p.communicate(timeout=60)[1]
    assert p.returncode == 130, err
    assert "interrupted" in err and "Rerun the same command to resume" in err
    assert "Traceback" not in err
    r = subprocess.run(cmd[:-4] + ["--scheduler", "serial", "-q"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 1, r.stderr  # the corrupt and vanished files failed
    assert len(_markers(out, DONE)) == N_GOOD and not list((out / "files").glob("*/*.tmp"))


def test_ctrl_c_swallowed_by_a_finaliser_still_stops_the_run(cohort_dir, tmp_path, monkeypatch):
    """Ctrl-C that lands inside a finaliser (a Dask future's ``__del__``: Python swallows it)
    still stops the run at the next turn of its loop, without an "Exception ignored" traceback."""
    from stillpoint.engine.cohort import execute
    real_job = execute.run_job
    calls = []

    class Finaliser:
        def __del__(self):  # the interrupt raised here is swallowed by Python
            signal.getsignal(signal.SIGINT)(signal.SIGINT, None)

    def job(*args):
        calls.append(args[0]["path"])
        r = real_job(*args)
        if len(calls) == 1:
            Finaliser()  # dropped at once: its __del__ runs here
        return r

    monkeypatch.setattr(execute, "run_job", job)
    seen = []
    monkeypatch.setattr(sys, "unraisablehook", seen.append)  # what would print the traceback
    files = sorted(str(p) for p in cohort_dir.glob("p0*.cwa"))
    before = signal.getsignal(signal.SIGINT)
    res = run_cohort(make_plan(files, RunSettings()), tmp_path / "out", scheduler="serial", progress=False)
    assert res.interrupted and res.done == len(calls) < len(files)  # one turn of the loop
    assert res.pending == len(files) - len(calls)
    assert signal.getsignal(signal.SIGINT) is before  # handler given back
    assert seen == [] and sys.unraisablehook == seen.append


def test_a_named_pipe_among_the_inputs_fails_without_waiting(tmp_path):
    """A named pipe found in an input folder is a failed input ("is a pipe"), taken as such
    before it is opened: opening it would wait for a writer and stall the whole plan."""
    d = tmp_path / "in"
    d.mkdir()
    _sim(d / "p.cwa", seed=3)
    os.mkfifo(d / "pipe.cwa")
    got = {}
    t = threading.Thread(target=lambda: got.update(plan=make_plan(discover_inputs([d]), RunSettings())),
                         daemon=True)
    t.start()
    t.join(60)
    assert not t.is_alive(), "the plan waited on the named pipe"
    entries = {Path(e.path).name: e for e in got["plan"].entries}
    assert entries["pipe.cwa"].error == "cannot open: is a pipe, not a recording file"
    assert entries["p.cwa"].error == "" and entries["p.cwa"].size > 0
