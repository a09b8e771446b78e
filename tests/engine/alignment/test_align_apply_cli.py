"""Resampling onto the reference clock, the MCAP output and `stillpoint align` end to end
(synthetic pairs written as real .cwa files; a real recording re-clocked through the writer)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from stillpoint.engine.alignment.apply import aligned_chunks
from stillpoint.engine.alignment.fit import ClockFit, Step
from stillpoint.engine.alignment.mcap_out import (TOPIC_BLOCK_LAG, TOPIC_ESTIMATE, read_aligned,
                                                  read_topic_json)
from synthetic_alignment import DeviceClock, SyntheticPair, write_cwa
from stillpoint.engine.core.blocks import Block, DeviceInfo, QCReport
from stillpoint.tools.cli import main
from mcap_layout import conforms

RATE = 30.0


class ArraySource:
    """A Source over (time_s, accel_g) arrays, cut into blocks of ``per`` samples."""

    def __init__(self, t_s, acc, rate, per=997):
        self.t_s, self.acc, self.per = t_s, acc, per
        self.info = DeviceInfo("AX3", "T", 0, "t", rate, 8.0)
        self.qc = QCReport("sector")

    def __iter__(self):
        for a in range(0, self.t_s.size, self.per):
            t = self.t_s[a:a + self.per]
            yield Block(time_ns=np.round(t * 1e9).astype(np.int64),
                        accel=np.round(self.acc[a:a + self.per] * 2**20).astype(np.int64),
                        accel_counts_per_g=np.full(3, 2.0**20), accel_zero=np.zeros(3))

    def close(self):
        pass


def _signal(tau):
    return np.column_stack([np.sin(2 * np.pi * 0.5 * tau), np.cos(2 * np.pi * 0.23 * tau),
                            0.5 * np.sin(2 * np.pi * 0.07 * tau + 1)])


def _other(offset_s, skew, rate=50.0, dur=600.0, gap=None):
    """Other device: its clock reads c = tau * (1 + skew) + offset; samples uniform in c."""
    c = np.arange(0, dur, 1 / rate) + 0.0071
    if gap is not None:
        c = c[(c < gap[0]) | (c >= gap[1])]
    tau = (c - offset_s) / (1 + skew)
    return c, _signal(tau)


@pytest.mark.parametrize("kind,tol", [("previous", 0.07), ("linear", 2e-3), ("cubic", 2e-4)])
def test_resampled_other_matches_the_reference_time_base(kind, tol):
    offset, skew = 1.37, 40e-6
    c, acc = _other(offset, skew)
    fit = ClockFit("robust", "linear", RATE, b0=offset * RATE, b1=skew * RATE)
    out_t, out_a = zip(*aligned_chunks(ArraySource(c, acc, 50.0), fit, 0, 25.0, kind))
    t = np.concatenate(out_t) * 1e-9
    a = np.concatenate(out_a)
    ok = np.isfinite(a[:, 0])
    assert ok.mean() > 0.95
    # reference time t is true time t (reference clock = true clock here)
    err = np.abs(a[ok] - _signal(t[ok]))
    assert err.max() < tol
    assert np.all(np.diff(t) > 0) and np.allclose(np.diff(t), 1 / 25.0, atol=1e-9)


def test_previous_keeps_original_values_and_gaps_stay_empty():
    c, acc = _other(0.5, 0.0, gap=(200.0, 230.0))
    fit = ClockFit("robust", "linear", RATE, b0=0.5 * RATE, b1=0.0)
    src = ArraySource(c, acc, 50.0)
    t, a = (np.concatenate(x) for x in zip(*aligned_chunks(src, fit, 0, 50.0, "previous")))
    q = np.round(acc * 2**20) / 2**20
    good = np.isfinite(a[:, 0])
    # every output value is one of the input samples (amplitudes kept: ENMO/MAD unchanged)
    assert np.isin(np.round(a[good, 0] * 2**20), np.round(q[:, 0] * 2**20)).all()
    tt = t * 1e-9 + 0.5  # other-clock time of each output point
    in_gap = (tt > 200.0 + 0.08) & (tt < 230.0 - 0.02)
    assert np.isnan(a[in_gap]).all() and in_gap.sum() > 1400


def test_step_window_is_left_empty():
    c, acc = _other(0.0, 0.0)
    step = Step(time_s=300.0, window_s=(290.0, 310.0), size=-3.0 * RATE, after_block=0,
                before_block=1)
    fit = ClockFit("robust", "piecewise", RATE, b0=0.0, b1=0.0, steps=[step])
    t, a = (np.concatenate(x) for x in zip(*aligned_chunks(ArraySource(c, acc, 50.0), fit, 0,
                                                            50.0, "linear")))
    ts = t * 1e-9
    assert np.isnan(a[(ts >= 290) & (ts <= 310)]).all()
    after = (ts > 311) & (ts < 500)
    np.testing.assert_allclose(a[after], _signal(ts[after] - 3.0), atol=2e-3)


@pytest.fixture(scope="module")
def cwa_pair(tmp_path_factory):
    d = tmp_path_factory.mktemp("align")
    pair = SyntheticPair(seed=31, duration_s=0.75 * 86400, rate_ref=25, rate_other=25,
                         clock_ref=DeviceClock(skew_ppm=-12), active_fraction=0.5,
                         clock_other=DeviceClock(offset_s=-6.25, skew_ppm=35))
    return pair, write_cwa(pair, 0, d / "ref.cwa"), write_cwa(pair, 1, d / "other.cwa")


def test_cli_aligns_cwa_files_and_writes_json_mcap_and_plot(cwa_pair, tmp_path, capsys):
    pair, ref, oth = cwa_pair
    out, png = tmp_path / "al.mcap", tmp_path / "al.png"
    rc = main(["align", ref, oth, "-o", str(out), "--json", "--plot", str(png),
               "--interpolation", "linear", "--online"])
    assert rc == 0
    d = json.loads(capsys.readouterr().out)
    for k in ("initial_offset_s", "drift_s_per_day", "drift_day7_s", "blocks_used",
              "blocks_excluded", "rmse_samples", "steps", "model"):
        assert k in d
    truth = pair.truth()
    assert d["aligned"] and d["model"] in ("linear", "linear+temperature") and d["steps"] == []
    # .cwa timestamps carry 1/32768 s anchors: allow one sample at 30 Hz
    assert abs(d["initial_offset_s"] - truth["initial_offset_s"]) < 1 / RATE
    assert abs(d["drift_day7_s"] - truth["drift_day7_s"]) < 0.2
    assert png.stat().st_size > 10_000
    rep = conforms(out)  # spec-complete layout, read by the mcap package's indexed reader
    assert rep["channel_schema"][TOPIC_ESTIMATE] == "stillpoint.AlignmentEstimate"
    assert rep["schemas"]["stillpoint.AlignmentBlockLag"] == "jsonschema"
    lags = read_topic_json(out, TOPIC_BLOCK_LAG)
    assert len(lags) == d["blocks_total"]
    est = read_topic_json(out, TOPIC_ESTIMATE)
    assert est[-1]["final"] and est[-1]["initial_offset_s"] == pytest.approx(d["initial_offset_s"])
    online = est[:-1]  # --online: the estimate refreshed as blocks arrived
    assert len(online) >= 3 and not any(e["final"] for e in online)
    assert abs(online[-1]["initial_offset_s"] - d["initial_offset_s"]) < 2 / RATE
    t, a = read_aligned(out)
    assert t.size > 0.9 * 0.75 * 86400 * 25
    # the aligned other stream lines up with the reference: same movement at the same time
    ref_t, ref_m = [], []
    from stillpoint.drivers import open_recording
    for b in open_recording(ref):
        ref_t.append(b.time_ns)
        ref_m.append(np.linalg.norm(b.accel_g(), axis=1))
    ref_t, ref_m = np.concatenate(ref_t), np.concatenate(ref_m)
    oth = np.interp(ref_t, t, np.linalg.norm(a, axis=1))
    act = np.abs(ref_m - 1) > 0.2
    assert np.corrcoef(ref_m[act], oth[act])[0, 1] > 0.6


def test_cli_brond_method_and_exit_code_3_when_too_few_blocks(cwa_pair, tmp_path, capsys):
    _, ref, oth = cwa_pair
    rc = main(["align", ref, oth, "--method", "brond"])
    assert rc == 0
    assert "(brond)" in capsys.readouterr().out
    rc = main(["align", ref, oth, "--min-blocks", "500", "--json"])
    cap = capsys.readouterr()
    assert rc == 3
    d = json.loads(cap.out)
    assert d["aligned"] is False and d["reason"].startswith("too few blocks")
    assert "not aligned" in cap.err


def test_cli_unreadable_input_exits_2(tmp_path, capsys):
    bad = tmp_path / "x.cwa"
    bad.write_bytes(b"hello")
    assert main(["align", str(bad), str(bad)]) == 2
    assert "x.cwa" in capsys.readouterr().err


def test_real_recording_against_a_reclocked_copy(real_file, tmp_path):
    """A real AX3 recording vs. itself re-written with another clock (offset, skew) through the
    .cwa writer: the offset and drift come back from the acceleration alone."""
    from stillpoint.drivers import open_recording
    from stillpoint.drivers.cwa_writer import CwaWriter
    from stillpoint.engine.alignment import AlignConfig, estimate_alignment
    src = real_file("ax3_oxwearables_tiny_sample_3h_with_restart.cwa.gz")
    offset_s, skew = 2.345, 80e-6  # exaggerated skew: visible within 3 h
    copy = tmp_path / "copy.cwa"
    t0 = None
    with CwaWriter(copy, rate_hz=100.0, range_g=8) as w:
        for b in open_recording(src):
            if t0 is None:
                t0 = int(b.time_ns[0])
            rel = (b.time_ns - t0).astype(np.float64)
            w.write(t0 + np.round(rel * (1 + skew) + offset_s * 1e9).astype(np.int64),
                    np.round(b.accel_g() * 256).astype(np.int64))
    cfg = AlignConfig(method="robust", block_s=600.0)
    res = estimate_alignment(open_recording(src), open_recording(copy), cfg)
    assert res.ok, res.reason
    assert abs(res.fit.initial_offset_s - offset_s) < 1 / RATE
    assert abs(res.fit.drift_s_per_day - skew * 86400) < 0.5  # 6.9 s/day
