"""The per-file job of a cohort: (input path, canonical settings) -> one output folder.

``run_job`` is a pure function of its arguments as far as outputs go: it calls the engine's
``process_file`` (engine/run/) into ``<folder>.tmp``, writes ``summary.json`` (the run summary
without timings, so two runs give byte-identical files), fsyncs everything, writes ``_DONE.json``
last, and renames the folder into place: a folder without ``.tmp`` holding ``_DONE.json`` is
complete. While it runs, ``<folder>.tmp/_RUNNING.json`` names the process (host, pid).

One job per file at a time: the job holds an exclusive lock on ``.<folder>.lock`` beside the
folder (a lock dies with its process, so a killed run never blocks a rerun); a second job for the
same file waits, then finds ``_DONE.json`` and returns. A ``.tmp`` folder found under the lock
was left by a killed run and is discarded.

A failure writes ``<folder>/_FAILED.json`` with a class:

==============  ==========================================================  ===============
class           what                                                        retried
==============  ==========================================================  ===============
corrupt_input   the recording cannot be read (StillpointError from the       never
                readers, missing or unreadable file, bad gzip)
transient_io    an OS error while reading or writing (network file          up to 3 tries
                system, input changed since it was planned)
resource        the worker was killed (memory limit, walltime), out of      once
                memory, disk full
bug             anything else: reported loudly with its traceback            never
==============  ==========================================================  ===============

(``retried`` is applied by the runner, engine/cohort/execute.py.)
"""

from __future__ import annotations

import errno
import gzip
import json
import os
import platform
import shutil
import socket
import sys
import time
import traceback
import zlib
from contextlib import contextmanager
from pathlib import Path
from typing import Optional

from stillpoint.drivers.byteio import sha256_file
from stillpoint.engine.core.errors import StillpointError
from stillpoint.drivers.names import recording_stem
from stillpoint.engine.core.outputs import atomic_output, fsync_folder

from ..core.malloc import set_block_thresholds
from ..core.times import iso_utc
from .plan import canonical_settings, code_version, entry_settings, fingerprint, make_key

try:
    import fcntl
except ImportError:  # pragma: no cover - non-POSIX: no cross-process guard
    fcntl = None  # type: ignore[assignment]

DONE = "_DONE.json"
FAILED = "_FAILED.json"
RUNNING = "_RUNNING.json"
PROGRESS = "_PROGRESS.txt"  # while running: the share of the file's run done (0-1), every ~2 s
MCAP_NAME = "recording.mcap"
SUMMARY_NAME = "summary.json"
TMP_SUFFIX = ".tmp"

FAILURE_CLASSES = ("corrupt_input", "transient_io", "resource", "bug")
MAX_ATTEMPTS = {"corrupt_input": 1, "transient_io": 3, "resource": 2, "bug": 1}
# fields of the run summary that change from run to run: kept in _DONE.json, not summary.json
_VOLATILE = ("wall_s", "peak_rss_mb")


# ---------------------------------------------------------------------------- markers
def read_marker(path: Path) -> Optional[dict]:
    """A marker's content, or None when it is absent or unreadable."""
    try:
        with open(path, encoding="utf-8") as f:
            d = json.load(f)
        return d if isinstance(d, dict) else None
    except (OSError, ValueError):
        return None


def write_json(path: Path, obj: dict) -> None:
    """One JSON file through the atomic output path (``.part``, fsync, rename)."""
    from stillpoint.engine.core.jsonsafe import jsonable
    with atomic_output(path, binary=False, what="cohort marker") as f:
        f.write(json.dumps(jsonable(obj), indent=2, sort_keys=True) + "\n")


def _progress_writer(path: Path, every_s: float = 2.0):
    """A ``process_file`` progress callback that writes the share done to ``path`` (replaced
    atomically, at most every ``every_s``) for the runner's byte-weighted ETA."""
    from stillpoint.engine.progress import run_fraction
    last = [-1e18]

    def write(label, st):
        now = time.monotonic()
        if st.fraction is None or now - last[0] < every_s:
            return
        last[0] = now
        part = path.with_name(path.name + ".part")
        try:
            part.write_text(f"{run_fraction(label, st.fraction):.4f}\n")
            os.replace(part, path)
        except OSError:
            pass  # progress is advisory: never fails the file
    return write


