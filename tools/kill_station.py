"""Kill trials for the station: SIGKILL it at random times and at every state boundary, restart it,
and count the devices it strands and the data it loses (0 and 0 expected).

    python -m stillpoint.tools.kill_station --random 50 --boundaries [--seed 1] [--keep DIR]

One trial: emulated AX3 devices in this process (pseudo-terminal ports and folder drives, found by
the station through the runtime registry), ``stillpoint station OUT --clear-after-verify`` in a
process group of its own, killed with SIGKILL (the whole group, or only the station's pid, so
its download workers must end by themselves), then ``stillpoint station OUT --once
--clear-after-verify`` run to its end. A boundary trial starts the first station with
``STILLPOINT_KILL_AT=<step>`` (``ledger.KILL_STEPS``; ``KILL_STEPS_CONFIGURE`` with a study profile
and ``--configure-after``), so it kills itself at that step. Counted:

* stranded: a device not cleared after the restart, or a ledger row left between states
  (``downloading``/``completing`` download, ``sent`` clear);
* lost: a device whose original bytes (SHA-256 taken before the trial) are in no file of the
  output folder;
* orphans: processes of the killed station's group still alive 1 s after the kill.
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import os
import random
import signal
import sqlite3
import subprocess
import sys
import tempfile
import time
from pathlib import Path

DAYS = 0.01  # ~0.37 MB per device
READ_BPS = 0.6e6  # the emulated drives' read speed: a download takes about a second


def _sha(b: bytes) -> str:
    return hashlib.sha256(b).hexdigest()


def _group_alive(pgid: int) -> list[int]:
    alive = []
    for d in os.listdir("/proc"):
        if not d.isdigit():
            continue
        try:
            with open(f"/proc/{d}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[2]) == pgid and fields[0] != "Z":
            alive.append(int(d))
    return alive


PROFILE = """
[device]
rate_hz = 50
range_g = 4
start = "+2h"
stop = "+7d"
session = "increment"
min_battery_pct = 10
"""


def _last_states(out: Path) -> str:
    """Each device's last state in the ledger (where the kill found it)."""
    try:
        db = sqlite3.connect(out / "stillpoint-ledger.sqlite")
        try:
            rows = db.execute("SELECT device_id, state FROM events WHERE id IN "
                              "(SELECT MAX(id) FROM events GROUP BY device_id) "
                              "ORDER BY device_id").fetchall()
        finally:
            db.close()
    except sqlite3.Error:
        return "-"
    return ",".join(state for _, state in rows) or "-"


def _station(out: Path, env: dict, once: bool, profile: Path | None = None) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "stillpoint.tools", "station", str(out), "--clear-after-verify",
           "--plain", "--stall-s", "20"] + (["--once"] if once else []) + \
        (["--configure-after", "--profile", str(profile)] if profile else [])
    return subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            start_new_session=True, text=True)


