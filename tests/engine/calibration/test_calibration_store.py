"""The per-device calibration store and the online calibrator's use of it."""

from __future__ import annotations

import json

import numpy as np
import pytest

from stillpoint.engine.calibration import (CalibrationEstimate, CalibrationStore,
                                           CalibrationStoreError, OnlineCalibrator,
                                           estimate_error_mg, fit_calibration)
from stillpoint.engine.calibration.store import HOME_ENV, default_root, device_file_name
from synthetic_calibration import random_truth, synthetic_recording


def est(status="ok", off=0.01, end_h=72, key="AX3-39434"):
    return CalibrationEstimate(offset=[off, -off, 0.0], scale=[1.01, 0.99, 1.0],
                               tempoffset=[1e-4, 0, 0], temperature_ref=27.0, status=status,
                               reason="r", method="autocal-c2", error_before_mg=20.0,
                               error_after_mg=3.0, windows=5000, hours_used=end_h,
                               fit_start_ns=0, fit_end_ns=int(end_h * 3.6e12), device_key=key)


def test_add_list_show_roundtrip(tmp_path):
    s = CalibrationStore(tmp_path)
    s.add(est(end_h=72), source="a.cwa")
    s.add(est(end_h=96, off=0.02), source="b.cwa")
    s.add(est(end_h=48, key="GENEActiv-012967"), source="c.bin")
    assert s.devices() == ["AX3-39434", "GENEActiv-012967"]
    recs = s.records("AX3-39434")
    assert [r["source"] for r in recs] == ["a.cwa", "b.cwa"]
    assert recs[0]["data_end"] == "1970-01-04T00:00:00.000Z"
    assert recs[0]["quality"] == {"error_before_mg": 20.0, "error_after_mg": 3.0,
                                  "windows": 5000, "hours_used": 72}
    back = s.estimates("AX3-39434")[1]
    np.testing.assert_array_equal(back.offset, [0.02, -0.02, 0.0])
    assert back.status == "ok" and back.method == "autocal-c2"
    rows = {r["device_key"]: r for r in s.summary()}
    assert rows["AX3-39434"]["records"] == 2 and rows["AX3-39434"]["good"] == 2
    doc = s.export()
    assert set(doc["devices"]) == {"AX3-39434", "GENEActiv-012967"}
    json.dumps(doc)  # JSON-able


def test_same_fit_twice_is_one_record(tmp_path):
    s = CalibrationStore(tmp_path)
    s.add(est(), source="a.cwa", stored_at="2026-01-01T00:00:00Z")
    s.add(est(), source="a.cwa", stored_at="2026-01-02T00:00:00Z")
    recs = s.records("AX3-39434")
    assert len(recs) == 1 and recs[0]["stored_at"] == "2026-01-02T00:00:00Z"


def test_prior_is_latest_good_estimate(tmp_path):
    s = CalibrationStore(tmp_path)
    assert s.prior_for("AX3-39434") is None
    s.add(est(end_h=72, off=0.01))
    s.add(est(end_h=120, off=0.03))
    s.add(est(status="sphere_not_covered", end_h=200, off=0.0))
    p = s.prior_for("AX3-39434")
    np.testing.assert_array_equal(p.offset, [0.03, -0.03, 0.0])
    assert p.extra["prior_from_store"]


def test_default_root_and_odd_keys(tmp_path, monkeypatch):
    monkeypatch.setenv(HOME_ENV, str(tmp_path / "home"))
    assert default_root() == tmp_path / "home"
    s = CalibrationStore()
    s.add(est(key="AX6/odd key:1"))
    assert s.devices() == ["AX6/odd key:1"]
    name = device_file_name("AX6/odd key:1")
    assert "/" not in name and (tmp_path / "home" / "calibration" / name).is_file()
    assert device_file_name("AX3-39434") == "AX3-39434.json"


def test_errors_are_clear(tmp_path):
    s = CalibrationStore(tmp_path)
    with pytest.raises(CalibrationStoreError, match="device key"):
        s.add(est(key=None))
    s.dir.mkdir(parents=True)
    (s.dir / "AX3-1.json").write_text("{not json")
    with pytest.raises(CalibrationStoreError, match="AX3-1.json"):
        s.records("AX3-1")


def test_online_starts_from_stored_prior(tmp_path):
    """A device's stored estimate is in force until an online fit beats it on the data so far."""
    rng = np.random.default_rng(51)
    truth = random_truth(rng)
    old = synthetic_recording(72, truth, seed=52)
    good = fit_calibration(old.features, device_key="AX3-7")
    s = CalibrationStore(tmp_path)
    s.add(good, source="old.cwa")
    prior = s.prior_for("AX3-7")
    new = synthetic_recording(36, truth, seed=53)
    cal = OnlineCalibrator(prior=prior)
    assert cal.current is prior and cal.device_key == "AX3-7"
    pub = cal.add(new.features)
    assert len(pub) == 2 and all(e.device_key == "AX3-7" for e in pub)
    # the stored estimate is already good; a new fit must beat it on the windows so far
    for e in pub:
        so_far = cal.windows.select(cal.windows.start_ns < e.fit_end_ns)
        err, _ = estimate_error_mg(e, so_far)
        assert e.extra["accepted"] == (err < e.extra["in_force_error_mg"])
    accepted = [e for e in pub if e.extra["accepted"]]
    assert cal.current is (accepted[-1] if accepted else prior)
    # a badly wrong prior is replaced by the first fit
    bad = CalibrationEstimate(offset=[0.05, 0, 0], status="ok", method="autocal-c1",
                              device_key="AX3-7")
    cal2 = OnlineCalibrator(prior=bad)
    pub2 = cal2.add(new.features)
    assert pub2[0].extra["accepted"] and pub2[0].extra["in_force_error_mg"] > 10
    assert cal2.current is [e for e in pub2 if e.extra["accepted"]][-1]
    assert "accepted" in pub2[0].reason
