"""Results never depend on how a reader cuts the file into batches: every reader, every batch
size from one sector/page up, on clean and damaged files (incl. the fuzz reproducers)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from stillpoint.drivers.cwa import CwaReader
from stillpoint.drivers.geneactiv import GeneactivReader, GeneactivWriter

FUZZ = Path(__file__).parents[1] / "data" / "fuzz"
FIELDS = ("time_ns", "accel", "gyro", "unit_index", "unit_sequence", "unit_start",
          "temperature_c", "battery_v", "light", "events")


def snapshot(reader) -> dict:
    """Every per-sample and per-unit array, the segment of every sample and the QC log."""
    blocks = list(reader)
    out = {"qc": [(e.index, e.reason, e.time_ns, e.samples) for e in reader.qc.events],
           "counts": (reader.qc.total, reader.qc.valid, reader.qc.skipped)}
    for f in FIELDS:
        parts = [getattr(b, f) for b in blocks if getattr(b, f) is not None]
        if f == "unit_start":
            parts = [b.unit_start + b.first_sample for b in blocks]
        out[f] = np.concatenate(parts) if parts else None
    out["segment"] = np.concatenate([np.full(b.n, b.segment) for b in blocks]) if blocks else None
    return out


def assert_same(a: dict, b: dict, what: str) -> None:
    assert a["qc"] == b["qc"], what
    assert a["counts"] == b["counts"], what
    for k in (*FIELDS, "segment"):
        if a[k] is None or b[k] is None:
            assert a[k] is None and b[k] is None, f"{what}: {k}"
            continue
        np.testing.assert_array_equal(a[k], b[k], err_msg=f"{what}: {k}")


CWA_FILES = ["ax3_unpacked_40_sectors.cwa", "ax3_3200hz_anchor_back_52ms.cwa",
             "ax6_mixed_0x62_0x32_sector.cwa"]


@pytest.mark.parametrize("name", CWA_FILES)
@pytest.mark.parametrize("batch", [1, 2, 3, 7, 16])
def test_cwa_batch_size_does_not_change_results(name, batch):
    ref = snapshot(CwaReader(FUZZ / name))
    assert_same(ref, snapshot(CwaReader(FUZZ / name, batch_sectors=batch)), f"{name} batch={batch}")


def test_unpacked_one_sector_batches_regression():
    """The reproducer: unpacked AX3 read one sector at a time used to keep views into the reused
    read buffer (3,120 of 3,200 rows wrong)."""
    ref = snapshot(CwaReader(FUZZ / "ax3_unpacked_40_sectors.cwa"))
    one = snapshot(CwaReader(FUZZ / "ax3_unpacked_40_sectors.cwa", batch_sectors=1))
    assert ref["accel"].shape == (3200, 3)
    np.testing.assert_array_equal(ref["accel"], one["accel"])


def _damage(data: bytearray, rng, n: int) -> None:
    for _ in range(n):
        i = int(rng.integers(0, len(data)))
        data[i] ^= 1 << int(rng.integers(0, 8))


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 10_000), batch=st.integers(1, 9), flips=st.integers(0, 6),
       kind=st.sampled_from(["packed", "unpacked", "ax6", "ax6_accel"]))
def test_cwa_damaged_property(tmp_path, seed, batch, flips, kind):
    from stillpoint.drivers.cwa_writer import CwaWriter
    rng = np.random.default_rng(seed)
    n = 120 * 12
    t = 1_700_000_000_000_000_000 + np.rint(np.arange(n) * 1e7).astype(np.int64)
    a = rng.integers(-511, 512, (n, 3)) * 4
    p = tmp_path / f"{kind}_{seed}_{batch}_{flips}.cwa"
    kw = {"packed": dict(packed=True), "unpacked": dict(packed=False),
          "ax6": dict(device_type="AX6", gyro_range_dps=500),
          "ax6_accel": dict(device_type="AX6")}[kind]
    w = CwaWriter(p, rate_hz=100, **kw)
    g = rng.integers(-2000, 2000, (n, 3)) if kind == "ax6" else None
    w.write(t, a, gyro_counts=g) if g is not None else w.write(t, a)
    w.close()
    data = bytearray(p.read_bytes())
    body = data[1024:]
    _damage(body, rng, flips)
    p.write_bytes(bytes(data[:1024] + body))
    try:
        ref = snapshot(CwaReader(p))
    except Exception as e:  # the same typed error for every batch size
        with pytest.raises(type(e)):
            snapshot(CwaReader(p, batch_sectors=batch))
        return
    assert_same(ref, snapshot(CwaReader(p, batch_sectors=batch)), f"{kind} batch={batch}")


def _bin(path, pages=8, rate=50.0):
    n = pages * 300
    rng = np.random.default_rng(3)
    t = 1_600_000_000_000_000_000 + np.round(np.arange(n) * 1e9 / rate).astype(np.int64)
    w = GeneactivWriter(path, rate_hz=rate)
    w.write(t, rng.integers(-2048, 2048, (n, 3)))
    w.close()


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 10_000), batch=st.integers(1, 5), flips=st.integers(0, 8))
@example(seed=239, batch=1, flips=2)  # page 1's data-line CR -> 0x0F: accepted only by the fast path
@example(seed=132, batch=2, flips=7)  # page 7's Page Time ":000" -> ":00 ": read as 0 ms by the general parser
def test_geneactiv_damaged_property(tmp_path, seed, batch, flips):
    p = tmp_path / f"g_{seed}_{batch}_{flips}.bin"
    _bin(p)
    data = bytearray(p.read_bytes())
    rng = np.random.default_rng(seed)
    start = data.find(b"Recorded Data")
    body = data[start:]
    _damage(body, rng, flips)
    p.write_bytes(bytes(data[:start] + body))
    try:
        ref = snapshot(GeneactivReader(p))
    except Exception as e:
        with pytest.raises(type(e)):
            snapshot(GeneactivReader(p, batch_pages=batch))
        return
    assert_same(ref, snapshot(GeneactivReader(p, batch_pages=batch)), f"batch={batch}")


GNA_FILES = ["geneactiv_temperature_inf.bin", "geneactiv_pagetime_1960.bin",
             "geneactiv_page_freq_tiny.bin"]


@pytest.mark.parametrize("name", GNA_FILES)
@pytest.mark.parametrize("batch", [1, 2, 3])
def test_geneactiv_batch_size_does_not_change_results(name, batch):
    ref = snapshot(GeneactivReader(FUZZ / name))
    assert_same(ref, snapshot(GeneactivReader(FUZZ / name, batch_pages=batch)), f"{name} batch={batch}")


REAL_CWA = ["ax6_ggirread_testfile_100hz_16g_gyro250dps.cwa",  # an axis-swap run (AX6 fw < 56)
            "ax3_ggirread_corrupt_blocks_0_13_14_142_143_144.cwa",
            "ax6_skdh_sample_100hz_16g_gyro2000dps.cwa"]


@pytest.mark.parametrize("name", REAL_CWA)
@pytest.mark.parametrize("batch", [1, 3, 7])
def test_real_cwa_batch_size_does_not_change_results(real_file, name, batch):
    """Samples and QC events (times included) of real files, whatever the batch size; the
    axis-swap event is logged when its run ends, blocks after its first sector was emitted."""
    path = real_file(name)
    ref = snapshot(CwaReader(path))
    got = snapshot(CwaReader(path, batch_sectors=batch))
    assert_same(ref, got, f"{name} batch={batch}")
    if name.startswith("ax6_ggirread"):
        assert [q[1] for q in ref["qc"]] == ["axis_swap"]
