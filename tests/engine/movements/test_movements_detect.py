"""Infant leg-movement detector: hand-built golden vectors for the reference rules (marks, pairing,
start/end, overlap), thresholds v1/v2, fs scaling, cycle filter, sleep, rate and filters."""

from __future__ import annotations

import numpy as np
import pytest

from stillpoint.engine.movements import detect as D
from stillpoint.engine.movements import post as P
from stillpoint.engine.movements.signals import (apply_filter, lowpass, signals_from_arrays,
                                                 two_tap)
from stillpoint.engine.movements.leg import MovementInputError, detect_signals
from stillpoint.engine.sim.infant import make_infant

TH = D.Thresholds(1.0, -1.0, 1, 1)


def run(a, w=None, fs=20):
    a = np.asarray(a, np.float64)
    w = np.ones_like(a) if w is None else np.asarray(w, np.float64)
    count, crossed = D.labels(a, w, TH)
    mark = D.crossing_marks(a, count, crossed)
    rows = D.pair_movements(a, count, crossed, mark, fs)
    return mark, rows, D.resolve_overlaps(rows)


def test_marks_shift_dedupe_walk_back_and_end():
    a = np.zeros(40)
    a[10:14] = 2.0
    a[14:18] = -2.0
    a[18:20] = 0.5  # back on the first lobe's side (count +1) below the threshold
    mark, rows, mv = run(a)
    # +2 shift at 10 -> 12, then 13 marked, 12 cleared as adjacent; same on the negative lobe
    assert np.flatnonzero(mark).tolist() == [13, 17]
    assert mark[13] == 1 and mark[17] == -1
    # walk-back from f = 13 over count = +1 to 10 (k = 4), min |a| at 9 -> start 10, slack 3
    assert rows[rows.any(axis=1)].tolist() == [[10, 17, 18, 3]]
    assert mv.tolist() == [[10, 17, 18]]
    dur, avg, peak = P.kinematics(a, mv, None, 20)
    assert dur[0] == pytest.approx(9 / 20) and avg[0] == pytest.approx(16.5 / 9) and peak[0] == 2.0


def test_end_not_found_within_span_drops_candidate():
    a = np.zeros(40)
    a[10:14] = 2.0
    a[14:18] = -2.0  # never returns to the positive side
    _, rows, mv = run(a)
    assert not rows.any() and mv.shape == (0, 3)


def test_gyro_gate_closes_crossings():
    a = np.zeros(40)
    a[10:14] = 2.0
    a[14:18] = -2.0
    a[18:20] = 0.5
    w = np.ones(40)
    w[14:18] = -0.1  # no rotation during the second lobe: no negative mark
    mark, _, mv = run(a, w)
    assert (mark < 0).sum() == 0 and mv.shape[0] == 0


def test_movement_starting_at_sample_zero_is_dropped():
    a = np.zeros(40)
    a[0] = 2.0
    a[1:5] = -2.0
    a[5:7] = 0.5
    mark, rows, mv = run(a)
    assert np.flatnonzero(mark).tolist() == [0, 4]
    assert rows[0].tolist() == [0, 4, 5, 0]  # budget >= f: start = f = 0
    assert mv.shape[0] == 0  # the reference drops start 0
    _, _, mv1 = run(np.concatenate(([0.0], a)))
    assert mv1.tolist() == [[1, 5, 6]]


def test_overlapping_candidates_cleared_when_no_slack_fits():
    a = np.zeros(60)
    a[10:13] = 2.0
    a[13:16] = -2.0
    a[16:19] = 2.0
    a[19:21] = -0.5
    mark, rows, mv = run(a)
    assert np.flatnonzero(mark).tolist() == [12, 15, 18]
    assert rows[rows.any(axis=1)].tolist() == [[12, 15, 16, 0], [13, 18, 19, 2]]
    assert mv.tolist() == [[12, 15, 16]]  # row 2 starts before row 1 ends; its slack cannot fix it


def test_resolve_overlaps_shift_and_cascade():
    rows = np.array([[10, 15, 20, 0],
                     [18, 25, 30, 4],  # overlaps; shifting to 20 (<= 18 + 4) succeeds
                     [29, 35, 40, 0],  # overlaps row 2's end 30, no slack: cleared
                     [33, 45, 50, 0],  # previous cleared: cleared while start < end of row 2 (30)? no
                     [60, 65, 70, 0]])
    out = D.resolve_overlaps(rows)
    assert out.tolist() == [[10, 15, 20], [20, 25, 30], [33, 45, 50], [60, 65, 70]]
    rows2 = np.array([[10, 15, 40, 0], [20, 25, 30, 0], [35, 36, 38, 0], [41, 45, 50, 0]])
    # row 2 cleared (overlap, no slack) -> rows 3.. cleared while start < end of row 1 (40)
    assert D.resolve_overlaps(rows2).tolist() == [[10, 15, 40], [41, 45, 50]]


