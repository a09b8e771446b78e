"""MIMS-units (engine/operators/mims.py, engine/operators/mims_extrapolation.py): equal to R
MIMSunit (fixtures written by tools/crosschecks/mims_reference.py) to 1e-3 per 1 s epoch on real
recordings, with and without samples near their range, and on a synthetic recording that sits at
its range; independent of block cuts; carried through `process` into the epoch table, the MCAP and
replay."""

from __future__ import annotations

import gzip
import subprocess
import sys

import numpy as np
import pytest
from synthetic_blocks import push_in_pieces

from stillpoint.engine.operators.correction import CorrectedBatch
from stillpoint.engine.operators import mims_extrapolation as mx
from stillpoint.engine.operators.mims import REFERENCE_A, REFERENCE_B, EpochMims, MimsOperator
from stillpoint.tools.crosschecks import mims_reference as mr

CLI = "import sys; from stillpoint.tools.cli import main; sys.exit(main(sys.argv[1:]))"
# recordings without samples within 0.15 g of their range (the reference extrapolates those)
CLEAN = [mr.ACTILIFE_CSV, "actigraph_pygt3x_neo_30hz_legacy.gt3x", "actigraph_actfast_mos_60hz_81s.gt3x",
         "actigraph_pygt3x_tas_30hz_ism_disabled.gt3x", "ax3_skdh_sample_200hz_490blocks.cwa",
         "geneactiv_sleeppy_test_100hz_64pages.bin",
         "geneactiv_ggirread_testfile_85p7hz_truncated64k.bin",
         "geneactiv_actfast_cmi_60hz_20pages_LF_fw0617.bin"]


def _signal(rate, seconds, seed=0, start_frac=0.37):
    rng = np.random.default_rng(seed)
    n = int(rate * seconds)
    t = np.arange(n) / rate
    a = np.stack([0.3 * np.sin(2 * np.pi * 1.1 * t) + 0.02 * rng.standard_normal(n),
                  1 + 0.5 * np.sin(2 * np.pi * 0.7 * t),
                  0.1 + 0.8 * np.sin(2 * np.pi * 2.3 * t) * (t < seconds / 2)], axis=1)
    tn = (1_599_998_400 * 10**9 + int(start_frac * 1e9) + np.round(t * 1e9)).astype(np.int64)
    return tn, a


def _run(tn, a, epoch=1, cuts=(), segments=None, op=None):
    op = op or MimsOperator(0.0, epoch, 8.0)
    return EpochMims.concat(push_in_pieces(op, tn, a, cuts, segments))


@pytest.mark.parametrize("rate,seed", [(30, 0), (50, 1), (100, 2), (85.7, 3)])
def test_mims_independent_of_block_cuts(rate, seed):
    """Long enough for several spline tiles; the same numbers, bit for bit, whatever the cuts."""
    tn, a = _signal(rate, 100, seed)
    whole = _run(tn, a)
    rng = np.random.default_rng(seed)
    cut = _run(tn, a, cuts=rng.integers(1, len(tn), 60))
    tiny = _run(tn, a, cuts=range(1, len(tn), 97))
    assert np.array_equal(whole.start_ns, cut.start_ns)
    assert np.array_equal(whole.mims, cut.mims, equal_nan=True)
    assert np.array_equal(whole.mims, tiny.mims, equal_nan=True)
    assert np.nanmax(whole.mims) > 0.3


def test_epochs_rules():
    tn, a = _signal(50, 20)
    one = _run(tn, a)
    five = _run(tn, a, epoch=5)
    assert np.isnan(one.mims[0]) and one.n[0] < 90  # the first second is 63 % full
    assert np.allclose(one.axes.sum(axis=1)[1:], one.mims[1:], equal_nan=True)
    assert np.all(one.n[1:-1] == 100) and five.n[1] == 500
    # a 5 s epoch's area is its seconds' areas plus the trapezoids across their boundaries
    assert five.axes[1].sum() >= one.axes[5:10].sum() - 1e-12
    # a still signal: once the filter has settled on gravity (it starts at rest, as the
    # reference's), every axis's area is truncated to 0
    still = _run(tn, np.tile([0.0, 0.0, 1.0], (len(tn), 1)) + 1e-6 * np.sin(np.arange(len(tn)))[:, None])
    assert still.mims[1] > 0.1 and np.all(still.mims[-6:-1] == 0)
    with pytest.raises(ValueError):
        MimsOperator(50, 2.5)


def test_segments_restart():
    tn, a = _signal(50, 60)
    seg = (np.arange(len(tn)) >= 1500).astype(np.int64)
    both = _run(tn, a, segments=seg)
    second = _run(tn[1500:], a[1500:])
    b = both.mims[both.segment == 1]
    assert np.array_equal(b, second.mims, equal_nan=True)


