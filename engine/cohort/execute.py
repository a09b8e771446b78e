"""Running a cohort plan: a local process pool (the default), Dask distributed (a LocalCluster
or a scheduler address), or in this process.

* **What runs.** Entries whose folder holds ``_DONE.json`` for their key are skipped; entries
  with ``_FAILED.json`` are skipped unless their class is in ``retry_classes``; the rest are
  pending. Unreadable files (no key could be taken) get their ``_FAILED.json`` here.
* **Bounded batches.** At most ``max_in_flight`` (default twice the worker slots; at least 500 on
  a scheduler address or a given client, so an adaptive cluster sees work waiting and scales up)
  jobs are submitted at a time; a new one goes in as one finishes, so the scheduler never holds
  100,000 tasks and a Ctrl-C loses at most the jobs in flight.
* **Retries** by failure class (engine/cohort/job.py): ``transient_io`` up to 3 tries,
  (after 2 s, then 4 s), ``resource`` (a worker killed mid-task: memory limit, walltime, SIGKILL) once, ``corrupt_input``
  and ``bug`` never. On our LocalCluster the scheduler hands a killed worker's task back to us at
  once (``allowed-failures`` 0), so the retry policy is this one and is logged.
* **LocalCluster**: one thread per worker process (the engine is numpy-bound; threads would fight
  over the GIL and BLAS), workers = cores, a memory limit per worker (default: the machine's
  memory divided among workers; Dask's nanny restarts a worker that goes over it).
* **Progress**: files done/failed, MB/s of input, ETA; a bar on a terminal, plain lines
  otherwise. Failures are printed as they happen, bugs loudly with where the traceback is.
* **Ctrl-C** cancels what is in flight, closes the cluster and returns with ``interrupted``;
  a rerun resumes (a killed job's ``.tmp`` folder is discarded, finished folders are kept).
"""

from __future__ import annotations

import os
import sys
import time
from collections import deque
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

from stillpoint.engine.core.errors import StillpointError

from ..core.prefetch import cores_available
from .job import (DONE, FAILED, MAX_ATTEMPTS, one_line, paths, read_marker, read_progress, run_job,
                  write_failure)
from .plan import Entry, Plan

INSTALL_HINT = "pip install 'stillpoint[cohort]'"

# The scheduler of a cohort on one machine when none is named: a process pool. Dask's
# LocalCluster (``local``) adds a scheduler process, a nanny per worker and an event loop beside
# each job (the job shares its worker's interpreter lock with it). On the 2-core machine, 8
# simulated 1-day 100 Hz files (default wearer), `stillpoint cohort run DIR -o OUT -j 2`, two
# alternating runs each (/usr/bin/time): LocalCluster 16.15 and 16.06 s wall, process pool 12.71
# and 13.43 s; the outputs are the same (the same job runs in both). Dask stays for clusters
# (a scheduler address), for a memory limit per worker (``--memory-limit``), and on request.
DEFAULT_SCHEDULER = "processes"
TRANSIENT_DELAY_S = 2.0  # a transient_io retry waits 2 s, then 4 s (a network file system hiccup)


class SchedulerError(StillpointError):
    """The Dask scheduler cannot be reached or Dask is missing for a scheduler address."""


def have_dask() -> bool:
    try:
        import distributed  # noqa: F401
        return True
    except ImportError:
        return False


def default_workers() -> int:
    return max(1, cores_available())


@dataclass
class CohortResult:
    """What one ``run_cohort`` call did."""

    total: int = 0  # entries in the (sharded) plan
    already_done: int = 0  # finished before this run
    already_failed: int = 0  # failed before this run and not retried
    done: int = 0  # finished by this run
    failed: dict = field(default_factory=dict)  # class -> count, failed in this run
    retried: int = 0
    pending: int = 0  # left to do (after an interrupt)
    interrupted: bool = False
    backend: str = ""
    workers: int = 0
    startup_s: float = 0.0  # starting the cluster / pool
    wall_s: float = 0.0
    bytes_done: int = 0
    results: list = field(default_factory=list)  # one dict per job finished in this run

    @property
    def failed_total(self) -> int:
        return sum(self.failed.values())


# ---------------------------------------------------------------------------- progress
def _hms(s: float) -> str:
    from ..progress import hms
    return hms(s)