def test_thresholds_v1_vs_v2_and_bounds():
    a = np.array([0, 1.0, 0, 3.2501, 0, 2.0, 0, -1.5, 0, -2.5, 0])
    t2 = D.thresholds(a, "v2")
    assert t2.peaks_positive == 2 and t2.positive == pytest.approx(1.5 - 0.5)  # 1.0 in, 3.2501 out
    assert t2.negative == pytest.approx(-(2.0 - 0.5))
    shoulder = np.array([0, 2.0, 4.0, 2.0, 0, 1.5, 0])  # a peak above the rejection bound
    v2, v1 = D.thresholds(shoulder, "v2"), D.thresholds(shoulder, "v1")
    assert v2.peaks_positive == 1 and v2.positive == pytest.approx(1.5)
    assert v1.peaks_positive == 3  # zeroing 4.0 first turns its shoulders into two peaks
    assert v1.positive == pytest.approx(np.mean([2, 2, 1.5]) - np.std([2, 2, 1.5]))
    none = D.thresholds(np.zeros(50), "v2")
    assert not none.usable
    with pytest.raises(ValueError):
        D.thresholds(a, "v3")


def test_counts_scale_with_fs():
    counts = []
    for fs in (20, 25, 52):
        sim = make_infant(minutes=15, fs=fs, seed=21)
        t, meas, _, gyro = sim.arrays()
        counts.append(detect_signals(signals_from_arrays(t, meas, gyro, fs))["movements"].shape[0])
    assert max(counts) - min(counts) <= 0.08 * np.mean(counts), counts


def _table(starts, length=4):
    s = np.asarray(starts, np.int64)
    return np.stack([s, s + 2, s + length], 1)


def test_cycle_filter_40_vs_41_and_tail():
    fs = 20
    gap = 2  # <= floor(0.2 * 20) = 4
    for chain, removed in ((40, 0), (41, 41 + 3)):
        starts = [100 + i * (4 + gap) for i in range(chain)]
        last_end = starts[-1] + 4
        tail = [last_end + 40 + 20 * k for k in range(5)]  # 2 s apart: not chained, < 12 s
        mv = _table(starts + tail + [last_end + 5000])
        kept, drop = P.cycle_filter(mv, fs)
        assert int(drop.sum()) == removed, chain
        if removed:
            assert drop[:chain].all() and drop[chain:chain + 3].all() and not drop[chain + 3:].any()
    # tail movements 12 s or more after the chain are kept
    starts = [100 + i * 6 for i in range(41)]
    mv = _table(starts + [starts[-1] + 4 + 12 * fs, starts[-1] + 4 + 13 * fs, 99999])
    assert int(P.cycle_filter(mv, fs)[1].sum()) == 41


def test_sleep_rule_and_rate():
    fs, n = 20, 20000
    mv = _table([100, 200, 300, 10000, 10100, 10200], length=10)
    # t0 = 0 .. start(3) - 1 = 9999 holds 3 movements (allowed) -> 9999; tail 19999 - 10211
    assert P.sleep_samples(mv, n, fs) == 9999 + (19999 - 10211)
    assert P.sleep_samples(np.zeros((0, 3), np.int64), n, fs) == n
    r = P.rate(6, n, 9999 + 9788, fs)
    # 16.49 min of sleep floors to 15 min; 1000 s of recording
    assert r.sleep_hours == pytest.approx(0.25) and r.recording_hours == pytest.approx(n / 20 / 3600)
    assert r.per_hour_awake == pytest.approx(6 / (n / 20 / 3600 - 0.25))
    allsleep = P.rate(0, 6000 * 4, 6000 * 4, fs)
    assert allsleep.per_hour_awake == 0.0 and allsleep.flags
    assert P.rate(3, 6000, 6000, fs).per_hour_awake is None


def test_sleep_only_recording_is_refused():
    sim = make_infant(minutes=8, seed=22, sleep_blocks=[(0, 8)])
    t, meas, _, gyro = sim.arrays()
    with pytest.raises(MovementInputError, match="no acceleration peaks"):
        detect_signals(signals_from_arrays(t, meas, gyro, 25), where="x.cwa")


def test_filters():
    imp = np.zeros(8)
    imp[3] = 1.0
    assert two_tap(imp)[3:5].tolist() == [0.5, 0.5] and two_tap(imp).sum() == 1.0
    assert two_tap(np.array([2.0, 2.0]))[0] == 1.0  # zero initial state
    for fs in (20, 25, 52):
        t = np.arange(400) / fs
        y = two_tap(np.sin(2 * np.pi * fs / 4 * t + np.pi / 4))
        assert np.abs(y[10:]).max() == pytest.approx(np.sqrt(0.5), abs=1e-3)  # -3 dB at fs/4
    fs = 25
    t = np.arange(2000) / fs
    slow, fast = np.sin(2 * np.pi * 2 * t), np.sin(2 * np.pi * 11 * t)
    assert np.abs(lowpass(slow, fs)[100:-100]).max() == pytest.approx(1, abs=0.03)
    assert np.abs(lowpass(fast, fs)[100:-100]).max() < 0.05
    with pytest.raises(ValueError, match="sampling rate above 16"):
        apply_filter(slow, "lowpass8", 15)


def test_strict_gyro_gate_only_removes():
    sim = make_infant(minutes=10, seed=23)
    t, meas, _, gyro = sim.arrays()
    sig = signals_from_arrays(t, meas, gyro, 25)
    ref = detect_signals(sig)
    strict = detect_signals(sig, strict_gyro=True)
    assert strict["movements"].shape[0] <= ref["movements"].shape[0]
    rows = {tuple(r) for r in ref["movements"].tolist()}
    assert all(tuple(r) in rows for r in strict["movements"].tolist())
    w = strict["w"]
    assert all((w[s:e + 1] > 0).all() for s, _, e in strict["movements"])
