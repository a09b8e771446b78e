"""Four emulated devices (clean, one bit misread in the copy, data that changes between reads, the
cable pulled mid-copy), two passes of ``station --once --clear-after-verify``: the clean, the
re-plugged and the misread devices end cleared with a raw copy byte-identical to what they held;
the one whose data changed is never cleared; nothing a cleared device held is missing from the
output folder; every file left there has one of the documented names."""

from __future__ import annotations

import os
import time

from stillpoint.engine.station import names
from stillpoint.tools.cli import main

from station_fixtures import emu, runtime  # noqa: F401

FAULTS = {10001: (), 10002: ("bit-flip",), 10003: ("change-between-reads",),
          10004: ("unplug-mid-copy",)}


def test_four_devices_two_passes(emu, tmp_path, capsys):
    devs = {i: emu(i, faults=f, replug_s=0.3) for i, f in FAULTS.items()}
    held = {i: d.data_file.read_bytes() for i, d in devs.items()}
    out = tmp_path / "out"
    out.mkdir()
    args = ["station", str(out), "--once", "--clear-after-verify", "--plain"]
    assert main(args) == 2  # the changed and the unplugged devices end in error
    first = capsys.readouterr().out
    assert "10002 [emu-2] cleared" in first and "10001 [emu-1] cleared" in first
    end = time.monotonic() + 10
    while not devs[10004].plugged and time.monotonic() < end:  # the emulator re-plugs it
        time.sleep(0.05)
    assert main(args) == 2  # the changed device is still refused its clear
    second = capsys.readouterr().out
    assert "10004 [emu-4] cleared" in second
    assert "10003 [emu-3] error: not cleared: the device's data changed" in second

    files = {n: (out / n).read_bytes() for n in os.listdir(out) if (out / n).is_file()}
    for i in (10001, 10002, 10004):
        d = devs[i]
        assert len(d.clears) == 1, (i, d.events)
        assert d.data_file.stat().st_size <= 1024  # cleared: only a header
        assert files[f"AX3-{i}_1.cwa"] == held[i]  # the raw copy is what the device held
        assert f"AX3-{i}_1.mcap" in files
    d = devs[10003]
    assert d.clears == [] and d.data_file.stat().st_size == len(held[10003])
    # both versions of the changed device's data are kept: the first read (set aside) and the
    # device's bytes now
    assert held[10003] in files.values() and d.data_file.read_bytes() in files.values()
    for n in files:
        assert ".part.part" not in n and names.kind_of(n) is not None, n
