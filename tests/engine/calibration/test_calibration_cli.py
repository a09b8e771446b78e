"""`stillpoint calibrate`, `calibrate-features` and `calibration` from the command line."""

from __future__ import annotations

import csv
import json
import sys

import numpy as np
import pytest

from stillpoint.engine.calibration import fit_calibration
from stillpoint.engine.calibration.fit import rereference
from synthetic_calibration import (random_truth, synthetic_recording,
                                                     write_synthetic_cwa)
from stillpoint.engine.calibration.table import read_features_csv
from stillpoint.tools.cli import main

KEYS = ["offset", "scale", "tempoffset", "temperature_ref", "error_before_mg", "error_after_mg",
        "windows", "iterations", "status", "reason"]


def run_cli(capsys, *argv):
    code = main(list(argv))
    out = capsys.readouterr()
    return code, out.out, out.err


@pytest.fixture(scope="module")
def truth():
    return random_truth(np.random.default_rng(61))


@pytest.fixture(scope="module")
def features_csv(tmp_path_factory, truth):
    rec = synthetic_recording(30, truth, seed=62)
    f = rec.features.select(rec.still)
    p = tmp_path_factory.mktemp("feat") / "sphere.csv"
    with open(p, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["window_index", "Euclidean Norm", "meanx", "meany", "meanz", "sdx", "sdy",
                    "sdz", "temperature", "unrelated"])
        for i in range(len(f)):
            w.writerow([int(f.start_ns[i] // 10**10), repr(float(f.norm_mean[i]))]
                       + [repr(float(v)) for v in f.mean[i]] + [repr(float(v)) for v in f.sd[i]]
                       + [repr(float(f.temperature[i])), "x"])
    return p, f


def test_calibrate_features_json(capsys, features_csv, truth):
    path, f = features_csv
    code, out, _ = run_cli(capsys, "calibrate-features", str(path), "--json")
    assert code == 0
    d = json.loads(out)
    assert list(d)[:len(KEYS)] == KEYS
    assert d["status"] == "ok" and d["windows"] == len(f)
    api = fit_calibration(read_features_csv(path), select=False)
    assert d["offset"] == api.offset.tolist() and d["tempoffset"] == api.tempoffset.tolist()
    tr = rereference(truth, d["temperature_ref"])
    np.testing.assert_allclose(d["offset"], tr.offset, atol=0.1e-3)
    code, out, _ = run_cli(capsys, "calibrate-features", str(path), "--json", "--no-temperature")
    d1 = json.loads(out)
    assert d1["tempoffset"] == [0.0, 0.0, 0.0] and d1["temperature_used"] is False


def test_calibrate_features_ggir_and_human(capsys, features_csv):
    path, _ = features_csv
    code, out, _ = run_cli(capsys, "calibrate-features", str(path), "--ggir-compatible", "--json")
    d = json.loads(out)
    assert d["stop_rule"] == "ggir-res"
    assert d["error_after_g"] == round(d["error_after_mg"] / 1000, 5)
    code, out, _ = run_cli(capsys, "calibrate-features", str(path))
    assert code == 0 and "status       ok" in out and "offset (g)" in out


def test_calibrate_features_bad_tables(capsys, tmp_path):
    p = tmp_path / "bad.csv"
    p.write_text("meanx,meany,sdx\n1,2,3\n")
    code, _, err = run_cli(capsys, "calibrate-features", str(p))
    assert code == 2 and "missing column(s) meanz, sdy, sdz" in err and err.count("\n") == 1
    p.write_text("meanx,meany,meanz,sdx,sdy,sdz\n0,0,1,0,0,0\n0,zero,1,0,0,0\n")
    code, _, err = run_cli(capsys, "calibrate-features", str(p))
    assert code == 2 and "line 3" in err
    code, _, err = run_cli(capsys, "calibrate-features", str(tmp_path / "nope.csv"))
    assert code == 2 and "no such file" in err


def test_real_sphere_data_cli_matches_api(capsys, real_file):
    p = real_file("calib_features_ggir_data_calibrate_spheredata_84h.csv")
    code, out, _ = run_cli(capsys, "calibrate-features", str(p), "--ggir-compatible", "--json")
    d = json.loads(out)
    api = fit_calibration(read_features_csv(p), ggir_compatible=True)
    assert code == 0 and d["offset"] == api.offset.tolist() and d["scale"] == api.scale.tolist()
    assert d["windows"] == 10958 and d["status"] == "ok"


@pytest.fixture(scope="module")
def cwa_file(tmp_path_factory, truth):
    rec = synthetic_recording(10, truth, seed=63)
    p = tmp_path_factory.mktemp("cwa") / "synthetic.cwa"
    write_synthetic_cwa(p, rec.features, rate_hz=25.0, seed=64, device_id=4242)
    return p


def test_calibrate_cwa_end_to_end_with_store(capsys, cwa_file, truth, tmp_path):
    store = tmp_path / "store"
    code, out, err = run_cli(capsys, "calibrate", str(cwa_file), "--json", "--first-hours", "6",
                             "--chunk-hours", "2", "--store", "--store-dir", str(store))
    assert code == 0, err
    d = json.loads(out)
    assert d["status"] == "ok" and d["device_key"] == "AX3-4242"
    assert d["hours_used"] == pytest.approx(6.0) and d["read_to_end"] is False
    tr = rereference(truth, d["temperature_ref"])
    np.testing.assert_allclose(d["offset"], tr.offset, atol=0.5e-3)
    np.testing.assert_allclose(np.array(d["scale"]) / truth.scale, 1.0, atol=5e-4)
    assert d["error_after_mg"] < 1.0 < 10.0 < d["error_before_mg"]
    code, out, _ = run_cli(capsys, "calibration", "--store-dir", str(store), "list")
    assert code == 0 and "AX3-4242" in out
    code, out, _ = run_cli(capsys, "calibration", "--store-dir", str(store), "show", "AX3-4242")
    assert code == 0 and "autocal-c2" in out and str(cwa_file) in out
    code, out, _ = run_cli(capsys, "calibration", "--store-dir", str(store), "show", "AX3-1",
                           "--json")
    assert code == 2
    exp = tmp_path / "export.json"
    code, _, _ = run_cli(capsys, "calibration", "--store-dir", str(store), "export", "-o", str(exp))
    doc = json.loads(exp.read_text())
    assert doc["devices"]["AX3-4242"][0]["estimate"]["offset"] == d["offset"]


def test_calibrate_whole_file_and_bad_input(capsys, cwa_file, tmp_path):
    code, out, _ = run_cli(capsys, "calibrate", str(cwa_file), "--json", "--no-temperature")
    d = json.loads(out)  # default 72 h first load on a 10 h file: all of it, flagged short
    assert d["status"] == "ok" and "short" in d["flags"] and d["read_to_end"] is True
    assert d["tempoffset"] == [0.0, 0.0, 0.0] and d["hours_used"] == pytest.approx(10.0, abs=0.01)
    junk = tmp_path / "junk.cwa"
    junk.write_bytes(b"not a recording at all" * 40)
    code, _, err = run_cli(capsys, "calibrate", str(junk))
    assert code == 2 and "junk.cwa" in err


def test_plot_writes_png(capsys, features_csv, tmp_path, monkeypatch):
    pytest.importorskip("matplotlib", reason="matplotlib (the plot extra) is not installed")
    path, _ = features_csv
    png = tmp_path / "cal.png"
    code, out, _ = run_cli(capsys, "calibrate-features", str(path), "--plot", str(png))
    assert code == 0 and png.stat().st_size > 10000
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_plot_without_matplotlib_is_a_clear_error(capsys, features_csv, tmp_path, monkeypatch):
    path, _ = features_csv
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    code, _, err = run_cli(capsys, "calibrate-features", str(path), "--plot",
                           str(tmp_path / "x.png"))
    assert code == 2 and "matplotlib" in err and "stillpoint[plot]" in err


@pytest.mark.parametrize("jobs", ["1", "2"])
def test_calibrate_cohort_several_files(capsys, cwa_file, tmp_path, jobs):
    junk = tmp_path / "junk.bin"
    junk.write_bytes(b"\x00" * 2000)
    plots = tmp_path / "plots"
    extra = ["--plot", str(plots)] if jobs == "2" else []
    code, out, err = run_cli(capsys, "calibrate", str(cwa_file), str(junk), str(cwa_file),
                             "--json", "--first-hours", "6", "-j", jobs, *extra)
    lines = [json.loads(x) for x in out.splitlines()]
    assert code == 2 and "junk.bin" in err
    assert [d["file"] for d in lines] == [str(cwa_file), str(junk), str(cwa_file)]
    assert lines[1]["status"] == "error" and "junk.bin" in lines[1]["reason"]
    assert lines[0]["status"] == "ok" and lines[0]["offset"] == lines[2]["offset"]
    assert (plots / (cwa_file.name + ".png")).is_file() == (jobs == "2")
