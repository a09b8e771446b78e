"""`stillpoint static-calibrate`, `movements`, `simulate --scenario sixface|infant` and
`process --static` on simulated AX6/AX3 .cwa files; bad input -> one line, exit 2, no output."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from stillpoint.engine.sim.infant import make_infant, write_infant
from stillpoint.engine.sim.sixface import simulate_sixface, write_cwa, write_sixface
from stillpoint.engine.sim.static_errors import StaticErrors
from stillpoint.tools.cli import main

LEFT = StaticErrors(offset_g=[0.062, -0.074, 0.030], gain=[1.002, 0.998, 1.009], noise_g=[0.002] * 3)
RIGHT = StaticErrors(offset_g=[-0.03, 0.067, 0.018], gain=[0.998, 0.994, 1.011], noise_g=[0.002] * 3)


def cli(capsys, *argv):
    code = main([str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.out, out.err


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("static")
    f = {}
    for leg, e, dev in (("left", LEFT, 601), ("right", RIGHT, 602)):
        write_sixface(d / f"cal_{leg}.cwa", simulate_sixface(fs=25, errors=e, seed=dev), device_id=dev)
        write_infant(d / f"{leg}.cwa", make_infant(minutes=12, seed=dev, errors=e, n_postures=5,
                                                   clock_skew_ppm=30 if leg == "right" else 0),
                     device_id=dev)
        f[leg] = d / f"{leg}.cwa"
        f["cal_" + leg] = d / f"cal_{leg}.cwa"
    f["dir"] = d
    return f


def test_static_calibrate_json_output_store_plot(capsys, files, tmp_path):
    code, out, _ = cli(capsys, "static-calibrate", files["cal_left"], "--mode", "robust", "--json",
                       "-o", tmp_path / "cal.json", "--store", tmp_path / "store",
                       "--plot", tmp_path / "cal.png", "--full-matrix")
    assert code == 0
    doc = json.loads(out)
    for k in ("offset_g", "gain", "misalignment_signed_g", "misalignment_abs_g", "noise_g"):
        assert len(doc[k]) == 3
    assert doc["mode"] == "robust" and doc["status"] == "ok" and doc["device_key"] == "AX6-601"
    np.testing.assert_allclose(doc["offset_g"], LEFT.offset_g, atol=1e-3)
    np.testing.assert_allclose(doc["gain"], LEFT.gain, atol=1e-3)
    assert len(doc["matrix"]) == 3
    for face in ("+x", "-x", "+y", "-y", "+z", "-z"):
        f = doc["faces"][face]
        assert f["start_time"] < f["end_time"] and f["window_s"] >= 1 and f["samples"] > 0
    ref = json.loads(cli(capsys, "static-calibrate", files["cal_left"], "--json")[1])
    assert ref["faces"]["+x"]["band_g"] == pytest.approx([0.9, 1.1]) and ref["faces"]["+x"]["window_s"] == 5
    assert json.loads((tmp_path / "cal.json").read_text())["offset_g"] == doc["offset_g"]
    assert (tmp_path / "cal.png").stat().st_size > 10_000
    assert list((tmp_path / "store" / "calibration").glob("AX6-601*.json"))
    code, out, _ = cli(capsys, "static-calibrate", files["cal_left"])
    assert code == 0 and "offset_g" in out and "+z" in out


def _bad(capsys, tmp_path, *argv):
    out = tmp_path / "out.json"
    code, _, err = cli(capsys, *argv, "-o", out)
    assert code == 2 and len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert not out.exists() and not list(tmp_path.glob("out.json*"))
    return err


def test_static_calibrate_bad_input(capsys, files, tmp_path):
    e = StaticErrors(noise_g=[0.001] * 3)
    five = simulate_sixface(fs=25, errors=e, seed=41, order=["+x", "-x", "+y", "-y", "+z"])
    write_sixface(tmp_path / "five.cwa", five)
    err = _bad(capsys, tmp_path, "static-calibrate", tmp_path / "five.cwa")
    assert "five.cwa" in err and "-z (z axis down)" in err
    short = simulate_sixface(fs=25, errors=e, seed=42, hold_s=0.6)
    write_sixface(tmp_path / "short.cwa", short)
    assert "6 of the six faces" in _bad(capsys, tmp_path, "static-calibrate", tmp_path / "short.cwa",
                                        "--mode", "robust")
    # an infant recording is not a calibration session: no faces held still
    assert "not found" in _bad(capsys, tmp_path, "static-calibrate", files["left"], "--mode", "robust")
    write_cwa(tmp_path / "empty.cwa", np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)))
    assert "no samples" in _bad(capsys, tmp_path, "static-calibrate", tmp_path / "empty.cwa")
    clip = simulate_sixface(fs=25, errors=StaticErrors(offset_g=[0, 0, 0.5], noise_g=[0.001] * 3),
                            seed=43, clip_g=1.5)
    write_sixface(tmp_path / "clip.cwa", clip, range_g=2)
    err = _bad(capsys, tmp_path, "static-calibrate", tmp_path / "clip.cwa", "--mode", "robust")
    assert "clip.cwa" in err


def test_movements_two_legs_own_calibrations(capsys, files, tmp_path):
    cals = []
    for leg in ("left", "right"):
        p = tmp_path / f"{leg}.cal.json"
        assert cli(capsys, "static-calibrate", files["cal_" + leg], "--mode", "robust", "-o", p)[0] == 0
        cals.append(p)
    code, out, _ = cli(capsys, "movements", files["left"], files["right"], "--calibration", cals[0],
                       "--calibration", cals[1], "--json", "-o", tmp_path / "mv.csv",
                       "--plot", tmp_path / "mv.png")
    assert code == 0
    doc = json.loads(out)
    for leg in ("left", "right"):
        s = doc[leg]
        assert s["count"] > 50 and s["calibration"]["applied"] and s["rate_per_hour_awake"] > 0
        assert s["threshold_positive_ms2"] > 0 > s["threshold_negative_ms2"]
    assert doc["right"]["effective_rate_hz"] != doc["left"]["effective_rate_hz"]  # clock skew
    rows = list(csv.DictReader(open(tmp_path / "mv.csv")))
    assert len(rows) == doc["left"]["count"] + doc["right"]["count"]
    assert {r["leg"] for r in rows} == {"left", "right"}
    assert all(0 < float(r["duration_s"]) < 1.6 for r in rows)
    assert (tmp_path / "mv.png").stat().st_size > 10_000
    # swapped calibrations: refused, each leg needs its own device's calibration
    code, _, err = cli(capsys, "movements", files["left"], "--calibration", cals[1])
    assert code == 2 and "AX6-602" in err and "AX6-601" in err
    # from the store: the same counts as from the files
    store = tmp_path / "store"
    for leg in ("left", "right"):
        cli(capsys, "static-calibrate", files["cal_" + leg], "--mode", "robust", "--store", store)
    code, out, _ = cli(capsys, "movements", files["left"], files["right"], "--store", store, "--json")
    assert code == 0 and json.loads(out)["left"]["count"] == doc["left"]["count"]
    code, out, _ = cli(capsys, "movements", files["left"], "--variant", "v1", "--filter", "2tap",
                       "--resample", "20", "--nominal-time", "--calibration", cals[0])
    assert code == 0 and "left leg" in out and "filter 2tap" in out and "20 Hz" in out


def test_movements_bad_input(capsys, files, tmp_path):
    sim = make_infant(minutes=6, seed=44, errors=LEFT)
    write_infant(tmp_path / "ax3.cwa", sim, device="ax3")
    code, _, err = cli(capsys, "movements", tmp_path / "ax3.cwa", "-o", tmp_path / "m.csv")
    assert code == 2 and "no gyroscope" in err and not (tmp_path / "m.csv").exists()
    code, out, _ = cli(capsys, "movements", tmp_path / "ax3.cwa", "--accel-only", "--json")
    assert code == 0 and "NOT VALIDATED" in " ".join(json.loads(out)["left"]["flags"])
    write_infant(tmp_path / "sleep.cwa", make_infant(minutes=7, seed=45, sleep_blocks=[(0, 7)]))
    code, _, err = cli(capsys, "movements", tmp_path / "sleep.cwa", "-o", tmp_path / "m.csv")
    assert code == 2 and "sleep.cwa" in err and not (tmp_path / "m.csv").exists()
    write_cwa(tmp_path / "empty.cwa", np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)))
    code, _, err = cli(capsys, "movements", tmp_path / "empty.cwa")
    assert code == 2 and "no samples" in err


def test_simulate_scenarios(capsys, tmp_path):
    code, out, _ = cli(capsys, "simulate", "--scenario", "sixface", "--device", "ax6", "-o",
                       tmp_path / "s.cwa", "--seed", "3", "--json")
    assert code == 0 and json.loads(out)["device_key"] == "AX6-4003"
    truth = json.loads((tmp_path / "s.truth.json").read_text())
    assert len(truth["holds"]) == 6
    code, out, _ = cli(capsys, "static-calibrate", tmp_path / "s.cwa", "--mode", "robust", "--json")
    np.testing.assert_allclose(json.loads(out)["offset_g"], truth["errors"]["offset_g"], atol=1e-3)
    code, out, _ = cli(capsys, "simulate", "--scenario", "infant", "--device", "ax3", "-o",
                       tmp_path / "i.cwa", "--minutes", "3", "--controls", "--sleep", "1:1")
    assert code == 0 and "kicks" in out
    code, _, err = cli(capsys, "simulate", "--scenario", "infant", "--device", "geneactiv", "-o",
                       tmp_path / "i.bin")
    assert code == 2 and "i.bin" in err


def test_process_applies_static_calibration(capsys, files, tmp_path):
    cal = tmp_path / "cal.json"
    cli(capsys, "static-calibrate", files["cal_left"], "--mode", "robust", "-o", cal)
    out = tmp_path / "left.mcap"
    code, text, _ = cli(capsys, "process", files["left"], "-o", out, "--static", cal, "--json", "-q")
    assert code == 0
    s = json.loads(text)
    assert s["calibration"]["method"] == "static-6"
    np.testing.assert_allclose(s["calibration"]["offset"], -np.asarray(LEFT.offset_g), atol=1e-3)
    assert s["static_calibration"]["gap_hours"] is not None
    from mcap.reader import make_reader
    with open(out, "rb") as fh:
        msgs = [json.loads(m.data) for _, ch, m in make_reader(fh).iter_messages()
                if ch.topic == "/calibration"]
    assert len(msgs) == 1 and msgs[0]["method"] == "static-6" and msgs[0]["applied"] is True
    assert msgs[0]["extra"]["static"]["faces"]["+x"]["samples"] > 0
    code, text, _ = cli(capsys, "replay", out, "-o", tmp_path / "r.mcap", "--check", "-q")
    assert code == 0 and "DIFFERENT" not in text
    code, _, err = cli(capsys, "process", files["left"], "-o", tmp_path / "n.mcap", "--static", cal,
                       "--no-calibrate", "-q")
    assert code == 2 and "--no-calibrate" in err and not (tmp_path / "n.mcap").exists()
    # the right leg's device is not the calibration's
    code, _, err = cli(capsys, "process", files["right"], "-o", tmp_path / "r2.mcap", "--static", cal,
                       "-q")
    assert code == 2 and "AX6-601" in err and not (tmp_path / "r2.mcap").exists()


def test_station_download_applies_the_stored_static_calibration(tmp_path, monkeypatch):
    from stillpoint.drivers.ax.emulator import EmulatedDevice
    from stillpoint.engine.sim.record import device_recording
    from stillpoint.engine.calibration import CalibrationStore
    from stillpoint.engine.calibration.static import static_calibration, with_static_calibration
    from stillpoint.engine.station.download import DownloadJob, run_download
    monkeypatch.setenv("STILLPOINT_RUNTIME_DIR", str(tmp_path / "runtime"))
    d = EmulatedDevice(tmp_path / "dev", 12346, "AX6", slot="emu-1", make_recording=device_recording, days=0.003, remount_s=0.05,
                       replug_s=0.3)
    d.plug()
    try:
        s = simulate_sixface(fs=25, errors=LEFT, seed=46)
        cal = static_calibration(s.accel_g, 25, mode="robust", time_ns=s.time_ns,
                                 device_key="AX6-12346")
        CalibrationStore(tmp_path / "store").add(cal.to_estimate(), source="cal.cwa")
        assert with_static_calibration({}, tmp_path / "store", "AX6-99999") == {}
        settings = with_static_calibration({}, tmp_path / "store", "AX6-12346")
        out = tmp_path / "out"
        out.mkdir()
        r = run_download(DownloadJob(d.device_id, d.session_id, str(d.data_file), str(out), d.kind,
                                     tuple(sorted(d.faults)), str(d.control), settings=settings))
        assert r.ok, r.reason
        assert r.summary["calibration"]["method"] == "static-6"
        np.testing.assert_allclose(r.summary["calibration"]["offset"], -np.asarray(cal.offset_g))
    finally:
        d.shutdown()


def test_mcap_logs_read_back_with_the_mcap_package(capsys, files, tmp_path):
    from mcap.reader import make_reader

    def read(p):
        with open(p, "rb") as fh:
            return [(ch.topic, sch.name if sch else None, json.loads(m.data))
                    for sch, ch, m in make_reader(fh).iter_messages()]

    cal = tmp_path / "cal.json"
    code, _, _ = cli(capsys, "static-calibrate", files["cal_left"], "--mode", "robust", "-o", cal,
                     "--mcap", tmp_path / "cal.mcap")
    assert code == 0
    (topic, schema, est), = read(tmp_path / "cal.mcap")
    assert topic == "/static_calibration" and schema == "stillpoint.StaticCalibrationEstimate"
    assert est["method"] == "static-6" and est["positions"] == 6
    assert est["extra"]["static"]["offset_g"] == json.loads(cal.read_text())["offset_g"]
    code, out, _ = cli(capsys, "movements", files["left"], "--calibration", cal, "--json",
                       "--mcap", tmp_path / "mv.mcap")
    assert code == 0
    msgs = read(tmp_path / "mv.mcap")
    events = [m for t, _, m in msgs if t == "/movements/left/events"]
    assert len(events) == json.loads(out)["left"]["count"]
    (summary,) = [m for t, _, m in msgs if t == "/movements/left/summary"]
    (params,) = [m for t, _, m in msgs if t == "/movements/left/parameters"]
    assert summary["count"] == len(events) and params["variant"] == "v2"
    assert params["calibration"]["applied"] and any(t == "/static_calibration" for t, _, _ in msgs)
    assert [e["start_ns"] for e in events] == sorted(e["start_ns"] for e in events)


def test_movements_with_a_coupled_sensor_match_the_error_free_count(capsys, tmp_path):
    # 1.2-2 % symmetric cross-axis coupling on every pair, calibrated from a session with hand-timed
    # holds of unequal length; counted against an error-free sensor with the same noise
    rng = np.random.default_rng((1, 2))
    e = StaticErrors(offset_g=list(rng.uniform(-0.1, 0.1, 3)), gain=list(rng.uniform(0.99, 1.015, 3)),
                     symmetric=list(rng.choice([-1.0, 1.0], 3) * rng.uniform(0.012, 0.02, 3)),
                     noise_g=[0.002] * 3)
    write_sixface(tmp_path / "cal.cwa", simulate_sixface(fs=25, errors=e, seed=1001,
                                                         hold_s=rng.uniform(7, 12, 6)), device_id=611)
    write_infant(tmp_path / "leg.cwa", make_infant(minutes=10, seed=1, n_postures=6, errors=e),
                 device_id=611)
    write_infant(tmp_path / "free.cwa", make_infant(minutes=10, seed=1, n_postures=6,
                                                    errors=StaticErrors(noise_g=e.noise_g)),
                 device_id=612)
    code, out, _ = cli(capsys, "movements", tmp_path / "free.cwa", "--json")
    assert code == 0
    free = json.loads(out)["left"]["count"]
    code, out, _ = cli(capsys, "static-calibrate", tmp_path / "cal.cwa", "--mode", "robust",
                       "--full-matrix", "--json", "-o", tmp_path / "cal.json")
    assert code == 0
    doc = json.loads(out)
    np.testing.assert_allclose(doc["offset_g"], e.offset_g, atol=0.001)
    np.testing.assert_allclose(doc["cross_axis_g"], e.matrix - np.diag(np.diag(e.matrix)), atol=0.001)
    for f, d in doc["faces"].items():  # after the affine correction each face reads +-1 g
        assert d["corrected_norm_error_g"] < 0.001 and d["corrected_tilt_deg"] < 0.1, (f, d)
    code, out, _ = cli(capsys, "static-calibrate", tmp_path / "cal.cwa", "--mode", "robust")
    assert code == 0 and "cross-axis coupling, %" in out and "--full-matrix" in out

    def count(*opts):
        code, out, _ = cli(capsys, "movements", tmp_path / "leg.cwa", "--calibration",
                           tmp_path / "cal.json", "--json", *opts)
        assert code == 0
        return json.loads(out)["left"]["count"]

    assert count() == count("--full-matrix") == free  # the calibration's matrix is applied
    raw = json.loads(cli(capsys, "movements", tmp_path / "leg.cwa", "--json")[1])["left"]["count"]
    assert raw != free
    # offset and gain alone leave u^T M u in the rest level: the count moves
    doc.pop("matrix")
    doc.pop("matrix_offset_g")
    (tmp_path / "diag.json").write_text(json.dumps(doc))
    code, out, _ = cli(capsys, "movements", tmp_path / "leg.cwa", "--calibration",
                       tmp_path / "diag.json", "--json")
    assert code == 0 and json.loads(out)["left"]["count"] != free


def test_simulate_sixface_with_coupling_and_a_tilted_table(capsys, tmp_path):
    code, out, _ = cli(capsys, "simulate", "--scenario", "sixface", "-o", tmp_path / "s.cwa",
                       "--seed", "5", "--coupling", "0.02", "--table-tilt-deg", "1", "--json")
    assert code == 0
    truth = json.loads((tmp_path / "s.truth.json").read_text())
    sym = np.asarray(truth["errors"]["symmetric"])
    assert np.all(np.abs(sym) <= 0.02) and np.abs(sym).max() > 0.005
    assert truth["settings"]["table_tilt_deg"] == 1.0
    code, out, _ = cli(capsys, "static-calibrate", tmp_path / "s.cwa", "--mode", "robust", "--json")
    doc = json.loads(out)
    np.testing.assert_allclose(doc["offset_g"], truth["errors"]["offset_g"], atol=0.001)
    assert np.abs(doc["diagnostics"]["off_axis_pair_mean_g"]).max() > 0.004  # the tilt, flagged
    code, _, _ = cli(capsys, "simulate", "--scenario", "sixface", "-o", tmp_path / "n.cwa",
                     "--sensor-errors", "none", "--coupling", "0.01", "--json")
    sym = np.asarray(json.loads((tmp_path / "n.truth.json").read_text())["errors"]["symmetric"])
    assert code == 0 and 0 < np.abs(sym).max() <= 0.01
    for extra in (["--coupling", "0.01"], ["--table-tilt-deg", "1"]):
        code, _, err = cli(capsys, "simulate", "-o", tmp_path / "x.cwa", "--days", "0.01", *extra)
        assert code == 2 and extra[0] in err and "ignored" in err and not (tmp_path / "x.cwa").exists()
    code, _, err = cli(capsys, "simulate", "--scenario", "infant", "-o", tmp_path / "i.cwa",
                       "--table-tilt-deg", "1")
    assert code == 2 and "--table-tilt-deg" in err