def read_progress(outdir, folder: str) -> float:
    """The share done of an entry being processed (0 when unknown)."""
    try:
        return min(max(float((paths(outdir, folder)[1] / PROGRESS).read_text()), 0.0), 1.0)
    except (OSError, ValueError):
        return 0.0


def paths(outdir, folder: str) -> tuple[Path, Path, Path]:
    """(final folder, temporary folder, lock file) of an entry."""
    final = Path(outdir) / folder
    return final, final.with_name(final.name + TMP_SUFFIX), final.with_name("." + final.name + ".lock")


@contextmanager
def _locked(lock: Path):
    fd = os.open(lock, os.O_RDWR | os.O_CREAT | getattr(os, "O_CLOEXEC", 0)
                 | getattr(os, "O_NOFOLLOW", 0), 0o644)  # a planted link is not followed
    try:
        if fcntl is not None:
            fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)


# ---------------------------------------------------------------------------- failures
def classify(exc: BaseException, input_path: str = "") -> str:
    """The failure class of an exception raised by the job (see the module docstring)."""
    if isinstance(exc, MemoryError):
        return "resource"
    if isinstance(exc, (gzip.BadGzipFile, zlib.error, EOFError)):
        return "corrupt_input"
    if isinstance(exc, OSError):
        if exc.errno in (errno.ENOSPC, getattr(errno, "EDQUOT", -1)):
            return "resource"
        if (exc.errno in (errno.ENOENT, errno.EACCES, errno.EPERM, errno.EISDIR, errno.ENOTDIR)
                and input_path and str(getattr(exc, "filename", "")) == str(input_path)):
            return "corrupt_input"
        return "transient_io"
    if isinstance(exc, StillpointError):
        return "corrupt_input"
    return "bug"


def one_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    msg = text[0] if text else ""
    return f"{type(exc).__name__}: {msg}" if msg else type(exc).__name__


def write_failure(outdir, entry: dict, cls: str, error: str, *, attempt: int = 1,
                  tb: str = "", extra: Optional[dict] = None) -> dict:
    """``<folder>/_FAILED.json`` (the folder holds nothing else). Returns the job result."""
    final, _, _ = paths(outdir, entry["folder"])
    final.mkdir(parents=True, exist_ok=True)
    marker = {"key": entry["key"], "input": entry["path"], "class": cls, "error": error,
              "attempts": attempt, "time_utc": _utc(), "host": socket.gethostname(),
              "pid": os.getpid(), "code_version": code_version()}
    if tb:
        marker["traceback"] = tb
    marker.update(extra or {})
    write_json(final / FAILED, marker)
    return {"key": entry["key"], "path": entry["path"], "state": "failed", "class": cls,
            "error": error, "attempt": attempt, "traceback": tb}


# ---------------------------------------------------------------------------- helpers
def _utc(t: Optional[float] = None) -> str:
    return iso_utc(int(time.time() if t is None else t) * 10**9)


_MALLOC_TUNED = False


def _undo_malloc_trim_threshold() -> None:
    """Dask's nanny starts workers with ``MALLOC_TRIM_THRESHOLD_=65536``, which switches off
    glibc's dynamic mmap threshold: every block-sized numpy array is then mmap'ed and faulted in
    afresh (1.2 M page faults and 1.9 s of system CPU on a 1-day 100 Hz file, against 7 k and
    0.1 s). Once per process, give glibc back thresholds like its dynamic ones (mmap above
    32 MiB, trim above 64 MiB). Only when that variable is set; glibc only."""
    global _MALLOC_TUNED
    if _MALLOC_TUNED or "MALLOC_TRIM_THRESHOLD_" not in os.environ:
        return
    _MALLOC_TUNED = True
    set_block_thresholds()