@pytest.mark.parametrize("name", mr.FILES)
def test_mims_equal_r_mimsunit(real_file, name):
    """To 1e-3 per 1 s epoch (measured: below 2.2e-5) on every real recording, those with samples
    near their range (extrapolated: AX3 and AX6 GGIRread, GENEActiv gait and 20 Hz ankle) among
    them; the epochs R leaves undefined are undefined in ours too."""
    range_g, segs = mr.segments(real_file(name))
    got = [mr.ours(t, a, range_g, seed=5) for t, a in segs]
    r = mr.compare(mr.read_fixture(mr.fixture_path(name)), got)
    assert r["valid"] > 50 and r["undefined_agree"] == r["undefined"], r
    assert r["over_1e-3"] == 0 and r["max_abs_diff"] < 1e-4, r
    near = sum(n for _, n, _ in got)
    assert (near == 0) == (name in CLEAN), near
    assert sum(n for _, _, n in got) == 0


def test_mims_equal_r_mimsunit_at_the_range():
    """A synthetic recording that sits at its range (runs at both of its ends longer than 5 s,
    so R sets them to -200 and leaves their epochs undefined; a shorter one at its start; 60
    clipped runs of a 9.5 g movement; single near-range samples): equal to R to 1e-4 in every
    epoch R gives a value for, undefined where R's is."""
    range_g, segs = mr.segments(mr.FIXTURES / mr.SYNTHETIC)
    got = [mr.ours(t, a, range_g, seed=s) for s, (t, a) in enumerate(segs)]
    r = mr.compare(mr.read_fixture(mr.fixture_path(mr.SYNTHETIC)), got)
    assert r["valid"] >= 70 and r["undefined"] == 14 and r["undefined_agree"] == 14, r
    assert r["over_1e-3"] == 0 and r["max_abs_diff"] < 1e-4, r
    g, near, asis = got[0]
    assert near >= 40 and asis == 0
    assert np.all(np.isnan(g.mims[:7])) and np.nanmax(g.mims) > 6


def test_mims_without_extrapolation_differs_at_the_range():
    """The extrapolation is what makes the synthetic recording agree: with the samples as
    recorded (range unknown) the clipped seconds differ from R by more than 0.1."""
    range_g, segs = mr.segments(mr.FIXTURES / mr.SYNTHETIC)
    t, a = segs[0]
    op = MimsOperator(0.0, 1, None)
    g = EpochMims.concat([op.push(CorrectedBatch(t, a, np.zeros(len(t)), 0)), op.flush()])
    r = mr.compare(mr.read_fixture(mr.fixture_path(mr.SYNTHETIC)), [(g, 0, 0)])
    assert r["max_abs_diff"] > 0.1


@pytest.mark.parametrize("hold", [mx.MAX_HOLD, 1500])
def test_extrapolation_independent_of_block_cuts(monkeypatch, hold):
    """Near-range runs held across block edges: the same numbers, bit for bit, whatever the cuts;
    a run longer than the hold (lowered to 15 s here) goes out as recorded and is counted, and
    the extrapolator holds at most the hold plus its context."""
    monkeypatch.setattr(mx, "MAX_HOLD", hold)
    tn, a, _ = mr.clipped_signal()
    a = a.copy()
    a[1000:2000, 1] = 8.0  # 20 s at the range in the middle
    rng = np.random.default_rng(7)
    ops = [MimsOperator(0.0, 1, 8.0) for _ in range(3)]
    whole = _run(tn, a, op=ops[0])
    cut = _run(tn, a, cuts=rng.integers(1, len(tn), 80), op=ops[1])
    tiny = _run(tn, a, cuts=range(1, len(tn), 97), op=ops[2])
    for other in (cut, tiny):
        assert np.array_equal(whole.start_ns, other.start_ns)
        assert np.array_equal(whole.axes, other.axes, equal_nan=True)
        assert np.array_equal(whole.unextrapolated, other.unextrapolated)
    assert len({op.unextrapolated_epochs for op in ops}) == 1
    # with the lowered hold only the 20 s at the range (21 epochs) go out as recorded, not the
    # 30 s of clipped movement (runs each shorter than the hold)
    assert ops[0].unextrapolated_epochs == (21 if hold < 2000 else 0)
    ex = mx.Extrapolator(8.0)
    x = 1_700_000_000.0 + np.arange(20 * hold) / 100.0
    v = np.tile([8.0, 0.0, 1.0], (x.shape[0], 1))
    longest = 0
    for s in range(0, x.shape[0], 997):
        ex.push(x[s:s + 997], v[s:s + 997])
        longest = max(longest, ex.x.shape[0])
    assert longest <= hold + 2 * mx.CONTEXT + 2 * 997


