"""Correction, streaming filters and epoch metrics: correctness and chunk invariance."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings, strategies as st
from scipy import signal

from stillpoint.engine.calibration.estimate import CalibrationEstimate
from stillpoint.engine.operators.correction import CorrectedBatch, CorrectionOperator
from stillpoint.engine.operators.filters import SosStream, band_used, bandpass_sos
from stillpoint.engine.operators.metrics import EpochMetrics, MetricsOperator

from synthetic_blocks import RATE, recut, run_op, synth_segments

EST = CalibrationEstimate(offset=[-0.02, 0.03, -0.05], scale=[0.99, 1.01, 1.0],
                          tempoffset=[0.001, -0.0005, 0.002], temperature_ref=26.0, status="ok")


def corrected(blocks, est=EST, gate=None):
    op = CorrectionOperator(est, rate_hz=RATE, gate=gate)
    out = [b for item in run_op(op, blocks) for b in item]
    return out


def cat(batches):
    by_seg = {}
    for b in batches:
        by_seg.setdefault(b.segment, []).append(b)
    return {s: CorrectedBatch.concat(v) for s, v in by_seg.items()}


def reference_temperature(block):
    """Unit temperature at each unit's last sample, linear in between, held before the first."""
    ends = np.append(block.unit_start[1:], block.n) - 1
    rel = lambda t: (t - block.time_ns[0]).astype(float)
    return np.interp(rel(block.time_ns), rel(block.time_ns[ends]), block.temperature_c)


def test_correction_applies_model_with_interpolated_temperature():
    blocks = synth_segments()
    got = cat(corrected(recut(blocks, "unit")))
    for b in blocks:
        c = got[b.segment]
        assert np.array_equal(c.time_ns, b.time_ns)
        temp = reference_temperature(b)
        assert np.allclose(c.temperature, temp, atol=1e-9)
        # temperature really is interpolated: values strictly between two unit readings exist
        assert len(np.setdiff1d(np.round(c.temperature, 6), np.round(b.temperature_c, 6))) > 0
        want = (b.accel_g() + EST.offset) * EST.scale + (temp - 26.0)[:, None] * EST.tempoffset
        assert np.allclose(c.accel, want, atol=1e-12)


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 10_000))
def test_correction_independent_of_block_cuts(seed):
    blocks = synth_segments(seed=seed % 5)
    ref = cat(corrected(recut(blocks, "whole")))
    for how in ("unit", "random"):
        got = cat(corrected(recut(blocks, how, seed)))
        for s in ref:
            assert np.array_equal(got[s].time_ns, ref[s].time_ns)
            assert np.array_equal(got[s].accel, ref[s].accel)
            assert np.array_equal(got[s].temperature, ref[s].temperature)


def test_correction_uses_estimate_in_force_and_gate():
    blocks = synth_segments(seconds=(60.0,))
    t_switch = int(blocks[0].time_ns[3000])
    later = CalibrationEstimate(offset=[0.1, 0.1, 0.1], effective_from_ns=t_switch, status="ok")
    gate_at = {"t": int(blocks[0].time_ns[0])}
    op = CorrectionOperator(EST, rate_hz=RATE, gate=lambda: gate_at["t"])
    out = []
    for i, b in enumerate(recut(blocks, "unit")):
        if i == 10:
            op.add_estimate(later)
        gate_at["t"] = int(b.time_ns[0])  # schedule final only up to the start of this block
        out += op.push(b)
        assert all(int(c.time_ns[-1]) < gate_at["t"] for c in out)
    out += op.flush()
    c = CorrectedBatch.concat(out)
    assert c.n == blocks[0].n
    raw = blocks[0].accel_g()
    assert np.allclose(c.accel[3000:], raw[3000:] + 0.1, atol=1e-12)
    assert not np.allclose(c.accel[:3000], raw[:3000] + 0.1, atol=1e-3)