class CohortProgress:
    """Files done/failed, MB/s and ETA: a bar on a terminal, one plain line every ``interval``
    seconds otherwise. Failures are printed as they happen."""

    def __init__(self, total_files: int, total_bytes: int, stream=None, tty=None,
                 interval: Optional[float] = None, enabled: bool = True, partial=None,
                 clock=time.monotonic):
        self.stream = stream or sys.stderr
        self.tty = self.stream.isatty() if tty is None else tty
        self.interval = interval if interval is not None else (0.25 if self.tty else 10.0)
        self.enabled = enabled
        self.total_files, self.total_bytes = total_files, total_bytes
        self.files = self.failed = 0
        self.bytes = 0
        self.partial = partial  # () -> bytes done of the files still running (their share read)
        self.clock = clock
        self.t0 = clock()
        self._last = 0.0
        self._drawn = False

    def line(self) -> str:
        """The ETA is by bytes: files done plus the share read of the files still running."""
        el = self.clock() - self.t0
        done = self.bytes + (self.partial() if self.partial is not None else 0)
        rate = done / el / 1e6 if el > 0 else 0.0
        left = max(0, self.total_bytes - done)
        eta = _hms(left / (rate * 1e6)) if rate > 0 and left else ("0m00s" if not left else "?")
        return (f"{self.files + self.failed}/{self.total_files} files: {self.files} done, "
                f"{self.failed} failed | {rate:.1f} MB/s | elapsed {_hms(el)} | ETA {eta}")

    def _write(self, text: str, newline: bool) -> None:
        if self.tty:
            self.stream.write("\r\033[K" + text + ("\n" if newline else ""))
        else:
            self.stream.write(text + "\n")
        self.stream.flush()

    def message(self, text: str) -> None:
        if self.enabled:
            self._write(text, True)
            self._drawn = False

    def update(self, state: str, nbytes: int = 0) -> None:
        if state == "done":
            self.files += 1
            self.bytes += nbytes
        elif state == "failed":
            self.failed += 1
            self.total_bytes -= nbytes
        self.tick()

    def tick(self, force: bool = False) -> None:
        if not self.enabled:
            return
        now = self.clock()
        if not force and now - self._last < self.interval:
            return
        self._last = now
        if self.tty:
            k = int(30 * (self.files + self.failed) / max(1, self.total_files))
            self._write(f"[{'#' * k}{'.' * (30 - k)}] " + self.line(), False)
            self._drawn = True
        else:
            self._write("cohort: " + self.line(), True)

    def close(self) -> None:
        if self.enabled and self.tty and self._drawn:
            self._write("[" + "#" * 30 + "] " + self.line() if self.files + self.failed >=
                        self.total_files else self.line(), True)


# ---------------------------------------------------------------------------- backends
class _Serial:
    """Jobs run one after another in this process (``--scheduler serial``)."""

    name, workers = "serial", 1

    def submit(self, args, label):
        try:
            return ("ok", run_job(*args))
        except (KeyboardInterrupt, SystemExit):
            raise
        except BaseException as e:  # noqa: BLE001
            return ("error", e)

    def wait_any(self, handles, timeout):
        return list(handles)

    def result(self, h):
        if h[0] == "error":
            raise h[1]
        return h[1]

    def slots(self):
        return 1

    def cancel(self, handles):
        pass

    def close(self):
        pass


class _Pool:
    """A local process pool (``--scheduler processes``, and ``local`` without Dask)."""

    name = "processes"

    def __init__(self, workers: int):
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor
        self.workers = workers
        self._make = lambda: ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"),
                                                 initializer=_ignore_sigint)
        self.pool = self._make()

    def submit(self, args, label):
        from concurrent.futures.process import BrokenProcessPool
        try:
            return self.pool.submit(run_job, *args)
        except BrokenProcessPool:  # a worker died: start a new pool
            self.pool.shutdown(wait=False, cancel_futures=True)
            self.pool = self._make()
            return self.pool.submit(run_job, *args)

    def wait_any(self, handles, timeout):
        from concurrent.futures import FIRST_COMPLETED, wait
        done, _ = wait(handles, timeout=timeout, return_when=FIRST_COMPLETED)
        return list(done)

    def result(self, h):
        return h.result()

    def slots(self):
        return self.workers

    def cancel(self, handles):
        for h in handles:
            h.cancel()

    def close(self):
        procs = list(getattr(self.pool, "_processes", {}).values())
        self.pool.shutdown(wait=False, cancel_futures=True)
        for p in procs:  # jobs still running (after Ctrl-C): their .tmp folders are discarded later
            if p.is_alive():
                p.terminate()


