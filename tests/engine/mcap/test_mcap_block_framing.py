"""Per-block framing of the MCAP log (engine/mcap/sink.py ``_frame_block``) writes the same file,
byte for byte, as the cell-by-cell path it replaces on the hot path: same records, same order,
same chunk cuts (also when the chunk size, not the chunk span, ends chunks)."""

from __future__ import annotations

import gzip
import shutil
from pathlib import Path

import pytest

from stillpoint.engine.mcap import sink as sink_mod
from stillpoint.engine.run import RunSettings, process_file
from synthetic_recording import make_recording


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    p = tmp_path_factory.mktemp("frame") / "rec.cwa"
    make_recording(p, hours=1.0, rate=50.0, seed=5)
    return p


def _both(src, out: Path, settings: RunSettings, monkeypatch) -> tuple[bytes, bytes, int]:
    calls = {"block": 0}
    frame = sink_mod._frame_block

    def counting(*a):
        done = frame(*a)
        calls["block"] += bool(done)
        return done

    monkeypatch.setattr(sink_mod, "_frame_block", counting)
    res = []
    for block_framing in (False, True):
        monkeypatch.setattr(sink_mod.McapSink, "block_framing", block_framing)
        process_file(src, out, settings)
        res.append(out.read_bytes())
    return res[0], res[1], calls["block"]


@pytest.mark.parametrize("settings", [
    RunSettings(mode="batch"),
    RunSettings(mode="online"),
    RunSettings(mode="batch", chunk_size=20000, view_hz=7.0),
    RunSettings(mode="online", flush_every_s=3.0, chunk_s=7.0, max_block_s=37.0),
], ids=["batch", "online", "small-chunks", "short-cells"])
def test_block_framing_writes_the_same_bytes(recording, tmp_path, settings, monkeypatch):
    cell, block, framed = _both(recording, tmp_path / "o.mcap", settings, monkeypatch)
    assert framed > 0  # the per-block path did run
    assert cell == block


@pytest.mark.parametrize("name", ["ax6_ggirread_testfile_100hz_16g_gyro250dps.cwa",
                                  "geneactiv_actfast_cmi_60hz_20pages_LF_fw0617.bin",
                                  "ax3_oxwearables_tiny_sample_3h_with_restart.cwa.gz"])
def test_block_framing_real_files(real_data_dir, tmp_path, name, monkeypatch):
    """Gyro (AX6), per-sample light and button (GENEActiv), a restart (two segments)."""
    src = real_data_dir / name
    if not src.exists():
        pytest.skip(f"{name} not in the real-data directory")
    if name.endswith(".gz"):
        plain = tmp_path / name[:-3]
        with gzip.open(src) as f, open(plain, "wb") as g:
            shutil.copyfileobj(f, g)
        src = plain
    for settings in (RunSettings(mode="batch", chunk_size=20000, view_hz=7.0),
                     RunSettings(mode="online", flush_every_s=3.0, chunk_s=7.0, max_block_s=37.0)):
        cell, block, framed = _both(src, tmp_path / "o.mcap", settings, monkeypatch)
        assert framed > 0 and cell == block


def test_isal_crc32_equals_zlibs():
    """The MCAP CRC-32 comes from ISA-L when the optional `fast` extra is installed (the test
    extra installs it), else from zlib: both give the same values."""
    import zlib

    import numpy as np
    from stillpoint.engine.mcap import records
    isal_zlib = pytest.importorskip("isal.isal_zlib", reason="the optional `fast` extra (isal) "
                                    "is not installed: only zlib's CRC is in use")
    assert records.crc32 is isal_zlib.crc32
    rng = np.random.default_rng(0)
    for n in (0, 1, 7, 4096, 1 << 20):
        data = rng.integers(0, 256, n, dtype=np.uint8).tobytes()
        assert isal_zlib.crc32(data) == zlib.crc32(data)
        assert isal_zlib.crc32(data, 12345) == zlib.crc32(data, 12345)
