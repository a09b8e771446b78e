"""Reading a .cwa without per-sample times (``sample_times=False``) and into column-major counts
(``column_major=True``): each Block's clock gives the same times the reader computes per
sample, the counts are the same, the window features are cut at the same samples and the
calibration is the same, on clean files, damaged files, gaps, restarts, jittered and jumping
sector times, any batch size."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from stillpoint.drivers.cwa import CwaReader, CwaWriter, corrupt_sector, patch_sector
from stillpoint.drivers.cwa_decode import SampleClock, interpolate_times
from stillpoint.engine.features import WindowFeatures
from stillpoint.engine.operators.windows import WindowFeaturesOperator

FUZZ = Path(__file__).parents[1] / "data" / "fuzz"
FUZZ_CWA = ["ax3_unpacked_40_sectors.cwa", "ax3_3200hz_anchor_back_52ms.cwa",
            "ax6_mixed_0x62_0x32_sector.cwa", "ax3_header_6p25hz_sectors_3200hz.cwa",
            "ax3_truncated.cwa.gz", "ax3_corrupt_deflate.cwa.gz"]
REAL_CWA = ["ax3_ggirread_corrupt_blocks_0_13_14_142_143_144.cwa",
            "ax3_ggirread_testfile_100hz_145blocks.cwa",
            "ax3_openmovement_example_610_steps_fw30_nofrac.cwa",
            "ax3_oxwearables_tiny_sample_3h_with_restart.cwa.gz",
            "ax3_skdh_sample_200hz_490blocks.cwa",
            "ax6_ggirread_testfile_100hz_16g_gyro250dps.cwa",
            "ax6_skdh_sample_100hz_16g_gyro2000dps.cwa"]
T0 = 1_700_000_000_000_000_000


# ----------------------------------------------------------------------------- the clock alone
def _clock(rng, n_anchors: int, closed: bool, j0: int, n: int) -> SampleClock:
    g = np.cumsum(rng.integers(60, 180, n_anchors)).astype(np.int64)
    t = np.cumsum(rng.normal(1e7, 2e5, n_anchors) * np.diff(np.append(0, g))).round()
    t_rel = t - t[0]
    s_first = (t_rel[1] - t_rel[0]) / (g[1] - g[0]) if n_anchors > 1 else 1e7
    s_last = (t_rel[-1] - t_rel[-2]) / (g[-1] - g[-2]) if n_anchors > 1 else 1e7
    return SampleClock(j0, n, g, t_rel.astype(np.float64), s_first, s_last, closed, T0 + 12_345)


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("n_anchors,closed", [(1, True), (2, True), (9, False), (9, True)])
def test_clock_times_and_search_match_the_per_sample_times(seed, n_anchors, closed):
    rng = np.random.default_rng(seed)
    c0 = _clock(rng, n_anchors, closed, 0, 0)
    last = int(c0.g[-1]) + (300 if closed else 1)
    j0 = int(rng.integers(0, 50))
    c = SampleClock(j0, last - j0, c0.g, c0.t_rel, c0.slope_first, c0.slope_last, closed,
                    c0.origin)
    rel = interpolate_times(j0, last, c.g, c.t_rel, c.slope_first, c.slope_last, closed)
    full = np.rint(rel).astype(np.int64) + c.origin
    assert np.array_equal(c.times(), full)
    rows = rng.integers(0, c.n, 50)
    assert np.array_equal(c.at(rows), full[rows])
    assert int(c.at(np.int64(3))) == full[3]
    edges = np.concatenate([full[rows], full[rows] - 1, full[rows] + 1, [full[0] - 10**9],
                            [full[-1] + 10**9], rng.integers(full[0], full[-1], 200)])
    assert np.array_equal(c.search(edges), np.searchsorted(full, edges, side="left"))


# ----------------------------------------------------------------------------- reader
def _read(path, **kw):
    """Blocks' times (from time_ns or the clock), segments, sizes and the QC log."""
    r = CwaReader(path, **kw)
    blocks = list(r)
    times = [b.time_ns if b.time_ns is not None else b.clock.times() for b in blocks]
    assert all((b.time_ns is None) == (kw.get("sample_times") is False) for b in blocks)
    if kw.get("column_major"):  # each axis contiguous
        assert all(b.accel.strides[0] == b.accel.itemsize for b in blocks if b.n > 1)
    return {"time": np.concatenate(times) if times else None,
            "segment": np.concatenate([np.full(b.n, b.segment) for b in blocks]) if blocks else None,
            "accel": np.concatenate([b.accel for b in blocks]) if blocks else None,
            "gyro": np.concatenate([b.gyro for b in blocks]) if blocks and blocks[0].gyro is not None
            else None,
            "qc": [(e.index, e.reason, e.time_ns, e.samples) for e in r.qc.events]}


def _features(path, **kw) -> WindowFeatures:
    op = WindowFeaturesOperator(rate_hz=CwaReader(path).info.sample_rate_nominal)
    parts = [op.push(b) for b in CwaReader(path, **kw)]
    parts.append(op.flush())
    return WindowFeatures.concat(parts)