class _Dask:
    """Dask distributed: our LocalCluster, a scheduler address, or a given Client."""

    def __init__(self, scheduler: str, workers: int, memory_limit, client=None):
        import dask
        from distributed import Client, LocalCluster
        self.cluster = None
        self.own_client = client is None
        if client is not None:
            self.client, self.name = client, "dask (client)"
        elif scheduler == "local":
            import logging
            # No MALLOC_TRIM_THRESHOLD_ for the workers (Dask's nanny sets 64 KiB by default):
            # it switches off glibc's dynamic mmap threshold, so every block-sized numpy array
            # is mmap'ed and faulted in afresh, at a cost in page faults and system CPU
            # (docs/performance.md#code-figures; job.py guards the same for clusters we did
            # not start).
            environ = {k: v for k, v in dask.config.get("distributed.nanny.pre-spawn-environ").items()
                       if k != "MALLOC_TRIM_THRESHOLD_"}
            with dask.config.set({"distributed.scheduler.allowed-failures": 0,
                                  "distributed.nanny.pre-spawn-environ": environ}), _sigint_ignored():
                # the scheduler's own log of a worker death is replaced by our retry line
                self.cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                            memory_limit=memory_limit, dashboard_address=None,
                                            silence_logs=logging.CRITICAL)
            self.client, self.name = Client(self.cluster), "dask LocalCluster"
        else:
            try:
                self.client = Client(scheduler, timeout="30s")
            except (OSError, TimeoutError, ValueError) as e:
                raise SchedulerError(f"scheduler {scheduler}: cannot connect ({one_line(e)})") from None
            self.name = f"dask {scheduler}"
        self._slots, self._slots_t = 0, 0.0
        # on a cluster that scales with its queue (adapt) the queue must show the work waiting
        self.min_in_flight = 2 if self.cluster is not None else 500

    @property
    def workers(self) -> int:
        return self.slots()

    def slots(self) -> int:
        now = time.monotonic()
        if now - self._slots_t > 5.0:
            info = self.client.scheduler_info()
            self._slots = sum(w.get("nthreads", 1) for w in info.get("workers", {}).values())
            self._slots_t = now
        return self._slots

    def submit(self, args, label):
        return self.client.submit(run_job, *args, pure=False, key=label)

    def wait_any(self, handles, timeout):
        from distributed import wait
        try:
            return list(wait(handles, timeout=timeout, return_when="FIRST_COMPLETED").done)
        except TimeoutError:
            return []

    def result(self, h):
        return h.result()

    def cancel(self, handles):
        try:
            self.client.cancel(list(handles))
        except Exception:  # noqa: BLE001 - the scheduler may be gone already
            pass

    def close(self):
        if self.own_client:
            try:
                self.client.close(timeout=10)
            except Exception:  # noqa: BLE001
                pass
        if self.cluster is not None:
            try:
                self.cluster.close(timeout=10)
            except Exception:  # noqa: BLE001
                pass


def _ignore_sigint() -> None:
    """Worker processes leave Ctrl-C to the client, which stops them in order."""
    import signal
    signal.signal(signal.SIGINT, signal.SIG_IGN)


@contextmanager
def _sigint_ignored():
    """Ctrl-C ignored while worker processes are started (they inherit it; the client's own
    handler is back before any job runs). A no-op off the main thread."""
    import signal
    try:
        old = signal.signal(signal.SIGINT, signal.SIG_IGN)
    except ValueError:  # not the main thread
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old)