def test_reference_filter_is_the_butterworth_band_pass():
    """R's coefficients are scipy's 4th-order 0.2-5 Hz Butterworth at 100 Hz to within an ulp."""
    from scipy import signal
    b, a = signal.butter(4, [0.2 / 50, 5 / 50], "bandpass")
    assert np.abs(b - REFERENCE_B).max() < 4 * np.finfo(float).eps * np.abs(b).max()
    assert np.abs(a - REFERENCE_A).max() < 4 * np.finfo(float).eps * np.abs(a).max()


def test_smooth_spline_and_fmm_spline_equal_r():
    """stats::smooth.spline(x, y, w, spar = 0.6) predictions inside and beyond the data, and
    stats::spline(method = "fmm"), against R 4.2.2's own values (printed with 17 digits by
    `predict(smooth.spline(...), x)$y` and `spline(kx, ky, xout = ..., method = "fmm")$y`)."""
    x = np.array([0, 0.01, 0.02, 0.03, 0.04]) + 1700000000.25
    y = np.array([7.1, 7.5, 7.8, 7.93, 7.99])
    w = np.array([1, 1, 1, 1, 0.12])
    xo = np.array([x[1], x[4] + 0.015, x[0] - 0.02])
    got = mx.smooth_spline_predict(np.tile(x, (3, 1)), np.tile(y, (3, 1)), np.tile(w, (3, 1)), xo)
    assert np.allclose(got, [7.4463442895736804, 8.6041426714185345, 6.6284556942975614],
                       rtol=0, atol=1e-9)
    x2 = np.array([0, 0.01, 0.02, 0.03, 0.04])
    y2 = np.array([-7.99, -7.6, -7.2, -6.5, -6.1])
    w2 = np.array([1.93, 1, 1, 1, 1])
    got = mx.smooth_spline_predict(np.tile(x2, (2, 1)), np.tile(y2, (2, 1)), np.tile(w2, (2, 1)),
                                   np.array([-0.03, 0.025]))
    assert np.allclose(got, [-9.4392438724101666, -6.8350386895564457], rtol=0, atol=1e-9)
    kx = np.array([0, 0.1, 0.25, 0.3, 0.5, 0.52, 0.7, 1])
    ky = np.array([1, 3, -2, 0.5, 4, 4.2, -1, 0])
    got = mx.fmm_spline(kx, ky, np.array([-0.05, 0.05, 0.27, 0.51, 0.9, 1.1]))
    assert np.allclose(got, [-6.6507330782198766, 3.6919110260732921, -1.1671314326634727,
                             4.1096708284225238, -5.7154435642284209, 15.282738980308718],
                       rtol=0, atol=1e-9)
    assert mx.gamma_shape() == pytest.approx(0.026)


def test_process_writes_mims(tmp_path, real_file):
    src = real_file("geneactiv_actfast_cmi_60hz_20pages_LF_fw0617.bin")
    out = tmp_path / "g.mcap"
    r = subprocess.run([sys.executable, "-c", CLI, "process", str(src), "-o", str(out), "--mims",
                        "--counts", "normal", "--no-calibrate", "--epoch-s", "1", "-q",
                        "--summary", str(tmp_path / "s.json")], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    with gzip.open(tmp_path / "g.epochs.csv.gz", "rt") as f:
        head = f.readline().strip().split(",")
        rows = [line.rstrip("\n").split(",") for line in f]
    i = head.index("mims")
    assert head[i - 4:i + 1] == ["axis1", "axis2", "axis3", "vm", "mims"]
    ref = mr.read_fixture(mr.fixture_path(src.name))[0]
    table = {np.datetime64(x[0].rstrip("Z"), "s").astype(np.int64): float(x[i])
             for x in rows if x[i] != ""}
    common = [int(t) for t, v in zip(ref[:, 0], ref[:, 1]) if v != -0.01 and int(t) in table]
    assert len(common) > 90
    assert max(abs(table[t] - v) for t, v in zip(ref[:, 0], ref[:, 1]) if int(t) in common) < 1e-3
    import json
    summary = json.loads((tmp_path / "s.json").read_text())
    assert summary["mims_near_range_epochs"] == 0 and summary["mims_unextrapolated_epochs"] == 0
    from mcap.reader import make_reader
    with open(out, "rb") as f:
        msgs = [(m.log_time, m.data) for _, _, m in make_reader(f).iter_messages(topics=["/metrics/mims"])]
    assert len(msgs) >= len(common)
    out2 = tmp_path / "r.mcap"
    r = subprocess.run([sys.executable, "-c", CLI, "replay", str(out), "-o", str(out2), "-q"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    with open(out2, "rb") as f:
        again = [(m.log_time, m.data) for _, _, m in make_reader(f).iter_messages(topics=["/metrics/mims"])]
    assert again == msgs
