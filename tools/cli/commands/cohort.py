"""`stillpoint cohort run|status|retry|collate`: process a cohort of recordings on Dask
distributed (laptop to cluster) into one output folder that is the single source of truth.

    stillpoint cohort run DATA/ -o OUT [-j N] [--scheduler local|processes|serial|ADDRESS]
                          [--shard K/N] [--strict] [processing settings...]
    stillpoint cohort status OUT [--json]
    stillpoint cohort retry OUT --class transient_io|resource|corrupt_input|bug|all
    stillpoint cohort collate OUT [--verify]

``run`` takes every processing setting of ``process`` and its table options (--nonwear,
--valid-day-hours, --enmo-bands, --mvpa-bout-s), all part of each file's key.

A rerun of the same command does only what is not finished; Ctrl-C stops cleanly (exit 130).
Exit codes: 0 when every file is done, 1 when some file failed (the failure table lists
them; the others are done), 2 when every file failed, no recording was found, or for unusable
arguments or an unusable output folder, 130 when interrupted.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from ._numbers import WORKERS, memory_size, number, shard
from ._runopts import OptionError, add_setting_arguments, settings_overrides

NAME = "cohort"
HELP = "process many recordings (Dask or a process pool), resumable; status, retry, collate"
DESCRIPTION = (HELP + ". Each file gets a key (hash of its first bytes, size, settings and code "
               "version) and an output folder; finished folders are never recomputed.")

CLASSES = ("corrupt_input", "transient_io", "resource", "bug")


def _exec_arguments(p) -> None:
    g = p.add_argument_group("execution")
    g.add_argument("--scheduler", default=None, metavar="processes|local|serial|ADDRESS",
                   help="processes: a process pool on this machine (default); local: a Dask "
                        "LocalCluster on this machine (the default when --memory-limit is given; "
                        "a process pool when Dask is not installed); serial: one file after "
                        "another in this process; or a Dask scheduler address (tcp://host:8786)")
    g.add_argument("-j", "--jobs", type=WORKERS, default=None,
                   help="worker processes for processes/local (default: the cores available)")
    g.add_argument("--memory-limit", type=memory_size, default=None,
                   help="LocalCluster memory limit per worker, e.g. 4GB or auto (memory / "
                        "workers); implies --scheduler local when no scheduler is given")
    g.add_argument("--max-in-flight", type=number(1, 1_000_000, integer=True), default=None,
                   help="jobs submitted at a time (default: twice the worker slots)")
    g.add_argument("--strict", action="store_true", help="exit 1 when any file failed (the default; kept for older scripts)")
    g.add_argument("-q", "--quiet", action="store_true", help="no progress and no failure lines")


def add_arguments(p) -> None:
    sub = p.add_subparsers(dest="action", metavar="ACTION")
    sub.required = True
    r = sub.add_parser("run", help="plan, process and collate a cohort",
                       description="Process recordings into OUTDIR; a rerun resumes.")
    r.add_argument("inputs", nargs="+", help="recordings, folders (searched recursively for "
                   ".cwa/.cwa.gz/.bin/.bin.gz) or manifest CSVs (a 'path' column; optional "
                   "'timezone' (that file's zone, in place of --timezone) and 'participant')")
    r.add_argument("-o", "--output", type=Path, required=True, help="the cohort folder")
    r.add_argument("--shard", type=shard, metavar="K/N", help="process only shard K of N (0-based; for job "
                   "arrays: --shard $SLURM_ARRAY_TASK_ID/$SLURM_ARRAY_TASK_COUNT); no collation")
    _exec_arguments(r)
    from ._tableopts import add_table_arguments, add_zone_arguments
    add_zone_arguments(r)
    add_setting_arguments(r)
    add_table_arguments(r, with_switch=False)
    from ._outcomeopts import add_outcome_arguments
    add_outcome_arguments(r)
    r.add_argument("--sleep", dest="sleep", action="store_true", default=True,
                   help="sleep (engine/sleep), the default as for process: spt/sib epoch columns, "
                        "each file's nights and windows tables, collated into cohort_nights.csv "
                        "and cohort_windows.csv (without a zone: on the device clock)")
    r.add_argument("--no-sleep", dest="sleep", action="store_false", help="no sleep")
    r.add_argument("--sleep-log", type=Path, metavar="LOG.csv",
                   help="one sleep diary for the cohort in GGIR's basic or advanced sleep-log "
                        "format: each file's nights are taken from the participant's row (the "
                        "manifest's participant, else the file name without its ending)")
    s = sub.add_parser("status", help="done / failed by class / pending")
    s.add_argument("outdir", type=Path)
    s.add_argument("--json", action="store_true", help="one JSON object")
    t = sub.add_parser("retry", help="run the files that failed with a class again")
    t.add_argument("outdir", type=Path)
    t.add_argument("--class", dest="classes", action="append", required=True,
                   choices=CLASSES + ("all",), help="failure class to retry (repeatable)")
    _exec_arguments(t)
    c = sub.add_parser("collate", help="write cohort_summary.csv and cohort_failures.csv")
    c.add_argument("outdir", type=Path)
    c.add_argument("--verify", action="store_true",
                   help="also check every output's SHA-256 against its marker (reads everything)")


def _parse_shard(text):
    if text is None:
        return None
    try:
        k, n = (int(x) for x in text.split("/"))
    except ValueError:
        raise OptionError(f"--shard {text}: expected K/N, e.g. 0/4") from None
    if not (n >= 1 and 0 <= k < n):
        raise OptionError(f"--shard {text}: need 0 <= K < N")
    return k, n


def _prepare_outdir(out: Path) -> Path:
    from stillpoint.engine.core.outputs import OutputError, check_output_path
    out = out.absolute()
    if out.exists() and not out.is_dir():
        raise OutputError(out, "the cohort folder is a file")
    if not out.exists():
        parent = out.parent if str(out.parent) else Path(".")
        if not parent.is_dir():
            raise OutputError(out, f"folder {parent} does not exist")
        try:
            out.mkdir()
        except OSError as e:
            from stillpoint.engine.core.outputs import describe_os_error
            raise OutputError(out, f"cannot create the cohort folder: {describe_os_error(e)}") from None
    check_output_path(out / "manifest.csv", what="cohort")
    return out


def scheduler_of(scheduler, memory_limit) -> str:
    """The scheduler a run uses: the one asked for; else a Dask LocalCluster when a memory
    limit (a LocalCluster setting) is given; else ``DEFAULT_SCHEDULER``, the process pool."""
    from stillpoint.engine.cohort.execute import DEFAULT_SCHEDULER
    if scheduler:
        return scheduler
    return "local" if memory_limit is not None else DEFAULT_SCHEDULER


def _execute(args, plan, outdir: Path, retry_classes=(), collate_after=True) -> int:
    from stillpoint.engine.cohort import collate, run_cohort
    if args.jobs is not None and args.jobs < 1:
        raise OptionError("--jobs must be at least 1")
    res = run_cohort(plan, outdir, scheduler=scheduler_of(args.scheduler, args.memory_limit),
                     jobs=args.jobs, memory_limit=args.memory_limit or "auto",
                     retry_classes=tuple(retry_classes),
                     max_in_flight=args.max_in_flight, progress=not args.quiet)
    failed = ", ".join(f"{k} {v}" for k, v in sorted(res.failed.items()))
    line = (f"cohort: {res.done} done now, {res.already_done} already done, "
            f"{res.failed_total} failed now{f' ({failed})' if failed else ''}, "
            f"{res.already_failed} failed earlier, {res.pending} pending; "
            f"{res.wall_s:.1f} s")
    print(line, file=sys.stderr)
    if res.interrupted:
        print(f"stillpoint cohort: interrupted; {res.pending} file(s) not finished. Rerun the same "
              "command to resume (finished files are kept).", file=sys.stderr)
        return 130
    if res.failed.get("bug"):
        print(f"stillpoint cohort: {res.failed['bug']} file(s) hit a stillpoint bug; their "
              "_FAILED.json holds the traceback. Please report it.", file=sys.stderr)
    if collate_after:
        col = collate(outdir)
        print(f"summary: {col.summary_csv} ({len(col.rows)} file(s)); days: {col.days_csv}; "
              f"participants: {col.participants_csv} ({len(col.participants)}); failures: "
              f"{col.failures_csv} ({len(col.failures)})", file=sys.stderr)
        for w in col.warnings:
            print(f"warning: {w}", file=sys.stderr)
        n_failed, n_done = len(col.failures), len(col.rows)
    else:
        print("shard finished; when every shard is done: stillpoint cohort collate "
              f"{outdir}", file=sys.stderr)
        n_failed, n_done = res.failed_total + res.already_failed, res.done + res.already_done
    return exit_code(n_done, n_failed)


def exit_code(done: int, failed: int) -> int:
    """0: every file done; 1: some failed (the others are done); 2: every file failed."""
    if failed and not done:
        print(f"stillpoint cohort: every file failed ({failed}); the failure table says why",
              file=sys.stderr)
        return 2
    return 1 if failed else 0


def _run(args) -> int:
    from stillpoint.engine.cohort import discover_inputs, make_plan
    from stillpoint.engine.run import RunSettings
    shard = _parse_shard(args.shard)
    attributes: dict = {}  # a manifest's per-file timezone / participant (inputs read before
    # the output folder is made: unusable inputs leave nothing behind)
    files = discover_inputs(args.inputs, attributes)
    if not files:
        raise OptionError("no recordings (.cwa, .cwa.gz, .bin, .bin.gz) found in "
                          + ", ".join(str(x) for x in args.inputs))
    outdir = _prepare_outdir(args.output)
    over = settings_overrides(args)
    from ._tableopts import zone_settings
    over.update(zone_settings(args))  # the participants' zone: a setting of the run
    settings = RunSettings.from_dict({}, **over).to_dict()
    settings["tables"] = {"nonwear_version": args.nonwear, "valid_day_hours": args.valid_day_hours,
                          "enmo_bands_mg": [float(x) for x in args.enmo_bands],
                          "mvpa_bout_s": args.mvpa_bout_s}  # part of every file's key
    from ._outcomeopts import outcome_settings
    outcomes = outcome_settings(args)
    if outcomes.active:  # only then: a cohort without outcomes keeps its files' keys
        settings["tables"]["outcomes"] = outcomes.to_dict()
    if getattr(args, "sleep", False):  # on by default, as for process
        settings["tables"]["sleep"] = True
    if getattr(args, "sleep_log", None) is not None:
        if not getattr(args, "sleep", False):
            raise OptionError("--sleep-log needs sleep (not with --no-sleep)")
        from stillpoint.drivers.byteio import sha256_file
        from stillpoint.engine.sleep import SleepLogError
        from stillpoint.engine.sleep.diary import sleep_log_ids
        try:
            sleep_log_ids(args.sleep_log)  # a bad log is refused before any work
            digest = sha256_file(args.sleep_log)
        except OSError as e:
            raise OptionError(f"--sleep-log {args.sleep_log}: {e.strerror or e}") from None
        except SleepLogError as e:
            raise OptionError(str(e)) from None
        # the log's bytes are part of every file's key: an edited log reruns the files
        settings["tables"]["sleep_log"] = {"path": str(args.sleep_log.absolute()), "sha256": digest}
    plan = make_plan(files, settings, attributes=attributes)
    plan.write(outdir)
    for dup, first in plan.duplicates:
        print(f"note: {dup} has the same bytes and name as {first}: processed once", file=sys.stderr)
    if shard is not None:
        plan = plan.shard(*shard)
        print(f"shard {shard[0]}/{shard[1]}: {len(plan.entries)} file(s)", file=sys.stderr)
    return _execute(args, plan, outdir, collate_after=shard is None)


def _retry(args) -> int:
    from stillpoint.engine.cohort import make_plan
    from stillpoint.engine.cohort.plan import read_plan
    outdir = args.outdir.absolute()
    old = read_plan(outdir)
    classes = CLASSES if "all" in args.classes else tuple(args.classes)
    attributes = {e.path: {"timezone": e.timezone, "participant": e.participant}
                  for e in old.entries}
    plan = make_plan([Path(e.path) for e in old.entries], old.settings, attributes=attributes)
    if plan.code_version != old.code_version:
        print(f"note: the code changed ({old.code_version} -> {plan.code_version}): files get new "
              "keys and are processed again", file=sys.stderr)
    plan.write(outdir)
    return _execute(args, plan, outdir, retry_classes=classes)


def _status(args) -> int:
    from stillpoint.engine.cohort import status
    st = status(args.outdir)
    if args.json:
        print(json.dumps(st.as_dict(), sort_keys=True))
        return 0
    by = ", ".join(f"{k} {v}" for k, v in sorted(st.failed.items()))
    print(f"cohort {args.outdir}: {st.total} file(s), code {st.code_version}")
    print(f"  done     {st.done}")
    print(f"  failed   {st.failed_total}" + (f"  ({by})" if by else ""))
    print(f"  pending  {st.pending}" + (f"  ({len(st.running)} being processed now)" if st.running else ""))
    for path, host, pid in st.running:
        print(f"    running: {path} on {host} pid {pid}")
    return 0


def _collate(args) -> int:
    from stillpoint.engine.cohort import collate
    col = collate(args.outdir, verify=args.verify)
    print(f"summary: {col.summary_csv} ({len(col.rows)} file(s))")
    print(f"days: {col.days_csv}")
    print(f"participants: {col.participants_csv} ({len(col.participants)})")
    print(f"failures: {col.failures_csv} ({len(col.failures)} file(s))")
    if col.pending:
        print(f"pending: {col.pending} file(s) not processed yet")
    for w in col.warnings:
        print(f"warning: {w}", file=sys.stderr)
    return 0


def run(args) -> int:
    return {"run": _run, "status": _status, "retry": _retry, "collate": _collate}[args.action](args)