def _reset_peak_rss() -> bool:
    """Reset this process's peak RSS (Linux: write 5 to clear_refs), so a worker reports each
    file's own peak rather than the worst file it ever ran."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def _fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def versions() -> dict:
    v = {"stillpoint": code_version(), "python": platform.python_version()}
    for mod in ("numpy", "scipy", "mcap", "dask", "distributed"):
        m = sys.modules.get(mod)
        if m is not None:
            v[mod] = getattr(m, "__version__", "?")
    return v


# ---------------------------------------------------------------------------- the job
TABLE_OPTIONS = ("nonwear_version", "valid_day_hours", "enmo_bands_mg", "mvpa_bout_s")


def table_options(settings: dict) -> dict:
    """The epoch/day table options of a cohort's settings (``settings["tables"]``, as
    ``process``'s --nonwear, --valid-day-hours, --enmo-bands, --mvpa-bout-s) as
    ``TablesSettings`` keywords; absent: the defaults."""
    t = settings.get("tables") or {}
    out = {k: t[k] for k in TABLE_OPTIONS if t.get(k) is not None}
    if "enmo_bands_mg" in out:
        out["enmo_bands_mg"] = tuple(float(x) for x in out["enmo_bands_mg"])
    if t.get("outcomes"):  # --cutpoints / --steps (engine.outcomes.daily.OutcomeSettings)
        from stillpoint.engine.outcomes.daily import OutcomeSettings
        o = t["outcomes"]
        out["outcomes"] = OutcomeSettings(
            cutpoints=o.get("cutpoints") or "", bout_minutes=tuple(o.get("bout_minutes") or ()),
            bout_criterion=float(o.get("bout_criterion", 0.8)), steps=tuple(o.get("steps") or ()),
            impute=bool(o.get("impute", False)))
    return out


def _subject_code(mcap: Path) -> str:
    """The recording's subject code (the header's ``Subject Code``), from the log's device
    record; "" when it has none."""
    from stillpoint.engine.mcap.stream import read_metadata
    try:
        with open(mcap, "rb") as f:
            dev = json.loads(read_metadata(f)["device"]["json"])
        return str((dev.get("metadata") or {}).get("Subject Code") or "").strip()
    except Exception:  # noqa: BLE001 - the id is a convenience: the file name stands in
        return ""


def _participant_id(entry: dict, path) -> str:
    """The id the cohort tables give the file's participant, before the file is processed: the
    manifest's, else the recording header's subject code, else the file name without its ending
    (the sleep log's row is looked up by it)."""
    if entry.get("participant"):
        return str(entry["participant"])
    try:
        from stillpoint.engine.recordings import open_recording
        src = open_recording(path)
        try:
            code = str(((getattr(src.info, "metadata", None) or {}).get("Subject Code")) or "").strip()
        finally:
            src.close()
    except Exception:  # noqa: BLE001 - the id is a convenience: the file name stands in
        code = ""
    name = Path(path).name
    return code or (name.split(".", 1)[0] if "." in name else name)


def run_job(entry: dict, outdir: str, settings: dict, code: str, attempt: int = 1) -> dict:
    """Process one entry of the plan (``path``, ``key``, ``folder``, ``error``) into its folder.

    Returns ``{"state": "done" | "skipped" | "failed", "key", "path", ...}``; never raises for a
    bad file (the failure is in the result and in ``_FAILED.json``). ``code`` is the code
    version the key was made with: a worker running other code refuses (class ``bug``).
    """
    from stillpoint.engine.mcap.writer import peak_rss_mb
    from stillpoint.engine.run import RunSettings, process_file

    _undo_malloc_trim_threshold()
    t0, cpu0 = time.perf_counter(), time.process_time()
    started = time.time()
    path = entry["path"]
    settings = entry_settings(settings, entry)  # the manifest's zone for this file, if any
    final, tmp, lock = paths(outdir, entry["folder"])
    final.parent.mkdir(parents=True, exist_ok=True)
    if entry.get("error"):
        return write_failure(outdir, entry, "corrupt_input", f"{path}: {entry['error']}", attempt=attempt)
    with _locked(lock):
        done = read_marker(final / DONE)
        if done is not None and done.get("key") == entry["key"]:
            return {"key": entry["key"], "path": path, "state": "skipped"}
        if code != code_version():
            return write_failure(outdir, entry, "bug", f"this worker runs stillpoint {code_version()} "
                                 f"but the plan was made with {code}: install the same version "
                                 "on the client and every worker", attempt=attempt)
        if tmp.exists():  # left by a killed run (we hold the lock): discard
            shutil.rmtree(tmp)
        try:
            fp = fingerprint(Path(path))
            if make_key(fp, canonical_settings(settings), code) != entry["key"]:
                return write_failure(outdir, entry, "transient_io",
                                     f"{path}: the file changed since the run was planned "
                                     "(rerun to plan it again)", attempt=attempt)
            tmp.mkdir()
            write_json(tmp / RUNNING, {"host": socket.gethostname(), "pid": os.getpid(),
                                       "started_utc": _utc(started), "attempt": attempt})
            scoped = _reset_peak_rss()
            from stillpoint.engine.tables import TablesSettings, table_paths
            # no reader thread (engine/core/prefetch.py): a cohort uses the cores by running files
            # side by side, and a reader thread per file would take them from the other workers
            # and hold its own allocator arena (peak RSS per worker 123-127 -> 180-200 MB on
            # 1-day files, tools/benchmarks/bench_cohort.py)
            from stillpoint.engine.rhythm.table import rhythm_path
            from stillpoint.engine.timeuse.table import windows_path
            tables = TablesSettings(*table_paths(tmp / MCAP_NAME), **table_options(settings),
                                    rhythm_path=rhythm_path(tmp / MCAP_NAME),
                                    windows_path=windows_path(tmp / MCAP_NAME))
            if (settings.get("tables") or {}).get("sleep"):
                from stillpoint.engine.sleep import SleepOptions, nights_path
                log = (settings.get("tables") or {}).get("sleep_log")
                if log:  # the cohort's one sleep log: this participant's row, if any
                    from stillpoint.engine.sleep.diary import participant_sleep_log
                    log = participant_sleep_log(log["path"], _participant_id(entry, path))
                tables.sleep = SleepOptions(sleep_log=log or None)
                tables.nights_path = nights_path(tmp / MCAP_NAME)
            summary = process_file(path, tmp / MCAP_NAME, RunSettings.from_dict(settings),
                                   tables=tables, prefetch=False,
                                   progress=_progress_writer(tmp / PROGRESS))
            t_engine = time.perf_counter() - t0
            rss = peak_rss_mb()
            summary = {k: v for k, v in summary.items() if k not in _VOLATILE}
            summary["participant"] = entry.get("participant") or _subject_code(tmp / MCAP_NAME) \
                or recording_stem(path)
            summary["outputs"] = {"mcap": MCAP_NAME}
            if "tables" in summary:  # names inside the folder, not the temporary path
                for k in ("epochs", "days"):
                    summary["tables"][k] = summary["outputs"][k] = Path(summary["tables"][k]).name
                for k in ("rhythm", "windows"):
                    if k in summary["tables"]:
                        summary["tables"][k] = summary["outputs"][k] = Path(summary["tables"][k]).name
                if "sleep" in summary["tables"]:
                    sl = summary["tables"]["sleep"]
                    sl["nights"] = summary["outputs"]["nights"] = Path(sl["nights"]).name
            write_json(tmp / SUMMARY_NAME, summary)
            os.unlink(tmp / RUNNING)
            if os.path.lexists(tmp / PROGRESS):
                os.unlink(tmp / PROGRESS)
            outputs = {}
            for f in sorted(tmp.iterdir()):
                _fsync(f)
                outputs[f.name] = {"sha256": sha256_file(f), "bytes": f.stat().st_size}
            marker = {
                "key": entry["key"], "input": dict(fp, path=path), "settings": settings,
                "code_version": code, "outputs": outputs, "attempts": attempt,
                "timings": {"wall_s": round(time.perf_counter() - t0, 4),
                            "engine_wall_s": round(t_engine, 4),
                            "cpu_s": round(time.process_time() - cpu0, 4),
                            "started_utc": _utc(started), "finished_utc": _utc()},
                "peak_rss_mb": rss, "peak_rss_scope": "file" if scoped else "process",
                "host": socket.gethostname(), "pid": os.getpid(), "versions": versions(),
            }
            write_json(tmp / DONE, marker)  # last: the folder is complete once it has this
            fsync_folder(tmp)
            if final.exists():  # a failure folder from an earlier attempt
                shutil.rmtree(final)
            os.rename(tmp, final)
            fsync_folder(final.parent)
        except (KeyboardInterrupt, SystemExit):
            raise
        except BaseException as e:  # noqa: BLE001 - every failure is classified and recorded
            cls = classify(e, path)
            shutil.rmtree(tmp, ignore_errors=True)
            tb = traceback.format_exc() if cls == "bug" else ""
            msg = one_line(e)
            if path not in msg:
                msg = f"{path}: {msg}"
            return write_failure(outdir, entry, cls, msg, attempt=attempt, tb=tb)
    return {"key": entry["key"], "path": path, "state": "done", "attempt": attempt,
            "wall_s": marker["timings"]["wall_s"], "bytes": fp["size"], "peak_rss_mb": rss,
            "pid": os.getpid()}
