"""The calibration outcome: the status enum and its ``applied`` rule, the typed fit diagnostics,
one outcome producing the message, QC event, record, summary and table column, and the one store
rule."""

from __future__ import annotations

import json

import numpy as np
import pytest

from stillpoint.engine.calibration.estimate import (CalibrationEstimate, CalibrationStatus,
                                                    FitDiagnostics, STATIC_METHOD, status_applied)
from stillpoint.engine.calibration.outcome import CalibrationOutcome, store_refusal


def _fit(status="ok", **kw) -> CalibrationEstimate:
    return CalibrationEstimate(offset=[0.01, -0.02, 0.03], scale=[1.01, 0.99, 1.0],
                               status=status, reason=f"{status}: a reason", method="autocal-c1",
                               fit_end_ns=123, **kw)


@pytest.mark.parametrize("status,applied", [("ok", True), ("high_error", True), ("identity", False),
                                            ("reverted", False), ("no_nonmovement", False),
                                            ("sphere_not_covered", False), ("too_few_windows", False),
                                            ("failed", False), ("incomplete", False)])
def test_status_applied(status, applied):
    assert CalibrationStatus(status).applied is applied
    assert status_applied(status) is applied
    assert _fit(status).applied is applied


def test_status_is_its_text_in_every_output():
    s = CalibrationStatus.HIGH_ERROR
    assert s == "high_error" and f"{s}" == "high_error" and str(s) == "high_error"
    assert json.dumps({"status": s}) == '{"status": "high_error"}'
    assert {"high_error": 1}[s] == 1


def test_unknown_status_of_another_version_is_kept_and_not_applied():
    est = CalibrationEstimate.from_dict({"status": "from_the_future", "reason": "r"})
    assert est.status == "from_the_future" and not isinstance(est.status, CalibrationStatus)
    assert not est.applied and not status_applied(None)


def test_fit_diagnostics_are_typed_from_extra():
    d = FitDiagnostics.from_extra({"converged": True, "flags": ["short"], "stop_rule": "parameters",
                                   "warnings": [{"code": "short", "message": "m"}], "other": 1})
    assert d.converged is True and d.flags == ["short"] and d.stop_rule == "parameters"
    assert d.warnings[0]["code"] == "short" and d.accepted is None and d.other == {"other": 1}
    assert FitDiagnostics.from_extra(None) == FitDiagnostics()


def test_fit_diagnostics_give_back_the_extra_they_were_read_from():
    extra = {"variant": "auto", "flags": ["short"], "converged": False, "res_final": None,
             "schedule": [{"hours": 24}], "first_hours": 72}
    d = FitDiagnostics.from_extra(extra)
    assert d.to_extra() == extra and d.other == {"first_hours": 72}
    d.flag("not_converged")
    d.windows_unusable = 3
    assert d.to_extra() == dict(extra, flags=["short", "not_converged"], windows_unusable=3)
    assert extra["flags"] == ["short"]  # the dict read is not changed
    assert "res_final" not in FitDiagnostics(variant="c1").to_extra()  # not reported without converged


def test_one_outcome_gives_every_report_the_same_status_and_reason():
    o = CalibrationOutcome(_fit("high_error"))
    msg, qc, summ = o.message(prior=True), o.qc_event(), o.summary()
    rec = json.loads(o.record()["json"])
    assert o.applied and msg["applied"] and qc["applied"]
    assert msg["status"] == qc["status"] == summ["status"] == rec["status"] == o.table_status \
        == "high_error"
    assert msg["reason"] == qc["detail"] == summ["reason"] == rec["reason"]
    assert msg["offset"] == summ["offset"] == rec["offset"] and msg["fitted_at_ns"] == 123
    assert msg["prior"] is True
    assert not CalibrationOutcome(_fit("ok"), applied=False).message()["applied"]


def test_explanation_reaches_every_report_once():
    est = _fit("no_nonmovement")
    o = CalibrationOutcome(est).explain(0.020, 0.013).explain(0.020, 0.013)
    assert est.reason.count("quietest window has an SD of 20.0 mg") == 1
    assert o.message()["reason"] == o.summary()["reason"] == est.reason
    quiet = _fit("no_nonmovement")
    CalibrationOutcome(quiet).explain(0.005, 0.013)  # a still window existed: nothing to add
    assert quiet.reason == "no_nonmovement: a reason"


def test_outcome_reads_old_records():
    old = {"json": json.dumps({"status": "ok", "reason": "r", "offset": [0, 0, 0.1],
                               "scale": [1, 1, 1], "tempoffset": [0, 0, 0]})}
    o = CalibrationOutcome.from_record(old)
    assert o.applied and o.status is CalibrationStatus.OK
    np.testing.assert_allclose(o.estimate.offset, [0, 0, 0.1])
    assert not CalibrationOutcome.from_record({}).applied


def test_store_rule():
    assert store_refusal(_fit("ok")) is None and store_refusal(_fit("high_error")) is None
    assert store_refusal(_fit("reverted")) == "final estimate reverted: not stored"
    static = _fit("ok")
    static.method = STATIC_METHOD
    assert "six-orientation" in store_refusal(static)


def test_explanation_names_the_rate_and_only_explains_a_missing_still_window():
    est = _fit("no_nonmovement")
    CalibrationOutcome(est).explain(0.030, 0.013, rate_hz=12.5)
    assert "SD of 30.0 mg" in est.reason and "13 mg threshold" in est.reason
    assert "noise at 12.5 Hz" in est.reason and est.extra["quietest_window_sd_mg"] == 30.0
    for status, sd in (("no_nonmovement", float("nan")), ("ok", 0.030), ("failed", 0.030)):
        other = _fit(status)
        CalibrationOutcome(other).explain(sd, 0.013, rate_hz=12.5)
        assert other.reason == f"{status}: a reason" and "quietest_window_sd_mg" not in other.extra


def test_a_log_without_a_record_reports_the_identity_not_applied():
    o = CalibrationOutcome.from_record({})
    assert o.status == "identity" and o.table_status == "identity" and not o.applied
    assert o.estimate.reason == "no calibration record"
    assert o.qc_event() == {"source": "engine", "reason": "calibration", "status": "identity",
                            "applied": False, "method": o.estimate.method,
                            "detail": "no calibration record"}
    np.testing.assert_array_equal(o.summary()["scale"], [1.0, 1.0, 1.0])
