"""The run summary: ``RunSummary``, one typed record of what a run did.

``process_file`` returns it as a dict (``RunSummary.as_dict``; `process --summary`/`--json`, a
cohort's ``summary.json``) and logs it as the ``summary`` metadata record. Its fields, with a
unit and a meaning each, are the documentation: ``docs_table()`` is the table on the Columns page
(docs/columns.md, "Run summary"), which a test keeps equal to it (``python
tools/summary_docs.py`` rewrites it), so a field cannot be added without its line in the docs.
A field marked ``optional`` is left out of the dict while it is None (it applies to some runs
only); the others are always there (``enmo_mean_mg`` may be null). A field marked
``logged=False`` is known only once the log is written, so the log's record leaves it out.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Any, Optional

from . import tuning


def _field(unit: str, meaning: str, *, optional: bool = False, logged: bool = True,
           default: Any = None):
    """A summary field: its unit and meaning (the docs); ``optional``: left out while None;
    ``logged=False``: known only after the log is written, so not in its ``summary`` record."""
    return field(default=default, metadata={"unit": unit, "meaning": meaning,
                                            "optional": optional, "logged": logged})


@dataclass
class RunSummary:
    """What one run read, estimated and wrote (field order is the dict's key order)."""

    input: str = _field("path", "the recording")
    mode: str = _field("text", "`batch` or `online`")
    device: dict = _field("object", "`type`, `id`, `session`, `rate_hz` (Hz), `range_g` (g)")
    static_calibration: Optional[dict] = _field(
        "object", "with `--static`: `device_key`, `fit_end_ns`, `gap_hours` (h from the "
        "calibration to the recording), `full_matrix_not_applied`", optional=True)
    estimates: Optional[list] = _field(
        "list", "online runs: every estimate logged, `status`, `applied`, `effective_from_ns`",
        optional=True)
    samples: Optional[int] = _field("samples", "samples read")
    duration_s: Optional[float] = _field("s", "recording span")
    segments: Optional[int] = _field("count", "continuous segments")
    windows: Optional[int] = _field("count", "10 s windows")
    nonmovement_windows: Optional[int] = _field("count", "windows the calibration used")
    epochs: Optional[int] = _field("count", "epochs computed")
    mims_near_range_epochs: Optional[int] = _field(
        "count", "with `--mims` only: epochs holding samples within 0.15 g of the range, "
        "extrapolated as R MIMSunit does (see [counts and MIMS-units](counts.md#mims-units))",
        optional=True)
    mims_unextrapolated_epochs: Optional[int] = _field(
        "count", "with `--mims` only: epochs holding near-range samples left as recorded, because "
        "their run lasted about 10 minutes or more (see [counts "
        "and MIMS-units](counts.md#mims-units))", optional=True)
    calibration: Optional[dict] = _field(
        "object", "`status`, `reason`, `method`, `offset` (g), `scale`, `tempoffset` (g/°C), "
        "`temperature_ref` (°C), `error_before_mg`, `error_after_mg` (mg), `hours_used` (h), "
        "`windows`, `fit_start_ns`, `fit_end_ns`, `uncertainty` (one standard error per "
        "coefficient, same units), `warnings`")
    enmo_mean_mg: Optional[float] = _field("mg", "mean ENMO over every epoch (null without one)")
    qc: Optional[dict] = _field(
        "object", "`unit`, `total`, `valid`, `skipped`, `segments`, `events`, `reasons` (count "
        f"per reason), `details` (the first {tuning.QC_DETAILS} described events, `reason at unit "
        "index: what was wrong`; only when there are any)")
    clipping: Optional[dict] = _field(
        "object", "`range_g` (g), `samples`, `seconds` (s), `fraction`, `longest_run_s` (s), "
        "`flagged`")
    outputs: Optional[dict] = _field(
        "object", "paths of `mcap`, `epochs`, `days`; `earlier_partial_log` when a killed "
        "earlier run's partial log was kept under a new name")
    estimates_logged: Optional[int] = _field(
        "count", "calibration estimates written to `/calibration` (an online run's list is "
        "`estimates`)")
    wall_s: Optional[float] = _field("s", "run wall time", logged=False)
    start_ns: Optional[int] = _field(
        "ns since 1970 UTC", "first sample (device clock shifted by the zone's offset)",
        optional=True)
    end_ns: Optional[int] = _field("ns since 1970 UTC", "last sample", optional=True)
    timezone: Optional[str] = _field("text", "zone used")
    timezone_override: Optional[bool] = _field(
        "true", "a header's zone was replaced by `--timezone` (`--timezone-override`)",
        optional=True)
    tables: Optional[dict] = _field(
        "object", "`epochs`, `days` (paths), `epoch_rows`, `clean_epochs`, `flags` (epochs per "
        "flag), `nonwear_windows`, `clipping_windows` (15-min windows), `day_rows`, `file` (the "
        "day table's `all` row), `nonwear_version`, `filter_warmup_s` (s), `timezone`, `rhythm`, "
        "`windows` (paths of the rhythm and windows tables)", optional=True)
    mcap_messages: Optional[int] = _field("count", "messages written", logged=False)
    mcap_flushes: Optional[int] = _field("count", "chunk flushes", logged=False)
    peak_rss_mb: Optional[dict] = _field(
        "MB", "peak resident memory of the `engine` and of the process that wrote the log "
        "(`writer`: the child process that wrote it; null when the engine did)", logged=False)

    def as_dict(self, *, log: bool = False) -> dict:
        """The summary as a dict in field order, without the optional fields that are None;
        ``log``: the ``summary`` metadata record's content (only the ``logged`` fields)."""
        out = {}
        for f in fields(self):
            v = getattr(self, f.name)
            if (v is None and f.metadata["optional"]) or (log and not f.metadata["logged"]):
                continue
            out[f.name] = v
        return out


def docs_table() -> str:
    """The Columns page's run-summary table (markdown), one row per field."""
    rows = ["| key | unit | meaning |", "|---|---|---|"]
    rows += [f"| `{f.name}` | {f.metadata['unit']} | {f.metadata['meaning']} |"
             for f in fields(RunSummary)]
    optional = ", ".join(f"`{f.name}`" for f in fields(RunSummary) if f.metadata["optional"])
    unlogged = ", ".join(f"`{f.name}`" for f in fields(RunSummary) if not f.metadata["logged"])
    return "\n".join(rows) + (f"\n\nKeys present only when they apply: {optional}. The log's "
                              f"`summary` metadata record holds the others but {unlogged} "
                              "(known only once the log is written).\n")


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