class _InterruptLatch:
    """Ctrl-C raises ``KeyboardInterrupt`` as usual and is also remembered, so the run loop
    stops even when the exception landed where Python swallows it (a finaliser such as a Dask
    future's ``__del__``); such a swallowed interrupt is not printed as a traceback either.
    A no-op off the main thread."""

    def __init__(self):
        self.hit = False
        self._old = None
        self._old_hook = None

    def _unraisable(self, u):
        if u.exc_type is KeyboardInterrupt:
            self.hit = True
        else:
            self._old_hook(u)

    def _on_sigint(self, signum, frame):
        self.hit = True
        raise KeyboardInterrupt

    def __enter__(self):
        import signal
        try:
            self._old = signal.signal(signal.SIGINT, self._on_sigint)
        except ValueError:  # not the main thread
            self._old = None
            return self
        self._old_hook, sys.unraisablehook = sys.unraisablehook, self._unraisable
        return self

    def check(self) -> None:
        if self.hit:
            raise KeyboardInterrupt

    def __exit__(self, *exc):
        if self._old is not None:
            import signal
            signal.signal(signal.SIGINT, self._old)
            sys.unraisablehook = self._old_hook
        return False


def _backend_error_class(e: BaseException) -> str:
    """Class of an error raised by the backend rather than by the job."""
    name = type(e).__name__
    if name in ("KilledWorker", "BrokenProcessPool", "MemoryError"):
        return "resource"
    if name in ("CancelledError", "CommClosedError", "FutureCancelledError") or isinstance(e, OSError):
        return "transient_io"
    from .job import classify
    return classify(e)


# ---------------------------------------------------------------------------- the run
def entry_state(outdir, e: Entry) -> tuple[str, Optional[dict]]:
    """``done`` / ``failed`` / ``pending`` of one entry, from its folder's markers."""
    final, _, _ = paths(outdir, e.folder)
    done = read_marker(final / DONE)
    if done is not None and done.get("key") == e.key:
        return "done", done
    failed = read_marker(final / FAILED)
    if failed is not None and failed.get("key") == e.key:
        return "failed", failed
    return "pending", None


def run_cohort(plan: Plan, outdir, *, scheduler: str = "processes", jobs: Optional[int] = None,
               memory_limit="auto", client=None, retry_classes=(), max_in_flight: Optional[int] = None,
               progress: bool = True, stream=None, tty=None, interval: Optional[float] = None,
               on_start=None) -> CohortResult:
    """Run every pending entry of ``plan`` into ``outdir``; see the module docstring.

    ``scheduler``: ``"processes"`` (a process pool of ``jobs`` workers; ``DEFAULT_SCHEDULER``),
    ``"local"`` (a Dask LocalCluster of ``jobs`` worker processes; a process pool when Dask is not
    installed), ``"serial"`` or a scheduler address
    (``tcp://host:8786``); or pass a Dask ``client``. ``retry_classes``: failure classes whose
    earlier failures are run again. Returns a ``CohortResult``; never raises for a bad file.
    """
    stream = stream or sys.stderr
    outdir = Path(outdir).absolute()
    res = CohortResult(total=len(plan.entries))
    t0 = time.perf_counter()
    todo: list[Entry] = []
    for e in plan.entries:
        st, marker = entry_state(outdir, e)
        if st == "done":
            res.already_done += 1
        elif st == "failed" and marker.get("class") not in retry_classes:
            res.already_failed += 1
        elif e.error:  # no key could be taken: recorded without a worker
            write_failure(outdir, e.as_row(), "corrupt_input", f"{e.path}: {e.error}")
            res.failed["corrupt_input"] = res.failed.get("corrupt_input", 0) + 1
            if progress:
                stream.write(f"FAILED {e.path} (corrupt_input): {e.error}\n")
        else:
            todo.append(e)
    inflight: dict = {}

    def running_bytes() -> int:
        return int(sum(read_progress(outdir, e.folder) * e.size for e, _, _ in inflight.values()))

    prog = CohortProgress(len(todo), sum(e.size for e in todo), stream=stream, tty=tty,
                          interval=interval, enabled=progress, partial=running_bytes)
    if not todo:
        res.wall_s = time.perf_counter() - t0
        return res

    workers = jobs or default_workers()
    for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ.setdefault(var, "1")  # one thread per worker process, also in a process pool
    t1 = time.perf_counter()
    if client is not None:
        backend = _Dask("client", workers, memory_limit, client=client)
    elif scheduler == "serial":
        backend = _Serial()
    elif scheduler == "processes" or (scheduler == "local" and not have_dask()):
        if scheduler == "local" and progress:
            prog.message(f"Dask is not installed: running on a local process pool of {workers} "
                         f"processes (for Dask and clusters: {INSTALL_HINT})")
        backend = _Pool(workers)
    else:
        if not have_dask():
            raise SchedulerError(f"--scheduler {scheduler} needs Dask: {INSTALL_HINT}")
        backend = _Dask(scheduler, workers, memory_limit)
    res.startup_s = time.perf_counter() - t1
    res.backend, res.workers = backend.name, backend.slots()
    if progress:
        prog.message(f"cohort: {len(todo)} file(s) to process on {backend.name} "
                     f"({res.workers} worker(s)); {res.already_done} already done, "
                     f"{res.already_failed} failed earlier")
    if on_start is not None:
        on_start(backend)
    prog.t0 = prog.clock()

    queue = deque((e, 1) for e in todo)
    delayed: list = []  # (entry, attempt, not before): transient_io retries wait a little
    settings, code = plan.settings, plan.code_version
    latch = _InterruptLatch()
    try:
        with latch:
            _run_loop(backend, outdir, settings, code, queue, delayed, inflight, res, prog,
                      max_in_flight, latch)
    except KeyboardInterrupt:
        res.interrupted = True
        backend.cancel([v[2] for v in inflight.values()])
    finally:
        res.pending = len(queue) + len(inflight) + len(delayed)
        prog.tick(force=True)
        prog.close()
        backend.close()
        res.wall_s = time.perf_counter() - t0
    return res


