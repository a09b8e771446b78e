"""Fixtures for the station tests: emulated devices in this process (axemu:// ports), each test
with its own runtime registry, short simulated recordings."""

from __future__ import annotations

import pytest

from stillpoint.drivers.ax.emulator import EmulatedDevice

DAYS = 0.01  # ~15 min at 100 Hz: 0.37 MB per AX3


@pytest.fixture
def runtime(tmp_path, monkeypatch):
    d = tmp_path / "runtime"
    monkeypatch.setenv("STILLPOINT_RUNTIME_DIR", str(d))
    return d


@pytest.fixture
def emu(tmp_path, runtime):
    made = []

    def make(device_id=10001, kind="AX3", faults=(), plug=True, **kw):
        kw.setdefault("days", DAYS)
        kw.setdefault("remount_s", 0.05)
        kw.setdefault("replug_s", 0.3)
        d = EmulatedDevice(tmp_path / f"dev{device_id}", device_id, kind, faults=faults,
                           slot=f"emu-{len(made) + 1}", **kw)
        made.append(d)
        if plug:
            d.plug()
        return d

    yield make
    for d in made:
        d.shutdown()
