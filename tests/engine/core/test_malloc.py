"""The heap's free pages go back to the system (engine/core/malloc.py ``trim``), and a run's pass 2
trims every ``TRIM_EVERY_STEPS`` pipeline steps so its resident size does not creep up with the
file's length."""

from __future__ import annotations

import subprocess
import sys

import pytest

from stillpoint.engine.run import RunSettings, process_file

linux_only = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc_trim: Linux only")


@linux_only
def test_trim_gives_back_freed_arrays_held_in_place_by_small_ones():
    """40 MiB of arrays freed between small long-lived ones stay resident (the heap cannot
    shrink past them, and the trim threshold is raised as a run raises it) until trim()."""
    code = r"""
import numpy as np
from stillpoint.engine.core.malloc import set_block_thresholds, trim
set_block_thresholds()
def rss():
    return int(open("/proc/self/statm").read().split()[1]) * 4096 / 2**20
big, pins = [], []
for i in range(40):
    big.append(np.ones(1 << 20, np.uint8))
    pins.append(np.ones(64, np.uint8))
pins.append(np.ones(64, np.uint8))
del big
before = rss()
ok = trim()
print(ok, before - rss())
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    ok, freed = out.stdout.split()
    assert ok == "True"
    assert float(freed) > 30, out.stdout


def test_pass_two_trims_every_few_steps(tmp_path, monkeypatch):
    from stillpoint.engine.run import output, tuning
    from cwa_helpers import damaged_cwa
    calls = []
    monkeypatch.setattr(output, "trim", lambda: calls.append(1) or True)
    monkeypatch.setattr(tuning, "TRIM_EVERY_STEPS", 2)
    steps = []
    orig = output.OutputStage.push
    monkeypatch.setattr(output.OutputStage, "push", lambda self, b: (steps.append(1), orig(self, b))[1])
    src = damaged_cwa(tmp_path / "damaged.cwa", 7)
    for mode in ("batch", "online"):
        calls.clear()
        steps.clear()
        process_file(src, tmp_path / f"{mode}.mcap", RunSettings(mode=mode, chunk_hours=0.25, first_hours=0.25),
                     source_options={"batch_sectors": 3})
        assert len(steps) >= 4, mode
        assert len(calls) == len(steps) // 2, mode
