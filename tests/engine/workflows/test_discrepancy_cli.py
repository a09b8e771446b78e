"""`stillpoint discrepancy` from the command line: feature tables, a simulated .cwa recording end to
end (simulator -> writer -> reader -> window operator -> workflow), an MCAP log, the report files,
the JSON keys, and bad input."""

import json

import numpy as np
import pytest

from stillpoint.engine.sim import model as sim
from stillpoint.engine.workflows import scenarios
from stillpoint.engine.workflows.simwindows import simulate_windows
from stillpoint.tools.cli import main

KEYS = {"steps", "final_model", "gap_initial_mg", "gap_final_mg", "noise_floor_mg"}
STEP_KEYS = {"effect", "axis", "parameters", "gap_before_mg", "gap_after_mg", "delta_bic"}


def _table(path, feats, still):
    f = feats.select(still)
    rows = np.column_stack([f.start_ns // 10**10, f.mean, f.sd, f.temperature])
    np.savetxt(path, rows, delimiter=",", comments="",
               header="window_index,meanx,meany,meanz,sdx,sdy,sdz,temperature",
               fmt=["%d"] + ["%.10f"] * 7)


@pytest.fixture(scope="module")
def hidden_table(tmp_path_factory):
    d = tmp_path_factory.mktemp("disc")
    truth, start = scenarios.models("temperature_offset", 5)
    sw = simulate_windows(truth, days=1.5, seed=5)
    feats, still, truth = sw.features, sw.still, sw.truth
    p = d / "features.csv"
    _table(p, feats, still)
    (d / "truth.json").write_text(truth.to_json())
    (d / "start.json").write_text(start.to_json())
    return d


def test_feature_table_json_report_names_the_hidden_effect(hidden_table, capsys, tmp_path):
    out = tmp_path / "report"
    rc = main(["discrepancy", str(hidden_table / "features.csv"), "--model",
               str(hidden_table / "start.json"), "--truth", str(hidden_table / "truth.json"),
               "-o", str(out), "--json"])
    assert rc == 0
    d = json.loads(capsys.readouterr().out)
    assert KEYS <= set(d)
    assert [(s["effect"], s["axis"]) for s in d["steps"]] == [("temperature_offset", "z")]
    s = d["steps"][0]
    assert STEP_KEYS <= set(s)
    assert s["delta_bic"] < -10 and s["gap_after_mg"] < s["gap_before_mg"]
    assert s["parameters"]["temperature_offset.z"]["value"] == pytest.approx(1.5, abs=0.2)
    assert s["parameters"]["temperature_offset.z"]["unit"] == "mg/degC"
    assert d["gap_final_mg"] <= 1.2 * d["noise_floor_mg"]
    # the written model is the simulator's format and is accepted by it as-is
    m = sim.load_model(out / "final_model.json")
    assert m.effects["temperature_offset"]["z_mg_per_c"] == pytest.approx(1.5, abs=0.2)
    sim.resolve_model(m, seed=0)
    assert (out / "report.txt").read_text().startswith("stillpoint discrepancy")
    # per window: what the final model predicts the sensor read is what it read, up to the norm
    # residual (the prediction is 1 g in the corrected direction)
    w = np.genfromtxt(out / "windows.csv", delimiter=",", names=True)
    assert w.size == d["input"]["windows_nonmovement"] - d["input"]["duplicates_dropped"]
    meas = np.column_stack([w["meanx"], w["meany"], w["meanz"]])
    pred = np.column_stack([w["final_x"], w["final_y"], w["final_z"]])
    dist = np.linalg.norm(meas - pred, axis=1) * 1000
    assert np.allclose(dist, np.abs(w["residual_final_mg"]), rtol=0.05, atol=0.05)
    pngs = sorted(p.name for p in out.glob("*.png"))
    pytest.importorskip("matplotlib")
    assert "step1_temperature_offset_z.png" in pngs and "locate_initial.png" in pngs


def test_text_output_and_effect_restriction(hidden_table, capsys):
    rc = main(["discrepancy", str(hidden_table / "features.csv"), "--effects", "offset_drift,misalignment"])
    assert rc == 0
    out = capsys.readouterr().out
    assert "Held-out gap" in out
    # the hidden temperature offset is not in the restricted library: it cannot be named
    assert "temperature-dependent offset" not in out


def test_simulated_recording_end_to_end(tmp_path, capsys):
    from stillpoint.engine.sim.record import simulate_recording
    rec = tmp_path / "rec.cwa"
    simulate_recording(rec, device="ax3", days=1.0, hz=25.0, seed=3,
                       effects=sim.SensorModel({"offset": {}, "gain": {}, "noise": {},
                                                "quantisation": {},
                                                "temperature_offset": {"x_mg_per_c": 0.0,
                                                                       "y_mg_per_c": 0.0,
                                                                       "z_mg_per_c": 3.0}}))
    truth = tmp_path / "rec.truth.json"
    assert truth.exists()
    rc = main(["discrepancy", str(rec), "--truth", str(truth), "--json", "--no-plots"])
    assert rc == 0
    d = json.loads(capsys.readouterr().out)
    assert d["input"]["windows_nonmovement"] > 1000 and d["input"]["rate_hz"] == 25.0
    named = [(s["effect"], s["axis"]) for s in d["steps"]]
    assert named[0] == ("temperature_offset", "z")
    assert d["final_model"]["effects"]["temperature_offset"]["z_mg_per_c"] == pytest.approx(3.0, abs=1.0)
    assert d["gap_final_mg"] < d["gap_initial_mg"]
    assert d["gap_final_mg"] <= 1.2 * d["noise_floor_mg"]
    # noise/quantisation check: the model's noise is below one packed-AX3 step, so most still
    # windows read a constant value on some axis and the check says so
    sd = d["distributions"]["still_window_sd_mg"]
    assert max(v["zero_fraction"] for v in sd.values()) > 0.05
    # the step measured from the counts: AX3 packed at +-8 g stores multiples of 4/256 g, and the
    # model noise at 25 Hz (~1.4-1.9 mg) cannot dither it: window means can be biased by ~3-4 mg
    assert d["input"]["quantisation_step_mg"] == [15.625] * 3
    assert all(3.0 < v["quantisation_bias_max_mg"] < 5.0 for v in sd.values())


def test_bad_inputs_exit_2_with_one_line(tmp_path, capsys):
    assert main(["discrepancy", str(tmp_path / "missing.csv")]) == 2
    assert "no such file" in capsys.readouterr().err
    short = tmp_path / "short.csv"
    short.write_text("meanx,meany,meanz,sdx,sdy,sdz,temperature\n0,0,1,0.005,0.005,0.005,25\n")
    assert main(["discrepancy", str(short)]) == 2
    err = capsys.readouterr().err
    assert "nonmovement windows" in err and len(err.strip().splitlines()) == 1
    assert main(["discrepancy", str(short), "--effects", "wobble"]) == 2
    assert "unknown candidate effect" in capsys.readouterr().err
    bad_model = tmp_path / "m.json"
    bad_model.write_text('{"effects": {"offset": {"q_mg": 1}}}')
    assert main(["discrepancy", str(short), "--model", str(bad_model)]) == 2
    assert "no parameter 'q_mg'" in capsys.readouterr().err


def test_mcap_log_gives_the_same_windows_and_report_as_its_recording(tmp_path):
    from stillpoint.engine.run import process_file
    from stillpoint.engine.sim.record import simulate_recording
    from stillpoint.engine.workflows.api import analyse
    rec = tmp_path / "short.cwa"
    from stillpoint.engine.sim.wearer import WearerParams
    # a perfectly still body: repeated identical windows occur, so their collapsing is compared too
    simulate_recording(rec, device="ax3", days=0.3, hz=12.5, seed=8, truth_path=False,
                       labels_path=False, wearer=WearerParams(still_micromotion_mg=0.0),
                       effects=sim.SensorModel({"offset": {}, "gain": {}, "noise": {},
                                                "quantisation": {}}))
    log = tmp_path / "short.mcap"
    process_file(rec, log)
    a, da = analyse(rec, plots=False)
    b, db = analyse(log, plots=False)
    assert db["input"]["source"].startswith("MCAP log")
    for k in ("windows_total", "windows_nonmovement", "duplicates_dropped"):
        assert da["input"][k] == db["input"][k] > 0
    assert da["gap_initial_mg"] == db["gap_initial_mg"]
    assert [s["effect"] for s in da["steps"]] == [s["effect"] for s in db["steps"]]


def test_table_without_temperature_skips_temperature_candidates_with_a_reason(hidden_table, capsys,
                                                                              tmp_path):
    rows = (hidden_table / "features.csv").read_text().splitlines()
    notemp = tmp_path / "notemp.csv"
    notemp.write_text("\n".join(",".join(r.split(",")[:7]) for r in rows) + "\n")
    assert main(["discrepancy", str(notemp), "--json", "--no-plots"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["input"]["temperature_available"] is False
    skipped = {(c["effect"], c["reason"]) for c in d["candidates_skipped"]}
    assert ("temperature_offset", "no usable temperature") in skipped
    assert ("thermal_lag", "no usable temperature") in skipped
    assert all(s["effect"] not in ("temperature_offset", "temperature_gain") for s in d["steps"])
