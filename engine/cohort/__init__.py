"""Cohorts: the per-file job run over thousands of recordings, idempotent and resumable.

The output folder is the single source of truth. Each input gets a key, a hash of (its first
bytes, its size, the canonical settings, the code version), and one folder named by that key;
a folder holding ``_DONE.json`` is finished and is never recomputed, a folder holding
``_FAILED.json`` records a failure with its class. Everything else (a ``.tmp`` folder left by a
killed run, a file never started) is pending, so any run can be stopped at any point and rerun.

Modules: ``plan`` (finding inputs, keys, the manifest, shards), ``job`` (the per-file job and its
markers, failure classes), ``execute`` (Dask distributed, a local process pool, or in-process:
bounded batches, retries, progress, clean interrupt), ``collate`` (status, the cohort summary
table and the failure table).
"""

from .collate import CohortStatus, collate, status
from .execute import CohortResult, run_cohort
from .job import FAILURE_CLASSES, run_job
from .plan import Entry, Plan, discover_inputs, make_plan

__all__ = ["CohortResult", "CohortStatus", "Entry", "FAILURE_CLASSES", "Plan", "collate",
           "discover_inputs", "make_plan", "run_cohort", "run_job", "status"]
