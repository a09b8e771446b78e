"""The run summary's parts that are computed rather than copied: the reader's QC."""

from __future__ import annotations

from . import tuning


def qc_summary(source) -> dict:
    """The reader's QC report as the summary's ``qc`` object: counts, events per reason and the
    first ``tuning.QC_DETAILS`` described events."""
    qc = getattr(source, "qc", None)
    if qc is None:
        return {}
    d = qc.as_dict()
    events = d.pop("events")
    d["events"] = len(events)
    reasons: dict[str, int] = {}
    for e in events:
        reasons[e["reason"]] = reasons.get(e["reason"], 0) + 1
    d["reasons"] = reasons
    # what was wrong, in the reader's words, for the tables a study reads (the cohort summary):
    # the first QC_DETAILS events that carry a description (no key when there are none)
    details = [f"{e['reason']} at {d.get('unit', 'unit')} {e['index']}: {e['detail']}"
               for e in events if e.get("detail")][:tuning.QC_DETAILS]
    if details:
        d["details"] = details
    return d
