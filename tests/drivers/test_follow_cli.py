"""Follow mode from the CLI: ``inspect --follow`` and ``process --follow`` read a recording that
is still being written, and say (QC ``follow_idle_stop``) that they stopped because it stopped
growing."""

from __future__ import annotations

import json
import subprocess
import sys
import time

import numpy as np
import pytest

from stillpoint.drivers.cwa_writer import CwaWriter
from stillpoint.drivers.geneactiv import GeneactivReader, GeneactivWriter


def _growing_cwa(path, parts=4, sectors_per_part=10, pause_s=0.4):
    """Write a .cwa in parts (flushed), as a download in progress does."""
    n = 120 * sectors_per_part
    rng = np.random.default_rng(0)
    f = open(path, "wb")
    w = CwaWriter(f, rate_hz=50)
    for k in range(parts):
        t = 1_700_000_000_000_000_000 + np.rint((np.arange(n) + k * n) * 2e7).astype(np.int64)
        w.write(t, rng.integers(-511, 512, (n, 3)) * 4)
        f.flush()
        yield k
        time.sleep(pause_s)
    w.close()
    f.close()


@pytest.mark.parametrize("cmd", ["inspect", "process"])
def test_cli_follow_reads_a_growing_file(tmp_path, cmd):
    p = tmp_path / "dl.cwa"
    gen = _growing_cwa(p)
    next(gen)
    args = ([sys.executable, "-m", "tools", "inspect", str(p), "--follow", "1.5", "--json"] if cmd == "inspect"
            else [sys.executable, "-m", "tools", "process", str(p), "--follow", "1.5", "--mode", "online",
                  "--json", "-o", str(tmp_path / "o.mcap")])
    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    for _ in gen:
        pass
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, err
    d = json.loads(out)
    assert d["samples"] == 4 * 10 * 120
    if cmd == "inspect":
        assert "follow_idle_stop" in [e["reason"] for e in d["qc"]]
    else:
        assert d["qc"]["reasons"].get("follow_idle_stop") == 1


def test_follow_needs_online_mode(tmp_path):
    p = tmp_path / "dl.cwa"
    for _ in _growing_cwa(p, parts=1, pause_s=0):
        pass
    r = subprocess.run([sys.executable, "-m", "tools", "process", str(p), "--follow", "-o",
                        str(tmp_path / "o.mcap")], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "--mode online" in r.stderr


def test_geneactiv_follow_idle_stop_logged_with_the_same_keyword(tmp_path):
    p = tmp_path / "g.bin"
    n = 600
    w = GeneactivWriter(p, rate_hz=50)
    w.write(1_600_000_000_000_000_000 + np.arange(n) * 20_000_000, np.zeros((n, 3), int))
    w.close()
    r = GeneactivReader(p, follow=True, follow_idle_s=0.3)
    assert sum(b.n for b in r) == n
    assert [e.reason for e in r.qc.events][-1:] == ["follow_idle_stop"]


@pytest.mark.parametrize("kind", ["unpacked", "ax6_accel"])
def test_follow_mode_with_a_live_writer_gives_the_file_read(tmp_path, kind):
    """Unpacked AX3 and AX6 accel-only followed while being written: the same samples as reading
    the finished file (blocks used to point into the reader's reused buffer)."""
    import threading

    from stillpoint.drivers.cwa import CwaReader
    p = tmp_path / "live.cwa"
    f = open(p, "wb")
    kw = dict(packed=False) if kind == "unpacked" else dict(device_type="AX6")
    w = CwaWriter(f, rate_hz=50, **kw)
    rng = np.random.default_rng(1)
    n = 80  # one sector per write: the reader sees one-sector batches
    started = threading.Event()
    errors = []

    def writer():
        try:
            for k in range(30):
                t = 1_700_000_000_000_000_000 + np.rint((np.arange(n) + (k + 1) * n) * 2e7).astype(np.int64)
                w.write(t, rng.integers(-2000, 2000, (n, 3)))
                f.flush()
                time.sleep(0.02)
            w.close()
            f.close()
        except Exception as e:  # reported by the test, not lost in the thread
            errors.append(e)

    t = 1_700_000_000_000_000_000 + np.rint(np.arange(n) * 2e7).astype(np.int64)
    w.write(t, rng.integers(-2000, 2000, (n, 3)))  # one whole sector before the reader starts
    f.flush()
    th = threading.Thread(target=writer)
    th.start()
    blocks = []
    for b in CwaReader(p, follow=True, follow_idle_s=1.0):
        blocks.append(b)
        started.set()
    th.join()
    assert not errors, errors
    live = np.concatenate([b.accel for b in blocks])
    assert live.shape[0] == 31 * n
    done = np.concatenate([b.accel for b in CwaReader(p)])
    np.testing.assert_array_equal(live, done)