def trial(work: Path, *, kill_at: str | None = None, delay_s: float | None = None,
          pid_only: bool = False, devices: int = 2, timeout_s: float = 120.0,
          configure: bool = False) -> dict:
    """One kill trial in ``work`` (see module docstring); returns what it found. ``configure``:
    the station also configures each cleared device from a study profile, and a device not
    configured after the restart counts as stranded too."""
    from stillpoint.drivers.ax.emulator import EmulatedDevice
    from stillpoint.engine.sim.record import device_recording
    from stillpoint.drivers.ax.registry import using_runtime_dir
    work.mkdir(parents=True, exist_ok=True)
    runtime, out = work / "runtime", work / "out"
    out.mkdir()
    profile = None
    if configure:
        profile = work / "study.toml"
        profile.write_text(PROFILE)
    env = dict(os.environ, STILLPOINT_RUNTIME_DIR=str(runtime))
    env.pop("STILLPOINT_KILL_AT", None)
    in_runtime = contextlib.ExitStack()
    in_runtime.enter_context(using_runtime_dir(runtime))
    devs = []
    res = {"kill_at": kill_at, "delay_s": delay_s, "pid_only": pid_only}
    try:
        for k in range(devices):
            d = EmulatedDevice(work / f"dev{k}", 10001 + k, "AX3", make_recording=device_recording,
                               days=DAYS, seed=k + 1,
                               slot=f"emu-{k + 1}", remount_s=0.2, read_bps=READ_BPS)
            d.plug(pty=True)
            devs.append(d)
        held = {d.device_id: _sha(d.data_file.read_bytes()) for d in devs}
        first_env = dict(env, STILLPOINT_KILL_AT=kill_at) if kill_at else env
        p = _station(out, first_env, once=kill_at is not None, profile=profile)
        if kill_at is None:
            time.sleep(delay_s or 0.0)
            if p.poll() is None:
                if pid_only:
                    os.kill(p.pid, signal.SIGKILL)
                else:
                    os.killpg(p.pid, signal.SIGKILL)
        try:
            first_out, _ = p.communicate(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            os.killpg(p.pid, signal.SIGKILL)
            first_out, _ = p.communicate()
        res["killed"] = p.returncode == -signal.SIGKILL
        end = time.monotonic() + 1.0  # a worker ends at once (parent-death signal, lifeline)
        while _group_alive(p.pid) and time.monotonic() < end:
            time.sleep(0.1)
        orphans = _group_alive(p.pid)
        res["orphans"] = len(orphans)
        for pid in orphans:  # never leave one running
            try:
                os.kill(pid, signal.SIGKILL)
            except OSError:
                pass
        res["states_at_kill"] = _last_states(out)
        for d in devs:  # a device the kill left unplugged (mid-clear) comes back
            t_end = time.monotonic() + 5.0
            while not d.plugged and time.monotonic() < t_end:
                time.sleep(0.05)
        q = _station(out, env, once=True, profile=profile)
        try:
            second_out, _ = q.communicate(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            os.killpg(q.pid, signal.SIGKILL)
            second_out, _ = q.communicate()
        res["restart_rc"] = q.returncode
        files = set()
        for n in os.listdir(out):
            pth = out / n
            if pth.is_file() and not n.startswith(("stillpoint-ledger", ".stillpoint")):
                files.add(_sha(pth.read_bytes()))
        stranded = [d.device_id for d in devs
                    if not d.clears or d.data_file.stat().st_size > 1024]
        db = sqlite3.connect(out / "stillpoint-ledger.sqlite")
        try:
            if configure:
                ok = {r[0] for r in db.execute("SELECT device_id FROM configurations "
                                               "WHERE result='ok'")}
                stranded += [d.device_id for d in devs if d.device_id not in ok]
            unsettled = db.execute("SELECT COUNT(*) FROM downloads WHERE state IN "
                                   "('downloading', 'completing')").fetchone()[0]
            unsettled += db.execute("SELECT COUNT(*) FROM clears WHERE result='sent'").fetchone()[0]
        finally:
            db.close()
        res["stranded"] = len(stranded) + unsettled
        res["lost"] = sum(1 for s in held.values() if s not in files)
        if res["stranded"] or res["lost"] or res["orphans"]:
            res["log"] = (first_out or "")[-2000:] + "\n--- restart ---\n" + (second_out or "")[-2000:]
    finally:
        for d in devs:
            d.shutdown()
        in_runtime.close()
    return res


def main(argv=None) -> int:
    from stillpoint.engine.station.ledger import KILL_STEPS, KILL_STEPS_CONFIGURE
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--random", type=int, default=50, help="trials killed at a random time")
    ap.add_argument("--boundaries", action="store_true", help="also one trial per state boundary")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--max-delay-s", type=float, default=5.0)
    ap.add_argument("--keep", type=Path, default=None, help="keep the trials' folders here")
    a = ap.parse_args(argv)
    rng = random.Random(a.seed)
    plan = [dict(kill_at=s) for s in (KILL_STEPS if a.boundaries else ())]
    plan += [dict(kill_at=s, configure=True) for s in (KILL_STEPS_CONFIGURE if a.boundaries else ())]
    plan += [dict(delay_s=round(rng.uniform(0.3, a.max_delay_s), 2), pid_only=bool(i % 2))
             for i in range(a.random)]
    root = Path(a.keep) if a.keep else Path(tempfile.mkdtemp(prefix="kill-station-"))
    totals = {"stranded": 0, "lost": 0, "orphans": 0, "killed": 0}
    for i, kw in enumerate(plan):
        r = trial(root / f"t{i:03d}", **kw)
        for k in totals:
            totals[k] += int(r[k])
        what = f"at {r['kill_at']}" if r["kill_at"] else \
            f"after {r['delay_s']:.2f} s ({'pid' if r['pid_only'] else 'group'})"
        print(f"trial {i + 1:3d}/{len(plan)} kill {what:<34} killed={int(r['killed'])} "
              f"orphans={r['orphans']} stranded={r['stranded']} lost={r['lost']} "
              f"restart_rc={r['restart_rc']} states={r['states_at_kill']}", flush=True)
        if "log" in r:
            print(r["log"], flush=True)
    print(f"{len(plan)} trials: {totals['killed']} killed, {totals['orphans']} orphaned workers, "
          f"{totals['stranded']} stranded, {totals['lost']} lost", flush=True)
    if not a.keep:
        import shutil
        shutil.rmtree(root, ignore_errors=True)
    return 1 if totals["stranded"] or totals["lost"] or totals["orphans"] else 0


if __name__ == "__main__":
    sys.exit(main())