def test_schedule_applies_per_sample_estimates_bit_for_bit_whatever_the_batch():
    """A batch between two changes takes one estimate whole; one that spans a change, touches
    its first nanosecond or ends just before it is corrected sample by sample: the numbers
    are the per-sample rule's in every case."""
    from stillpoint.engine.operators.correction import EstimateSchedule
    rng = np.random.default_rng(7)
    n = 4000
    t = np.arange(n, dtype=np.int64) * 10_000_000 + 1_700_000_000_000_000_000
    accel = rng.normal(size=(n, 3))
    temp = 25.0 + rng.normal(size=n)
    changes = [int(t[1000]), int(t[1000]) + 1, int(t[2500]) + 5_000_000]
    sched = EstimateSchedule(EST)
    ests = [EST]
    for k, at in enumerate(changes):
        e = CalibrationEstimate(offset=[0.01 * (k + 1)] * 3, scale=[1.0 + 0.01 * k] * 3,
                                tempoffset=[0.001, 0.0, -0.001], temperature_ref=25.0,
                                effective_from_ns=at, status="ok")
        sched.add(e)
        ests.append(e)
    eff = np.array([np.iinfo(np.int64).min] + changes, np.int64)
    which = np.searchsorted(eff, t, side="right") - 1
    want = np.empty((n, 3))
    for i, e in enumerate(ests):
        m = which == i
        want[m] = e.apply(accel[m], temp[m])
    for a, b in [(0, 1000), (0, 1001), (999, 1001), (1000, 1001), (1001, 2500), (1200, 2400),
                 (2400, 2600), (2501, n), (2502, n), (0, n), (3000, 3001)]:
        got = sched.apply(CorrectedBatch(t[a:b], accel[a:b], temp[a:b], 0))
        assert np.array_equal(got.accel, want[a:b]), (a, b)
    shuffled = rng.permutation(np.arange(900, 1100))  # times out of order: still per sample
    got = sched.apply(CorrectedBatch(t[shuffled], accel[shuffled], temp[shuffled], 0))
    assert np.array_equal(got.accel, want[shuffled])


def test_streaming_filter_equals_scipy_on_whole_signal():
    rng = np.random.default_rng(1)
    x = rng.normal(size=(5003, 3))
    for rate, band in ((100.0, (0.2, 15)), (600 / 7, (0.5, 15)), (20.0, (0.2, 15))):
        sos = bandpass_sos(rate, band)
        whole = signal.sosfilt(sos, x, axis=0)
        f = SosStream(sos)
        cuts = np.sort(rng.integers(0, len(x), size=17))
        pieces = [f.push(p) for p in np.split(x, cuts)]
        assert np.array_equal(np.concatenate(pieces), whole)
    assert band_used(20.0) == (0.2, 9.0)


def test_bandpass_design_has_scipy_butter_response_and_state_layout():
    for rate, band in ((100.0, (0.2, 15.0)), (600 / 7, (0.2, 15.0)), (20.0, (0.2, 9.0)),
                       (200.0, (0.5, 15.0))):
        ours = bandpass_sos(rate, band)
        ref = signal.butter(4, band, "bandpass", fs=rate, output="sos")
        _w, h1 = signal.sosfreqz(ours, 2048, fs=rate)
        _w, h2 = signal.sosfreqz(ref, 2048, fs=rate)
        assert np.max(np.abs(h1 - h2)) < 1e-9, (rate, band)
    # the state reads back in scipy's (sections, 2, channels) layout and continues scipy's filter
    x = np.random.default_rng(3).normal(size=(1000, 3))
    f = SosStream(bandpass_sos(100.0))
    f.push(x[:600])
    y2, _zi = signal.sosfilt(f.sos, x[600:], axis=0, zi=f.zi)
    assert np.array_equal(f.push(x[600:]), y2)