def _run_loop(backend, outdir, settings, code, queue, delayed, inflight, res, prog,
              max_in_flight, latch) -> None:
    """Submit, collect and retry until nothing is left; ``KeyboardInterrupt`` on Ctrl-C."""
    while queue or inflight or delayed:
        latch.check()
        now = time.monotonic()
        for d in [d for d in delayed if d[2] <= now]:
            delayed.remove(d)
            queue.appendleft(d[:2])
        limit = max_in_flight or max(getattr(backend, "min_in_flight", 2), 2 * backend.slots())
        while queue and len(inflight) < limit:
            e, attempt = queue.popleft()
            label = f"stillpoint-cohort-{Path(e.folder).name}-a{attempt}"
            h = backend.submit((e.as_row(), str(outdir), settings, code, attempt), label)
            inflight[h if not isinstance(h, tuple) else id(h)] = (e, attempt, h)
        handles = [v[2] for v in inflight.values()]
        if not handles:
            time.sleep(0.2)
            continue
        for h in backend.wait_any(handles, timeout=0.5):
            e, attempt, _ = inflight.pop(h if not isinstance(h, tuple) else id(h))
            try:
                r = backend.result(h)
            except (KeyboardInterrupt, SystemExit):
                raise
            except BaseException as exc:  # noqa: BLE001 - the worker died or the job raised
                cls = _backend_error_class(exc)
                r = {"state": "failed", "class": cls, "key": e.key, "path": e.path,
                     "error": f"{e.path}: {one_line(exc)}", "unrecorded": True}
            if r["state"] == "failed":
                cls = r["class"]
                if attempt < MAX_ATTEMPTS.get(cls, 1):
                    res.retried += 1
                    prog.message(f"retrying {e.path} ({cls}, attempt {attempt + 1} of "
                                 f"{MAX_ATTEMPTS[cls]}): {r['error']}")
                    if cls == "transient_io":
                        delayed.append((e, attempt + 1, time.monotonic() + TRANSIENT_DELAY_S * attempt))
                    else:
                        queue.appendleft((e, attempt + 1))
                    continue
                if r.get("unrecorded"):
                    write_failure(outdir, e.as_row(), cls, r["error"], attempt=attempt)
                res.failed[cls] = res.failed.get(cls, 0) + 1
                marker = Path(outdir) / e.folder / FAILED
                if cls == "bug":
                    prog.message(f"BUG processing {e.path}: {r['error']}\n    this is a "
                                 f"stillpoint bug: the traceback is in {marker}; please report it")
                else:
                    prog.message(f"FAILED {e.path} ({cls}): {r['error']}")
                prog.update("failed", e.size)
            elif r["state"] == "done":
                res.done += 1
                res.bytes_done += e.size
                prog.update("done", e.size)
            else:  # skipped: another run finished it meanwhile
                res.already_done += 1
                prog.update("done", 0)
            r["entry"] = e
            res.results.append(r)
        prog.tick()
    latch.check()
