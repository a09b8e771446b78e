"""The README's first station session runs: its commands, read from the README, in a
shell (terminal 1 in the background), in a fresh home folder, on the emulator, with one change:
the emulated recordings are ``SIM_DAYS`` long instead of the README's day, long enough for each
device's calibration to be fitted and stored. The example profile the session writes is the one
the station guide shows. Each device is downloaded, verified (device 2's misread re-read and
patched, on its line) with its calibration fitted, cleared and configured, and gets its outputs
and a stored calibration; the dashboard answers; Ctrl-C stops the station with exit code 0."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import threading
import time
import urllib.request
from pathlib import Path

from stillpoint.engine.station.profile import EXAMPLE_PROFILE, load_profile

ROOT = Path(__file__).resolve().parents[3]
# 7.2 h of simulated wear (10:00 to 17:12): long enough for every device's calibration to be
# fitted and stored
SIM_DAYS = "0.3"


def _session() -> tuple[list[str], list[str]]:
    """(terminal 1's commands, terminal 2's commands) of the README's station session."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    part = text.split("## A first station session", 1)[1]
    block = []
    for line in part.splitlines()[1:]:
        if line.startswith("    "):
            block.append(line[4:])
        elif block and line.strip():
            break
    terminals: list[list[str]] = []
    for line in block:
        if line.startswith("# terminal"):
            terminals.append([])
        elif line.strip() and not line.startswith("#"):
            terminals[-1].append(line)
    assert len(terminals) == 2, block
    return terminals[0], terminals[1]


def _guide_profile() -> str:
    text = (ROOT / "docs" / "station.md").read_text(encoding="utf-8")
    after = text.split("`stillpoint station --write-profile study.toml` writes it", 1)[1]
    lines, started = [], False
    for line in after.splitlines():
        if line.startswith("    "):
            started = True
            lines.append(line[4:])
        elif started:
            break
    return "\n".join(lines) + "\n"


def test_the_guide_shows_the_example_profile_the_station_writes():
    assert _guide_profile() == EXAMPLE_PROFILE


class _Lines:
    """The output of a process, line by line, on a thread."""

    def __init__(self, proc):
        self.lines: list[str] = []
        self._t = threading.Thread(target=self._read, args=(proc,), daemon=True)
        self._t.start()

    def _read(self, proc):
        for line in proc.stdout:
            self.lines.append(line.rstrip("\n"))

    def wait_for(self, cond, timeout_s: float, what: str):
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            if cond(self.lines):
                return
            time.sleep(0.2)
        raise AssertionError(f"timed out waiting for {what}:\n" + "\n".join(self.lines))


def test_the_readme_station_session_runs_as_written(tmp_path):
    first, second = _session()
    assert first[0].startswith("stillpoint device emulate") and second[-1].startswith(
        "stillpoint station ~/study-out")
    home, work = tmp_path / "home", tmp_path / "work"
    home.mkdir()
    work.mkdir()
    env = {k: v for k, v in os.environ.items()
           if not k.startswith("STILLPOINT_") and k not in ("XDG_RUNTIME_DIR", "XDG_SESSION_ID")}
    env.update(HOME=str(home), STILLPOINT_RUNTIME_DIR=str(tmp_path / "runtime"),
               PATH=str(Path(sys.executable).parent) + os.pathsep + env.get("PATH", ""),
               PYTHONUNBUFFERED="1", COLUMNS="400")

    def shell(cmd, **kw):
        return subprocess.Popen(["bash", "-c", cmd], cwd=work, env=env, text=True,
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                start_new_session=True, **kw)
    try:  # the report's figures: matplotlib's font cache, not the fresh home's empty one
        import matplotlib
        env["MPLCONFIGDIR"] = matplotlib.get_cachedir()
    except ImportError:
        pass
    assert len(first) == 1 and len(re.findall(r"--days \S+", first[0])) == 1, first
    emulator = shell(re.sub(r"--days \S+", f"--days {SIM_DAYS}", first[0]))
    station = None
    try:
        emu_out = _Lines(emulator)
        emu_out.wait_for(lambda ls: any("emulated device(s) attached" in x for x in ls), 300,
                         "the emulated devices")
        for cmd in second[:-1]:
            r = subprocess.run(["bash", "-c", cmd], cwd=work, env=env, capture_output=True,
                               text=True, timeout=120)
            assert r.returncode == 0, (cmd, r.stdout, r.stderr)
            if cmd.startswith("stillpoint devices"):
                assert len(re.findall(r"\b1000[123]\b", r.stdout)) >= 3, r.stdout
        assert (home / "study-out").is_dir()
        assert (work / "study.toml").read_text() == EXAMPLE_PROFILE
        load_profile(work / "study.toml")

        station = shell(second[-1])
        out = _Lines(station)
        done = re.compile(r"\b(1000[123]) \[emu-\d\] configured: session 2\b")
        out.wait_for(lambda ls: len({m.group(1) for x in ls for m in [done.search(x)] if m}) == 3
                     and sum("outputs:" in x for x in ls) == 3, 900, "three configured devices")
        text = "\n".join(out.lines)
        assert "Traceback" not in text and " error" not in text, text
        patched = [x for x in out.lines if "10002 [emu-2] verified:" in x]
        assert patched and "1 range re-read, copy patched" in patched[0], text
        verified = [x for x in out.lines if re.search(r"\b1000[123] \[emu-\d\] verified:", x)]
        assert len(verified) == 3 and all("calibration ok" in x for x in verified), text
        stored = [x for x in out.lines if "outputs:" in x]
        assert all("calibration store written" in x for x in stored), text
        url = next(x for x in out.lines if x.startswith("dashboard: ")).split()[1]
        with urllib.request.urlopen(url, timeout=10) as r:
            assert r.status == 200 and "AX3-10002" in r.read().decode()
        study = home / "study-out"
        for name in ("AX3-10001_1", "AX3-10002_1", "AX6-10003_1"):
            assert (study / f"{name}.cwa").is_file() and (study / f"{name}.mcap").is_file()
        os.killpg(station.pid, signal.SIGINT)  # Ctrl-C
        assert station.wait(60) == 0, text
    finally:
        for p in (station, emulator):
            if p is not None and p.poll() is None:
                os.killpg(p.pid, signal.SIGINT)
                try:
                    p.wait(30)
                except subprocess.TimeoutExpired:
                    os.killpg(p.pid, signal.SIGKILL)
                    p.wait(10)
