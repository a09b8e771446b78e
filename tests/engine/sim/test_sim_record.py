"""Simulated recordings through the real writers and readers: exact read-back for every format,
determinism, truth JSON + labels, two-device pairs, the CLI."""

import json

import numpy as np
import pytest

from stillpoint.drivers import open_recording
from stillpoint.engine.sim.model import ModelError, SensorModel, load_model
from stillpoint.engine.sim.record import (build_model, load_labels, load_truth, make_devices,
                                          simulate_pair, simulate_recording, truth_device_time)
from stillpoint.tools.cli import main as cli

FORMATS = [
    ("ax3", {}, 25.0, ".cwa"),
    ("ax3", {"packed": False}, 25.0, ".cwa"),
    ("ax6", {"gyro_range_dps": 1000.0}, 25.0, ".cwa"),
    ("geneactiv", {}, 20.0, ".bin"),
]


def _read(path):
    src = open_recording(path)
    blocks = list(src)
    return src, blocks


@pytest.mark.parametrize("device, kw, hz, ext", FORMATS)
def test_every_format_reads_back_exactly(tmp_path, device, kw, hz, ext):
    path = tmp_path / f"rec{ext}"
    eff = "default,halts,misalignment,nonlinearity"
    truth = simulate_recording(path, device=device, days=0.04, hz=hz, seed=4, effects=eff, **kw)
    [sim] = make_devices(sites=["wrist"], devices=[device], days=0.04, hz=hz, seed=4,
                         effects=build_model(eff), **kw)
    chunks = list(sim.chunks())
    counts = np.concatenate([c.counts for c in chunks])
    times = np.concatenate([c.time_ns for c in chunks])
    src, blocks = _read(path)
    got = np.concatenate([b.accel for b in blocks])
    assert truth.samples_written == counts.shape[0] == got.shape[0]
    assert np.array_equal(got.astype(np.int64), counts.astype(np.int64))  # counts exact
    gt = np.concatenate([b.time_ns for b in blocks])
    # times reproduce the device clock to the format's resolution, except the few samples that
    # share a sector/page with the halt (a reader spreads a unit's samples evenly)
    err = np.abs(gt - times)
    tol = 40_000 if ext == ".cwa" else 1_000_000  # 1/32768 s anchors; GENEActiv 1 ms page times
    per_unit = {".bin": 300}.get(ext, 480 // (4 if kw == {} else 6 if device == "ax3" else 12))
    assert np.count_nonzero(err > tol) <= per_unit  # at most the one unit straddling the halt
    assert src.qc.segments == 2  # the halt breaks the stream
    if device == "ax6":
        gyro = np.concatenate([c.gyro_counts for c in chunks])
        assert np.array_equal(np.concatenate([b.gyro for b in blocks]), gyro)
        assert blocks[0].gyro_dps_per_count == pytest.approx(1000.0 / 32768)
    # the file's temperature is the simulated sensor temperature (10-bit code / 0.1 degC)
    T = np.concatenate([b.temperature_c for b in blocks])
    Ts = np.concatenate([c.temperature_c for c in chunks])
    assert abs(np.median(T) - np.median(Ts)) < 0.3


def test_same_seed_same_bytes_and_seed_matters(tmp_path):
    a, b, c = tmp_path / "a.cwa", tmp_path / "b.cwa", tmp_path / "c.cwa"
    ta = simulate_recording(a, days=0.03, hz=25, seed=9, truth_path=tmp_path / "a.json")
    simulate_recording(b, days=0.03, hz=25, seed=9, truth_path=tmp_path / "b.json")
    simulate_recording(c, days=0.03, hz=25, seed=10, truth_path=tmp_path / "c.json")
    assert a.read_bytes() == b.read_bytes()
    assert a.read_bytes() != c.read_bytes()
    ja = json.loads((tmp_path / "a.json").read_text())
    jb = json.loads((tmp_path / "b.json").read_text())
    ja.pop("path"), jb.pop("path"), ja["labels"].pop("path"), jb["labels"].pop("path")
    assert ja == jb
    assert ta.samples_written > 0


def test_truth_json_and_labels(tmp_path):
    path = tmp_path / "r.cwa"
    eff = ["offset", "gain", "noise", "clock", "restarts", "corrupt_sectors", "thermal_lag",
           "temperature_offset"]
    t = simulate_recording(path, days=0.08, hz=25, seed=2, effects=eff)
    d = load_truth(tmp_path / "r.truth.json")
    m = SensorModel.from_dict(d["sensor_model"])
    assert set(m.effects) == {"offset", "gain", "noise", "clock", "restarts", "corrupt_sectors",
                              "thermal_lag", "temperature_offset"}
    assert all(k in m.effects["offset"] for k in ("x_mg", "y_mg", "z_mg"))  # drawn and recorded
    assert load_model(tmp_path / "r.truth.json").effects == m.effects  # truth usable as a model
    assert len(d["clock"]["restarts"]) == 1 and len(d["corrupt_sectors"]) == 3
    # the reader sees the restart and exactly the corrupt sectors the truth names
    src, blocks = _read(path)
    bad = sorted(e.index for e in src.qc.events if e.reason == "checksum")
    assert bad == d["corrupt_sectors"]
    assert any(e.reason == "restart" for e in src.qc.events)
    # labels: one row per 10 s window, still windows are truly still in the true signal
    lab = load_labels(t.labels_path)
    assert lab["window"].shape[0] == int(np.ceil(0.08 * 86400 / 10))
    still = lab["still"] == 1
    assert still.any() and (~still).any()
    # a still window holds no movement but the worn micro-motion (a few mg, zero mean)
    assert np.nanmax(lab["true_sd_x"][still]) < 0.05
    norm = np.sqrt(lab["true_mean_x"] ** 2 + lab["true_mean_y"] ** 2 + lab["true_mean_z"] ** 2)
    assert np.allclose(norm[still], 1.0, atol=5e-3)
    # the clock table maps true time to the file's device times
    first_block_t0 = blocks[0].time_ns[0]
    assert abs(int(truth_device_time(d, [0.0])[0]) - first_block_t0) < 1_000_000


def test_pair_shares_movement_with_own_clocks(tmp_path):
    a, b = tmp_path / "w.cwa", tmp_path / "h.cwa"
    ta, tb = simulate_pair(a, b, site_a="wrist", site_b="hip", days=0.3, hz=25, seed=5,
                           effects="default")
    assert ta.clock["model"]["skew_ppm"] != tb.clock["model"]["skew_ppm"]
    from stillpoint.engine.sim import relative_clock_s
    da, db = load_truth(tmp_path / "w.truth.json"), load_truth(tmp_path / "h.truth.json")
    rel = relative_clock_s(da, db, [0.0, 0.3 * 86400])
    ma, mb = ta.clock["model"], tb.clock["model"]
    assert rel[0] == pytest.approx(mb["offset_s"] - ma["offset_s"], abs=1e-6)
    drift = (rel[1] - rel[0]) / 0.3  # s/day: skew difference + crystal parabola at each site
    para = [m["curvature_ppm_per_c2"] * np.mean((t.labels["temperature_c"] - m["turnover_c"]) ** 2)
            for m, t in ((ma, ta), (mb, tb))]
    expect = ((mb["skew_ppm"] + para[1]) - (ma["skew_ppm"] + para[0])) * 0.0864
    assert drift == pytest.approx(expect, abs=0.02)
    assert abs(para[1] - para[0]) * 0.0864 > 0.05  # the sites' temperatures matter
    assert ta.sensor_model.effects["offset"] != tb.sensor_model.effects["offset"]
    la, lb = ta.labels, tb.labels
    assert np.array_equal(la["activity"], lb["activity"])  # one body, one schedule
    # heel strikes visible in both: the movement signals correlate at zero lag in true time
    [wa, wb] = make_devices(sites=["wrist", "hip"], devices=["ax3", "ax3"], days=0.3, hz=25, seed=5,
                            effects=build_model("none"))
    walk = np.nonzero(la["activity"] == 6)[0]
    assert walk.size > 12
    k = int(walk[0] * 10 // 3600)
    ca, cb = wa.chunk(k), wb.chunk(k)
    t0 = walk[0] * 10.0 + 5
    sel_a = (ca.true_s >= t0) & (ca.true_s < t0 + 60)
    sel_b = (cb.true_s >= t0) & (cb.true_s < t0 + 60)
    na = np.linalg.norm(ca.true_g[sel_a], axis=1)
    nb = np.linalg.norm(cb.true_g[sel_b], axis=1)
    n = min(na.size, nb.size)
    na, nb = na[:n] - na[:n].mean(), nb[:n] - nb[:n].mean()
    lags = np.arange(-25, 26)
    xc = [np.corrcoef(na[max(0, l):n + min(0, l)], nb[max(0, -l):n - max(0, l)])[0, 1] for l in lags]
    assert abs(lags[int(np.argmax(xc))]) <= 1
    assert max(xc) > 0.5


def test_cli_simulate_pair_model_and_errors(tmp_path, capsys):
    out = tmp_path / "s.cwa"
    model = tmp_path / "m.json"
    model.write_text(json.dumps({"format": "stillpoint.sensor_model", "version": 1,
                                 "effects": {"offset": {"x_mg": 10, "y_mg": 0, "z_mg": 50},
                                             "noise": {}}}))
    rc = cli(["simulate", "-o", str(out), "--days", "0.02", "--hz", "25", "--model", str(model),
              "--effect", "temperature:z=3.9mg/C", "--pair", "hip", "--json"])
    assert rc == 0
    rep = json.loads(capsys.readouterr().out)
    assert [r["site"] for r in rep["recordings"]] == ["wrist", "hip"]
    d = load_truth(tmp_path / "s.truth.json")
    eff = d["sensor_model"]["effects"]
    assert eff["offset"]["z_mg"] == 50 and eff["temperature_offset"]["z_mg_per_c"] == 3.9
    assert (tmp_path / "s.hip.cwa").exists() and (tmp_path / "s.hip.truth.json").exists()
    # --pair-effect: the second device only
    rc = cli(["simulate", "-o", str(tmp_path / "p.cwa"), "--days", "0.05", "--hz", "25", "--pair", "thigh",
              "--pair-effect", "halts:at=0.5h,duration=100s"])
    assert rc == 0
    assert load_truth(tmp_path / "p.truth.json")["clock"]["halts"] == []
    [h] = load_truth(tmp_path / "p.thigh.truth.json")["clock"]["halts"]
    assert h["start_true_s"] == 1800.0 and h["duration_s"] == 100.0
    capsys.readouterr()
    # bad effect parameter, wrong extension: exit 2 and one line on stderr
    assert cli(["simulate", "-o", str(tmp_path / "x.cwa"), "--effect", "offset:z=3s"]) == 2
    assert cli(["simulate", "-o", str(tmp_path / "x.cwa"), "--device", "geneactiv"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and all(line.startswith("stillpoint simulate: error:") for line in err)


def test_geneactiv_refuses_restarts():
    with pytest.raises(ModelError, match="restart"):
        make_devices(sites=["wrist"], devices=["geneactiv"], days=0.01, hz=20,
                     effects=build_model("restarts"))


def test_gzip_output_and_in_memory_generator(tmp_path):
    from stillpoint.engine.sim import iter_chunks
    p = tmp_path / "z.cwa.gz"
    t = simulate_recording(p, days=0.02, hz=25, seed=6, effects="default,corrupt_sectors")
    assert p.read_bytes()[:2] == b"\x1f\x8b" and (tmp_path / "z.truth.json").exists()
    src, blocks = _read(p)
    assert sum(b.n for b in blocks) == t.samples_written - 120 * len(t.corrupt_sectors)
    mem = list(iter_chunks(days=0.02, hz=25, seed=6, effects=build_model("default,corrupt_sectors")))
    assert sum(c.n for c in mem) == t.samples_written
    assert all(c.true_g.shape == c.measured_g.shape == (c.n, 3) for c in mem)


def test_sim_source_matches_the_written_file(tmp_path):
    from stillpoint.engine.sim.source import SimSource
    from stillpoint.engine.core.source import Source
    eff = build_model("default,halts,restarts")
    p = tmp_path / "s.cwa"
    simulate_recording(p, days=0.1, hz=25, seed=8, effects=eff)
    src = SimSource(days=0.1, hz=25, seed=8, effects=eff)
    assert isinstance(src, Source)
    blocks = list(src)
    fsrc, fblocks = _read(p)
    assert np.array_equal(np.concatenate([b.accel for b in blocks]),
                          np.concatenate([b.accel for b in fblocks]))
    dt = np.abs(np.concatenate([b.time_ns for b in blocks]) - np.concatenate([b.time_ns for b in fblocks]))
    assert np.count_nonzero(dt > 1_000_000) <= 120  # exact but for the sector straddling the halt
    assert src.qc.segments == fsrc.qc.segments == 3
    assert np.allclose(blocks[0].accel_g(), fblocks[0].accel_g()[:blocks[0].n])
    # units like the file's sectors: 120 samples, sequence reset at the restart
    assert np.all(np.diff(blocks[0].unit_start) == 120)
    tf = np.concatenate([b.temperature_c for b in fblocks])
    ts = np.concatenate([b.temperature_c for b in blocks])
    assert abs(np.median(tf) - np.median(ts)) < 0.3


def test_prefetch_thread_does_not_change_the_output():
    kw = dict(sites=["hip"], devices=["ax6"], days=2.5 / 24, hz=25, seed=12,
              effects=build_model("default,halts"))
    [a] = make_devices(**kw)
    [b] = make_devices(**kw)
    ca = list(a.chunks(prefetch=False))
    cb = list(b.chunks(prefetch=True))
    assert len(ca) == len(cb) == 3
    for x, y in zip(ca, cb):
        assert np.array_equal(x.counts, y.counts) and np.array_equal(x.time_ns, y.time_ns)
        assert np.array_equal(x.gyro_counts, y.gyro_counts)


def test_still_windows_without_rendering_match_the_labels(tmp_path):
    eff = build_model("default,halts")
    t = simulate_recording(tmp_path / "r.cwa", days=0.2, hz=25, seed=13, effects=eff)
    [sim] = make_devices(sites=["wrist"], devices=["ax3"], days=0.2, hz=25, seed=13, effects=eff)
    sw = sim.still_windows()
    lab = t.labels
    still = np.nonzero(lab["still"] == 1)[0]
    assert set(sw["window"]) <= set(still) and len(sw["window"]) >= len(still) - 40
    m = np.stack([lab["true_mean_x"], lab["true_mean_y"], lab["true_mean_z"]], 1)[sw["window"]]
    s = np.stack([lab["true_sd_x"], lab["true_sd_y"], lab["true_sd_z"]], 1)[sw["window"]]
    assert np.allclose(sw["gravity"] + sw["micro_mean"], m, atol=3e-4)
    rel = np.abs(sw["micro_sd"] - s) / np.maximum(s, 1e-3)  # closed form vs 25 Hz samples
    assert np.median(rel) < 0.05 and np.mean(rel < 0.25) > 0.9
    assert np.allclose(sw["temperature_c"], lab["temperature_c"][sw["window"]])


def test_labels_stream_through_long_gaps_and_in_memory_without_files(tmp_path):
    eff = build_model("noise").with_effect("restarts", events=[{"start_s": 3000.0, "gap_s": 7300.0}])
    t = simulate_recording(tmp_path / "g.cwa", days=0.2, hz=12.5, seed=2, effects=eff)
    lab = t.labels
    nw = int(np.ceil(0.2 * 86400 / 10))
    assert np.array_equal(lab["window"], np.arange(nw))
    gap = (lab["true_start_s"] >= 3000) & (lab["true_start_s"] + 10 <= 10300)
    assert gap.sum() > 700 and np.all(lab["samples"][gap] == 0) and np.all(lab["still"][gap] == 0)
    assert np.all(lab["samples"][~gap][1:-1] > 0)
    t2 = simulate_recording(tmp_path / "h.cwa", days=0.2, hz=12.5, seed=2, effects=eff, truth_path=False)
    assert not (tmp_path / "h.truth.json").exists() and t2.truth_path is None
    assert np.array_equal(t2.labels["samples"], lab["samples"])