def test_engine_start_up_does_not_import_scipy_signal():
    import subprocess
    import sys
    code = ("import sys; import stillpoint.engine.run; "
            "print('scipy.signal' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def metrics_of(batches, band=(0.2, 15.0)):
    return EpochMetrics.concat(run_op(MetricsOperator(RATE, band=band), batches))


def test_metrics_match_direct_computation():
    blocks = synth_segments()
    c = cat(corrected(blocks))
    m = metrics_of(corrected(recut(blocks, "random", 3)))
    sos = bandpass_sos(RATE)
    rows = []
    for s, b in sorted(c.items()):
        r = np.linalg.norm(b.accel, axis=1)
        bf = np.linalg.norm(signal.sosfilt(sos, b.accel, axis=0), axis=1)
        e = b.time_ns // (5 * 10**9)
        for k in np.unique(e):
            i = e == k
            rows.append((k * 5 * 10**9, i.sum(), np.maximum(r[i] - 1, 0).mean() * 1000,
                         bf[i].mean() * 1000, np.abs(r[i] - r[i].mean()).mean() * 1000, s))
    assert len(m) == len(rows)
    assert np.array_equal(m.start_ns, [r[0] for r in rows])
    assert np.array_equal(m.n, [r[1] for r in rows])
    for j, name in ((2, "enmo_mg"), (3, "bfen_mg"), (4, "mad_mg")):
        assert np.allclose(getattr(m, name), [r[j] for r in rows], atol=1e-9), name
    assert np.all(m.enmo_mg >= 0) and m.enmo_mg.max() > 10
    # epochs sit on the UTC 5 s grid and an epoch cut by the gap gives one row per segment
    assert np.all(m.start_ns % (5 * 10**9) == 0)
    assert np.array_equal(m.segment, [r[5] for r in rows])


def test_metrics_band_choice_matters():
    blocks = synth_segments()
    c = corrected(blocks)
    a, b = metrics_of(c, (0.2, 15.0)), metrics_of(c, (0.5, 15.0))
    assert not np.allclose(a.bfen_mg, b.bfen_mg)
    assert np.array_equal(a.enmo_mg, b.enmo_mg)


@settings(max_examples=20, deadline=None)
@given(st.integers(0, 10_000))
def test_metrics_independent_of_block_cuts(seed):
    blocks = synth_segments(seed=seed % 5)
    ref = metrics_of(corrected(recut(blocks, "whole")))
    for how in ("unit", "random"):
        m = metrics_of(corrected(recut(blocks, how, seed)))
        for name in ("start_ns", "n", "enmo_mg", "bfen_mg", "mad_mg", "mean", "temperature", "segment"):
            assert np.array_equal(getattr(m, name), getattr(ref, name), equal_nan=True), name


@settings(max_examples=30, deadline=None)
@given(st.lists(st.integers(0, 3000), max_size=12), st.sampled_from([(0.2, 15.0), (0.5, 15.0)]))
def test_streaming_filter_independent_of_cuts(cuts, band):
    x = np.random.default_rng(len(cuts)).normal(size=(3000, 3))
    sos = bandpass_sos(RATE, band)
    f = SosStream(sos)
    y = np.concatenate([f.push(p) for p in np.split(x, sorted(cuts))])
    assert np.array_equal(y, signal.sosfilt(sos, x, axis=0))


def test_column_helpers_are_bit_identical_to_the_broadcast_forms():
    from stillpoint.engine.calibration.estimate import CalibrationEstimate
    from stillpoint.engine.core.blocks import Block
    from stillpoint.engine.operators.base import accel_g_columns, apply_columns
    rng = np.random.default_rng(8)
    n = 5000
    blk = Block(time_ns=np.arange(n, dtype=np.int64) * 10**7,
                accel=rng.integers(-2000, 2000, (n, 3)).astype(np.int16),
                accel_counts_per_g=np.array([256.0, 250.5, 260.25]),
                accel_zero=np.array([1.5, -2.0, 0.25]))
    g = accel_g_columns(blk)
    assert np.array_equal(g, blk.accel_g())
    temp = 20 + rng.random(n) * 10
    for tempoffset in ([0.0, 0.0, 0.0], [1e-3, -2e-3, 5e-4]):
        est = CalibrationEstimate(offset=[0.01, -0.02, 0.03], scale=[0.99, 1.01, 1.002],
                                  tempoffset=tempoffset, temperature_ref=25.0)
        assert np.array_equal(apply_columns(est, g, temp), est.apply(g, temp))
    temp[7] = np.nan  # no temperature term: NaN temperatures do not reach the output
    est0 = CalibrationEstimate(offset=[0.01, 0, 0], scale=[1, 1, 1], tempoffset=[0, 0, 0])
    assert np.isfinite(apply_columns(est0, g, temp)).all()


def test_every_operator_is_a_pipeline_operator():
    import importlib
    import pkgutil

    import stillpoint.engine.operators as ops
    from stillpoint.engine.core.pipeline import Operator
    found = [cls for m in pkgutil.iter_modules(ops.__path__)
             for name, cls in vars(importlib.import_module(f"{ops.__name__}.{m.name}")).items()
             if name.endswith("Operator") and isinstance(cls, type)
             and cls.__module__.startswith(ops.__name__)]
    assert len(found) >= 8
    assert [c.__name__ for c in found if not issubclass(c, Operator)] == []
