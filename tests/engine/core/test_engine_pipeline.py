"""Pipeline: bounded block cutting, stage wiring, progress; interpolator edge cases."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings, strategies as st

from stillpoint.engine.core.blocks import Block, DeviceInfo, QCReport
from stillpoint.engine.features import WindowFeatures
from stillpoint.engine.operators.correction import CorrectedBatch, TemperatureInterpolator
from stillpoint.engine.operators.windows import WindowFeaturesOperator
from stillpoint.engine.core.pipeline import Pipeline, split_block

from synthetic_blocks import RATE, assert_features_equal, run_op, synth_segments


class ListSource:
    def __init__(self, blocks):
        self.blocks = blocks
        self.info = DeviceInfo("AX3", "1", 0, "t", RATE, 8.0)
        self.qc = QCReport("sector")

    def __iter__(self):
        return iter(self.blocks)

    def close(self):
        pass


class Collect:
    def __init__(self):
        self.op = WindowFeaturesOperator(RATE)
        self.out = []
        self.sizes = []

    def push(self, b):
        self.sizes.append(b.n)
        self.out.append(self.op.push(b))

    def flush(self):
        self.out.append(self.op.flush())


@settings(max_examples=30, deadline=None)
@given(st.integers(50, 5000))
def test_split_block_bounds_size_and_keeps_units_whole(max_samples):
    b = synth_segments(seconds=(95.0,))[0]
    parts = split_block(b, max_samples)
    assert sum(p.n for p in parts) == b.n
    assert all(p.n <= max_samples for p in parts)
    joined = Block.concat(parts)
    assert np.array_equal(joined.time_ns, b.time_ns) and np.array_equal(joined.accel, b.accel)
    if max_samples >= 120:  # units of 120 samples are never cut
        assert np.array_equal(joined.unit_index, b.unit_index)


def test_pipeline_runs_stages_with_bounded_blocks_and_progress():
    blocks = synth_segments()
    seen = []
    c = Collect()
    stats = Pipeline(ListSource(blocks), [c], rate_hz=RATE, max_block_s=7.0).run(
        progress=lambda st: seen.append(st.samples))
    assert max(c.sizes) <= 700
    assert stats.samples == sum(b.n for b in blocks) and seen[-1] == stats.samples
    assert stats.segments == {0, 1}
    ref = WindowFeatures.concat(run_op(WindowFeaturesOperator(RATE), blocks))
    assert_features_equal(WindowFeatures.concat(c.out), ref)


def test_interpolator_handles_blocks_without_units_and_single_unit_blocks():
    b = synth_segments(seconds=(30.0,))[0]
    ti = TemperatureInterpolator()
    out = []
    for k in range(0, b.n, 60):  # every block lies inside one unit
        out += ti.push(b.slice(k, k + 60))
    out += ti.flush()
    c = CorrectedBatch.concat(out)
    assert np.array_equal(c.time_ns, b.time_ns)
    assert np.all(np.isfinite(c.temperature))
    bare = Block(time_ns=b.time_ns[:500], accel=b.accel[:500], accel_counts_per_g=b.accel_counts_per_g,
                 accel_zero=b.accel_zero)
    ti = TemperatureInterpolator()
    c = CorrectedBatch.concat(ti.push(bare) + ti.flush())
    assert c.n == 500 and np.all(np.isnan(c.temperature))