def _assert_same_features(a: WindowFeatures, b: WindowFeatures) -> None:
    for f in ("start_ns", "n", "mean", "sd", "temperature", "norm_mean", "segment"):
        x, y = getattr(a, f), getattr(b, f)
        assert x.dtype == y.dtype and x.shape == y.shape, f
        assert np.array_equal(x.view(np.uint8), y.view(np.uint8)), f  # same bits, NaN included


def _assert_reader_and_features_agree(path, batches=(1, 3, 2048)) -> None:
    try:
        ref = _read(path)
    except Exception as e:  # the same typed error without per-sample times
        with pytest.raises(type(e)):
            _read(path, sample_times=False)
        return
    for batch in batches:
        ref = _read(path, batch_sectors=batch)
        for column_major in (False, True):
            got = _read(path, sample_times=False, batch_sectors=batch, column_major=column_major)
            assert got["qc"] == ref["qc"], batch
            assert np.array_equal(got["segment"], ref["segment"]), batch
            assert np.array_equal(got["time"], ref["time"]), batch
            assert np.array_equal(got["accel"], ref["accel"]), batch
            assert (got["gyro"] is None) == (ref["gyro"] is None), batch
            assert got["gyro"] is None or np.array_equal(got["gyro"], ref["gyro"]), batch
            _assert_same_features(_features(path, sample_times=False, batch_sectors=batch,
                                            column_major=column_major), _features(path))


@pytest.mark.parametrize("name", FUZZ_CWA)
def test_fuzz_files_without_sample_times(name):
    _assert_reader_and_features_agree(FUZZ / name)


@pytest.mark.parametrize("name", REAL_CWA)
def test_real_files_without_sample_times(real_file, tmp_path, name):
    _assert_reader_and_features_agree(real_file(name), batches=(7, 2048))


def _irregular(path: Path, rng, *, restart: bool, gap_s: float, jitter: float, jump_s: float,
               packed: bool = True) -> None:
    """A recording with a drifting, jittered clock, a gap, an optional restart and a time jump."""
    w = CwaWriter(path, rate_hz=100, packed=packed)
    n = 120 * 60
    t = T0 + np.cumsum(rng.normal(1e7 * 1.004, 1e7 * jitter, n).clip(1e6)).astype(np.int64)
    a = rng.integers(-255, 256, (n, 3)) * 4
    temp = np.repeat(rng.integers(200, 330, n // 120 + 1), 120)[:n]
    k = n // 3
    w.write(t[:k], a[:k], temperature_raw=temp[:k])
    shift = int(gap_s * 1e9)
    if restart:
        w.restart()
    w.write(t[k:2 * k] + shift, a[k:2 * k], temperature_raw=temp[k:2 * k])
    w.write(t[2 * k:] + shift + int(jump_s * 1e9), a[2 * k:], temperature_raw=temp[2 * k:])
    w.close()


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 10_000), restart=st.booleans(), gap_s=st.sampled_from([0.0, 3.3, 40.0]),
       jitter=st.sampled_from([0.0, 0.002, 0.02]), jump_s=st.sampled_from([0.0, 0.4, 25.0]),
       bad=st.lists(st.integers(0, 59), max_size=3), moved=st.lists(st.integers(0, 59), max_size=3),
       packed=st.booleans())
def test_irregular_recordings_without_sample_times(tmp_path, seed, restart, gap_s, jitter, jump_s,
                                                   bad, moved, packed):
    """Besides the writer's clock: sectors whose anchor was moved (fraction of the second or
    sample offset rewritten: time jumps backwards, bad anchors), removed (timestamp 0) or
    damaged."""
    rng = np.random.default_rng(seed)
    p = tmp_path / f"irregular_{seed}.cwa"
    _irregular(p, rng, restart=restart, gap_s=gap_s, jitter=jitter, jump_s=jump_s, packed=packed)
    cap = 120 if packed else 80
    for i, s in enumerate(sorted(set(moved))):
        if i % 3 == 1:
            patch_sector(p, s, timestamp_offset=int(rng.integers(-cap, cap)))
        elif i % 3 == 2:
            patch_sector(p, s, timestamp=0)  # no usable anchor: timed from the neighbours
        else:
            patch_sector(p, s, device_fractional=0x8000 | int(rng.integers(0, 0x8000)))
    for i, s in enumerate(sorted(set(bad))):
        corrupt_sector(p, s, ("checksum", "timestamp", "erase")[i % 3])
    _assert_reader_and_features_agree(p, batches=(1, 5, 2048))


# ----------------------------------------------------------------------------- calibration
def test_calibration_is_the_same_without_sample_times(tmp_path):
    from stillpoint.engine.calibration.recording import calibrate_recording

    p = tmp_path / "cal.cwa"
    _irregular(p, np.random.default_rng(5), restart=True, gap_s=40.0, jitter=0.002, jump_s=25.0)
    a = calibrate_recording(p, read_all=True, open_options={"sample_times": True,
                                                            "column_major": False})
    b = calibrate_recording(p, read_all=True)  # a .cwa is read without per-sample times
    assert a.estimate.to_dict() == b.estimate.to_dict()
    _assert_same_features(a.windows, b.windows)
    assert (a.samples, a.windows_total) == (b.samples, b.windows_total)


