"""Long stretches of samples at the range limit are flagged (summary, /qc and the text summary)."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np

from stillpoint.drivers.cwa_writer import CwaWriter
from stillpoint.engine.clipping import ClippingMonitor


class _B:
    def __init__(self, a_g):
        self.accel = (np.asarray(a_g) * 256).astype(np.int16)
        self.n = self.accel.shape[0]

    def accel_g(self, dtype=np.float64):
        return (self.accel / 256.0).astype(dtype)


def test_monitor_counts_runs_across_blocks():
    m = ClippingMonitor(8.0, 10.0)
    a = np.zeros((100, 3))
    a[60:, 0] = 8.0  # 40 clipped at the end of block 1
    m.observe(_B(a))
    b = np.zeros((100, 3))
    b[:30, 1] = -8.0  # ... continued by 30 at the start of block 2
    m.observe(_B(b))
    assert m.clipped == 70 and m.longest == 70
    assert m.clipped_s == 7.0 and not m.flagged


def test_process_flags_minutes_of_clipping(tmp_path):
    rate, n = 25, 25 * 60 * 4  # 4 minutes, 3 of them at the +2 g limit
    t = 1_700_000_000_000_000_000 + np.arange(n) * 40_000_000
    a = np.tile([0, 0, 256], (n, 1))
    a[n // 4:, 0] = 511
    p = tmp_path / "clip.cwa"
    w = CwaWriter(p, rate_hz=rate, range_g=2, packed=False)
    w.write(t, a)
    w.close()
    r = subprocess.run([sys.executable, "-m", "tools", "process", str(p), "-o", str(tmp_path / "o.mcap"),
                        "--json"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    clip = json.loads(r.stdout)["clipping"]
    assert clip["flagged"] and abs(clip["seconds"] - 180) < 1
    r = subprocess.run([sys.executable, "-m", "tools", "process", str(p), "-o", str(tmp_path / "o2.mcap")],
                       capture_output=True, text=True, timeout=120)
    assert "clipping: 0.05 h of data" in r.stdout
    from stillpoint.engine.alignment.mcap_out import read_topic_json
    assert any(q.get("reason") == "clipping" for q in read_topic_json(tmp_path / "o2.mcap", "/qc"))
