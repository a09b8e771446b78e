"""Calibration estimates are validated where they are loaded (store records, --prior, the run's
prior): NaN or absurd values are refused with one line, never applied to the data."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from stillpoint.engine.calibration import CalibrationEstimate, CalibrationStore, CalibrationStoreError
from stillpoint.engine.calibration.validate import InvalidEstimateError, validate_estimate


def good(**kw):
    d = {"offset": [0.01, -0.02, 0.03], "scale": [1.01, 0.99, 1.0], "tempoffset": [0, 0, 0.001],
         "temperature_ref": 25.0, "status": "ok", "method": "autocal-c2", "device_key": "AX3-1"}
    d.update(kw)
    return d


@pytest.mark.parametrize("field, value, what", [
    ("offset", [float("nan"), 0, 0], "offset"),
    ("offset", [3.0, 0, 0], "offset"),
    ("scale", [1e6, 1, 1], "scale"),
    ("scale", [0, 1, 1], "scale"),
    ("tempoffset", [0, float("inf"), 0], "tempoffset"),
    ("tempoffset", [0, 1.0, 0], "tempoffset"),
    ("temperature_ref", float("nan"), "temperature_ref"),
    ("offset", [1, 2], "offset"),
    ("offset", "abc", "offset"),
])
def test_absurd_estimates_are_refused(field, value, what):
    with pytest.raises(InvalidEstimateError, match=what):
        validate_estimate(good(**{field: value}), "test")


def test_a_real_estimate_passes():
    est = validate_estimate(good(), "test")
    assert isinstance(est, CalibrationEstimate)
    np.testing.assert_array_equal(est.scale, [1.01, 0.99, 1.0])


def _store_with(tmp_path, estimate: dict):
    root = tmp_path / "store"
    store = CalibrationStore(root)
    store.add(CalibrationEstimate.from_dict(good()))
    path = store.dir / "AX3-1.json"
    doc = json.loads(path.read_text())
    doc["records"][0]["estimate"].update(estimate)
    path.write_text(json.dumps(doc))
    return store


def test_nan_store_record_is_refused_at_load(tmp_path):
    store = _store_with(tmp_path, {"offset": [float("nan"), 0, 0]})
    with pytest.raises(InvalidEstimateError, match="record 0"):
        store.prior_for("AX3-1")


def test_store_never_writes_an_invalid_estimate(tmp_path):
    store = CalibrationStore(tmp_path / "s")
    with pytest.raises(InvalidEstimateError):
        store.add(CalibrationEstimate.from_dict(good(scale=[5, 1, 1])))


@pytest.mark.parametrize("damage", ["record_not_object", "estimate_missing", "records_not_list"])
def test_malformed_store_records(tmp_path, damage):
    store = CalibrationStore(tmp_path / "s")
    store.add(CalibrationEstimate.from_dict(good()))
    path = store.dir / "AX3-1.json"
    doc = json.loads(path.read_text())
    if damage == "record_not_object":
        doc["records"][0] = 7
    elif damage == "estimate_missing":
        del doc["records"][0]["estimate"]
    else:
        doc["records"] = {"a": 1}
    path.write_text(json.dumps(doc))
    with pytest.raises(CalibrationStoreError, match="AX3-1.json"):
        store.latest("AX3-1")


def test_store_root_that_is_a_file(tmp_path):
    (tmp_path / "root").write_text("x")
    store = CalibrationStore(tmp_path / "root")
    with pytest.raises(CalibrationStoreError, match="must be a folder"):
        store.add(CalibrationEstimate.from_dict(good()))
    with pytest.raises(CalibrationStoreError, match="must be a folder"):
        store.devices()


def test_lock_path_that_is_a_folder(tmp_path):
    store = CalibrationStore(tmp_path / "s")
    store.dir.mkdir(parents=True)
    (store.dir / "AX3-1.json.lock").mkdir()
    with pytest.raises(CalibrationStoreError, match="lock"):
        store.add(CalibrationEstimate.from_dict(good()))


def test_cli_prior_nan_refused(tmp_path):
    from stillpoint.drivers.cwa_writer import CwaWriter
    rec = tmp_path / "r.cwa"
    w = CwaWriter(rec, rate_hz=25)
    n = 25 * 120
    w.write(1_700_000_000_000_000_000 + np.arange(n) * 40_000_000, np.tile([0, 0, 256], (n, 1)))
    w.close()
    prior = tmp_path / "p.json"
    prior.write_text(json.dumps(good(offset=[float("nan"), 0, 0])).replace("NaN", "NaN"))
    r = subprocess.run([sys.executable, "-m", "tools", "process", str(rec), "--mode", "online",
                        "--prior", str(prior), "-o", str(tmp_path / "o.mcap")],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "--prior" in r.stderr and "offset" in r.stderr
    assert not (tmp_path / "o.mcap").exists()
