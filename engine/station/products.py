"""The analysis products of a verified download, beside its corrected log: the epoch and day
tables and the one-page report, made by the code ``process``/``export``/``report`` use.

``make_products(job, progress=None, cancel=None) -> dict`` (a ``worker`` task: it runs in its own
process, so a report's plotting or a failure never touches the station): from ``<stem>.mcap``

* ``<stem>.epochs.csv.gz``, ``<stem>.days.csv`` and ``<stem>.nights.csv``
  (``engine.workflows.tables_from_mcap``: a second pass over the log's raw stream, the verified
  copy's samples, with the recording's final estimate applied from the first sample; the live
  log applied the identity, or the store prior, until its first accepted 12 h refit, so its own
  epochs are not the study's numbers. The day table names the estimate (``calibration_source``).
  The defaults of ``process``: GGIR nonwear 2023, 16 h valid day, bands 40/100/400 mg, MVPA
  bouts of 60 s, sleep (HDCZA) in the log's zone);
* ``<stem>.report.png`` and ``<stem>.report.html`` (``engine.report.write_report``), only when
  matplotlib is installed; otherwise one line says so and nothing fails.

A product that already exists is kept, never replaced. The result is one entry per product
``{"product", "path", "result", "reason"}`` with ``result`` one of ``written``, ``kept``,
``skipped`` or ``failed``; the station records them in the ledger (``products``). A failure of
a product never changes the download: it is verified, and its clear goes ahead.

``products_wanted(mcap)``: whether a log still lacks a product (a station stopped before making
them makes them when the device comes back).
"""

from __future__ import annotations

import os
import threading
from pathlib import Path

TABLES = "tables"
REPORT = "report"
# matplotlib is not thread-safe: reports made on threads of one process (downloads run inline)
# are drawn one at a time (in worker processes, the default, each has its own)
_PLOT_LOCK = threading.Lock()


def _paths(mcap: Path) -> dict:
    from stillpoint.engine.report import report_paths
    from stillpoint.engine.sleep import nights_path
    from stillpoint.engine.tables import table_paths
    return {TABLES: table_paths(mcap) + (nights_path(mcap),), REPORT: report_paths(mcap)}


def products_wanted(mcap) -> bool:
    """True when the log exists and one of its products does not."""
    mcap = Path(mcap)
    if not mcap.is_file():
        return False
    return any(not os.path.lexists(p) for pair in _paths(mcap).values() for p in pair)


def _reason(e: BaseException) -> str:
    if isinstance(e, OSError) and not hasattr(e, "message"):
        from stillpoint.engine.core.outputs import describe_os_error
        return f"{getattr(e, 'filename', None) or ''}: {describe_os_error(e)}".lstrip(": ")
    return str(e) or type(e).__name__


def make_products(job: dict, progress=None, cancel=None) -> dict:
    """The tables and the report of ``job["mcap"]`` (module docstring). ``progress(phase, done,
    total)`` is called every second while the work runs (the worker's stall bound)."""
    mcap = Path(job["mcap"])
    paths = _paths(mcap)
    beat = threading.Event()
    if progress is not None:
        def heartbeat():
            k = 0
            while not beat.wait(1.0):
                k += 1
                progress("finishing", k, 0)
        threading.Thread(target=heartbeat, daemon=True, name="products-heartbeat").start()
    out = []
    try:
        ep, dp, nights = paths[TABLES]
        if os.path.lexists(ep) or os.path.lexists(dp) or os.path.lexists(nights):
            out.append({"product": TABLES, "path": str(ep), "result": "kept",
                        "reason": "already there; not replaced"})
        else:
            try:
                from stillpoint.engine.sleep import SleepOptions
                from stillpoint.engine.workflows.tables_from_mcap import tables_from_mcap
                tables_from_mcap(mcap, ep, dp, sleep=SleepOptions(), nights_path=nights)
                out.append({"product": TABLES, "path": str(ep), "result": "written",
                            "reason": None})
            except Exception as e:  # noqa: BLE001 - recorded with its reason, never raised
                out.append({"product": TABLES, "path": str(ep), "result": "failed",
                            "reason": _reason(e)})
        if cancel is not None and cancel.is_set():  # stopped (a worker thread): no report
            return {"products": out, "stopped": True}
        png, page = paths[REPORT]
        from stillpoint.engine.report import ReportUnavailableError, require_matplotlib
        try:
            require_matplotlib()
        except ReportUnavailableError as e:
            out.append({"product": REPORT, "path": str(png), "result": "skipped",
                        "reason": str(e)})
            return {"products": out}
        if os.path.lexists(png) or os.path.lexists(page):
            out.append({"product": REPORT, "path": str(png), "result": "kept",
                        "reason": "already there; not replaced"})
        else:
            try:
                from stillpoint.engine.report import write_report
                with _PLOT_LOCK:
                    write_report(mcap)
                out.append({"product": REPORT, "path": str(png), "result": "written",
                            "reason": None})
            except Exception as e:  # noqa: BLE001 - recorded with its reason, never raised
                out.append({"product": REPORT, "path": str(png), "result": "failed",
                            "reason": _reason(e)})
        return {"products": out}
    finally:
        beat.set()


def describe(products: list) -> str:
    """One short phrase for the station's table and lines: each product's result, and the reason
    of one skipped or failed."""
    return ", ".join(f"{p['product']} {p['result']}"
                     + (f" ({p['reason']})" if p["result"] in ("skipped", "failed") and p.get("reason")
                        else "") for p in products)
