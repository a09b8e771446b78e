"""Real recordings (STILLPOINT_REAL_DATA): process each format, replay bit for bit, QC on the
corrupt fixture, gyro topic on AX6, GENEActiv at 600/7 Hz, gzip input."""

from __future__ import annotations

import json

import numpy as np
import pytest
from mcap.reader import make_reader

from stillpoint.drivers import open_recording
from stillpoint.engine.mcap.replay import McapRawSource
from stillpoint.engine.mcap.compare import compare
from stillpoint.engine.run import RunSettings, process_file
from stillpoint.tools.cli import main as cli
from mcap_layout import conforms


def _topics(path):
    with open(path, "rb") as f:
        s = make_reader(f).get_summary()
    ch = {c.id: c.topic for c in s.channels.values()}
    return {ch[k]: v for k, v in s.statistics.channel_message_counts.items()}


@pytest.mark.parametrize("name", [
    "ax3_ggirread_corrupt_blocks_0_13_14_142_143_144.cwa",
    "ax6_ggirread_testfile_100hz_16g_gyro250dps.cwa",
    "geneactiv_ggirread_testfile_85p7hz_truncated64k.bin",
    "ax3_oxwearables_tiny_sample_3h_with_restart.cwa.gz",
])
def test_real_file_process_and_replay(real_file, tmp_path, name):
    path = real_file(name)
    out = tmp_path / "o.mcap"
    s = process_file(path, out, RunSettings(mode="online"))
    conforms(out)  # spec-complete layout (tests/mcap_layout.py) and the mcap indexed reader
    with open_recording(path) as src:
        n = sum(b.n for b in src)
        qc = src.qc
    assert s["samples"] == n > 0
    topics = _topics(out)
    assert topics["/raw/accel"] > 0 and topics["/corrected/accel"] > 0 and topics["/metrics/epoch"] > 0
    if name.startswith("ax6"):
        assert topics["/raw/gyro"] == topics["/raw/accel"]
        got = sum(b.n for b in McapRawSource(out))
        assert got == n
        assert all(b.gyro is not None for b in McapRawSource(out))
    if "corrupt" in name:
        with open(out, "rb") as f:
            ev = [json.loads(m.data) for _s, _c, m in make_reader(f).iter_messages(topics=["/qc"])]
        bad = sorted(e["index"] for e in ev if e.get("reason") == "checksum")
        assert bad == [0, 13, 14, 142, 143, 144]
        assert s["qc"]["skipped"] == qc.skipped == 6
    again = tmp_path / "again.mcap"
    assert cli(["replay", str(out), "-o", str(again), "-q"]) == 0
    assert all(r["identical"] for r in compare(out, again).values())


def test_real_geneactiv_non_integer_rate_epochs(real_file, tmp_path):
    path = real_file("geneactiv_ggirread_testfile_85p7hz_truncated64k.bin")
    s = process_file(path, tmp_path / "g.mcap", RunSettings())
    assert abs(s["device"]["rate_hz"] - 600 / 7) < 1e-9
    # 10 s windows hold 857 or 858 samples at 85.714 Hz: all windows pass the fill rule
    assert s["windows"] >= int(s["duration_s"] // 10) - 1
    assert s["enmo_mean_mg"] is not None and np.isfinite(s["enmo_mean_mg"])