# ----------------------------------------------------------------------------- per-unit columns
def test_temperature_summed_per_sector_is_the_per_sample_sum():
    """Window temperatures from the sectors' values times their samples in the window: the bits
    of summing the per-sample values, for any cut of the rows into windows; held rows are the
    per-sample values."""
    from stillpoint.drivers.constants import cwa_temperature_c
    from stillpoint.engine.operators.binning import held_per_sample, unit_bin_sums
    from stillpoint.engine.operators.windows import exact_unit_sums

    rng = np.random.default_rng(2)
    for _ in range(50):
        m = int(rng.integers(1, 300))
        counts = rng.integers(1, 121, m)
        unit_start = np.concatenate([[0], np.cumsum(counts[:-1])]).astype(np.int64)
        n = int(counts.sum())
        temp = cwa_temperature_c(rng.integers(1, 1024, m))
        assert exact_unit_sums(unit_start, temp, n)
        per_sample = np.repeat(temp, counts)
        stop = int(rng.integers(1, n + 1))
        starts = np.unique(np.concatenate([[0], rng.integers(0, stop, int(rng.integers(0, 40)))]))
        got = unit_bin_sums(unit_start, temp, starts, stop)
        want = np.add.reduceat(per_sample[:stop], starts)
        assert np.array_equal(got, want)
        a = int(rng.integers(0, n))
        b = int(rng.integers(a, n + 1))
        assert np.array_equal(held_per_sample(unit_start, temp, a, b, n), per_sample[a:b])
        assert np.array_equal(held_per_sample(unit_start, temp, a, n, n), per_sample[a:])
    one = np.zeros(1, np.int64)
    assert not exact_unit_sums(one, np.array([np.nan]), 10)  # no temperature: summed per sample
    assert not exact_unit_sums(one, np.array([25.3]), 10)  # not on the 2^-8 grid
    assert not exact_unit_sums(one, np.array([2048.0]), 10)
    assert not exact_unit_sums(np.array([5]), np.array([25.0]), 10)


def test_window_features_alike_with_temperature_per_sample(monkeypatch):
    """The operator's window temperatures (and every other feature) with the per-sector sums
    and with the per-sample values, on a file with a gap, a restart and moved anchors."""
    import stillpoint.engine.operators.windows as W

    p = FUZZ / "ax3_3200hz_anchor_back_52ms.cwa"
    for kw in ({}, {"sample_times": False, "batch_sectors": 3}):
        units = _features(p, **kw)
        monkeypatch.setattr(W, "exact_unit_sums", lambda *a: False)
        per_sample = _features(p, **kw)
        monkeypatch.undo()
        _assert_same_features(units, per_sample)


@pytest.mark.parametrize("mode", ["batch", "online"])
@pytest.mark.parametrize("name", ["ax3_oxwearables_tiny_sample_3h_with_restart.cwa.gz",
                                  "ax3_ggirread_corrupt_blocks_0_13_14_142_143_144.cwa",
                                  "ax6_ggirread_testfile_100hz_16g_gyro250dps.cwa"])
def test_process_reads_cwa_column_major_and_pass_one_without_sample_times(real_file, tmp_path,
                                                                          monkeypatch, name, mode):
    """process reads a .cwa column-major, and a batch run's pass 1 with the sample clock (no
    per-sample times, blocks as the reader gives them); its log is the one the per-sample,
    row-major read writes, byte for byte."""
    from stillpoint.engine import run as run_mod

    seen = []  # per block: (no per-sample times, each axis contiguous)
    push = run_mod.FeatureStage.push

    def spy(self, block):
        if block.n > 1:
            seen.append((block.time_ns is None, block.accel.strides[0] == block.accel.itemsize))
        return push(self, block)

    monkeypatch.setattr(run_mod.FeatureStage, "push", spy)
    out = tmp_path / "run.mcap"
    run_mod.process_file(real_file(name), out, run_mod.RunSettings(mode=mode), writer="inline")
    fast = out.read_bytes()
    assert seen and all(cm for _clock, cm in seen)
    assert all(clock for clock, _cm in seen) == (mode == "batch")
    seen.clear()
    # the reader's own defaults, but the output passes' batch size (it decides where blocks, and
    # so raw messages, are cut)
    from stillpoint.engine.run import inputs, tuning
    monkeypatch.setattr(inputs, "reader_options", lambda fmt, opts, features_only=False, tables=False: (
        opts if features_only else dict(opts, batch_sectors=tuning.TABLES_PASS_SECTORS if tables
                                        else tuning.OUTPUT_BATCH_SECTORS)))
    run_mod.process_file(real_file(name), out, run_mod.RunSettings(mode=mode), writer="inline")
    assert seen and not any(clock or cm for clock, cm in seen)
    assert out.read_bytes() == fast
