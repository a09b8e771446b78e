"""Synthetic Blocks for the engine tests, built directly from engine/core/blocks.py (no reader
needed): segments with still periods in several orientations, movement bursts, per-unit
temperature and a gap between segments; cutting them differently; running an operator over them;
comparing window features field by field."""

from __future__ import annotations

import numpy as np

from stillpoint.engine.core.blocks import Block
from stillpoint.engine.features import WindowFeatures

RATE = 100.0
UNIT = 120


def synth_segments(seed=0, seconds=(95.0, 47.3), rate=RATE, unit=UNIT, t0_ns=1_700_000_000_123_456_789,
                   offset=(0.02, -0.03, 0.05), gain=(1.01, 0.99, 1.0), noise_g=0.004, gyro=False):
    """One Block per segment (a sequence of units of ``unit`` samples), with still periods in
    several orientations, movement bursts, per-unit temperature and a gap between segments."""
    rng = np.random.default_rng(seed)
    blocks = []
    t = t0_ns
    first = 0
    uidx = 0
    for seg, dur in enumerate(seconds):
        n = int(dur * rate)
        n -= n % unit if n > unit else 0
        period = 1e9 / rate * (1 + rng.normal(0, 2e-5))
        times = t + np.round(np.arange(n) * period).astype(np.int64)
        # piecewise-constant orientations, 4 s each, plus movement bursts
        k = np.arange(n) // int(4 * rate)
        dirs = rng.normal(size=(k.max() + 1, 3))
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        g = dirs[k]
        moving = (k % 3 == 2)[:, None]
        g = g + moving * rng.normal(0, 0.3, size=g.shape)
        g = (g / np.asarray(gain) - np.asarray(offset)) + rng.normal(0, noise_g, size=g.shape)
        counts = np.clip(np.round(g * 256), -32768, 32767).astype(np.int16)
        m = -(-n // unit)
        ustart = np.arange(m, dtype=np.int64) * unit
        temp_raw = (260 + np.round(3 * np.sin(np.arange(m) / 7.0 + seg))).astype(np.int32)
        b = Block(time_ns=times, accel=counts, accel_counts_per_g=np.full(3, 256.0),
                  accel_zero=np.zeros(3),
                  gyro=(rng.integers(-500, 500, size=(n, 3)).astype(np.int16) if gyro else None),
                  gyro_dps_per_count=(2000 / 32768 if gyro else None),
                  unit_index=np.arange(uidx, uidx + m, dtype=np.int64),
                  unit_sequence=np.arange(uidx, uidx + m, dtype=np.int64) + 1000,
                  unit_start=ustart, temperature_c=temp_raw * 75 / 256 - 50,
                  temperature_raw=temp_raw, light=np.full(m, 300, np.int32),
                  battery_v=np.full(m, 4.1), events=np.zeros(m, np.uint8),
                  segment=seg, first_sample=first)
        blocks.append(b)
        first += n
        uidx += m + 1  # one skipped unit between segments
        t = int(times[-1]) + 3 * 10**9
    return blocks


def recut(blocks, how, seed=0):
    """Cut segment blocks differently: "whole", "unit" (per sector) or "random"."""
    rng = np.random.default_rng(seed)
    out = []
    for b in blocks:
        if how == "whole":
            out.append(b)
            continue
        if how == "unit":
            edges = list(b.unit_start[1:]) + [b.n]
        else:
            k = rng.integers(0, max(2, b.n // 50))
            edges = sorted(set(rng.integers(1, b.n, size=k).tolist())) + [b.n]
        s = 0
        for e in edges:
            out.append(b.slice(s, int(e)))
            s = int(e)
    return out


def run_op(op, items):
    outs = [op.push(i) for i in items]
    outs.append(op.flush())
    return outs


def assert_features_equal(a: WindowFeatures, b: WindowFeatures):
    assert len(a) == len(b)
    for name in ("start_ns", "n", "mean", "sd", "temperature", "norm_mean", "segment"):
        x, y = getattr(a, name), getattr(b, name)
        assert np.array_equal(x, y, equal_nan=True), name


def push_in_pieces(op, tn, a, cuts=(), segments=None) -> list:
    """Push (times ``tn``, g ``a``) into an operator taking ``CorrectedBatch`` es, cut at the sample
    indices ``cuts`` and wherever ``segments`` (one id per sample) changes; its outputs, flush's
    last."""
    from stillpoint.engine.operators.correction import CorrectedBatch

    edges = [0] + sorted(set(int(c) for c in cuts if 0 < c < len(tn))) + [len(tn)]
    seg = np.zeros(len(tn), np.int64) if segments is None else segments
    out = []
    for s, e in zip(edges[:-1], edges[1:]):
        for sg in np.unique(seg[s:e]):
            m = np.flatnonzero(seg[s:e] == sg) + s
            out.append(op.push(CorrectedBatch(tn[m], a[m], np.zeros(len(m)), int(sg))))
    out.append(op.flush())
    return out
