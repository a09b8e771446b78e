"""``stillpoint calibrate FILE [FILE ...]``: batch autocalibration of recordings, fit only (no
corrected output): the fast path for cohort QC.

One streaming pass computes 10 s window features, keeps the nonmovement windows and fits by the
72 h + 12 h schedule (van Hees 2014), stopping the read as soon as the fit is good (error
< 10 mg, sphere covered). ``--json`` prints one object with keys ``offset``, ``scale``,
``tempoffset`` (GGIR form), ``temperature_ref``, ``error_before_mg``, ``error_after_mg``,
``windows``, ``iterations``, ``status``, ``reason`` and more. ``--store`` records the estimate in
the per-device calibration store; ``--plot PNG`` draws the calibration report.

Several files (a cohort): one result per file (``--json``: one JSON object per line, with
``file``), ``--jobs N`` runs N files in parallel processes, ``--plot DIR`` writes
``DIR/<file name>.png``. A file that cannot be read does not stop the others: it gets a line
with ``status: "error"`` and the exit code is 2.
"""

from __future__ import annotations

import json
import sys

from stillpoint.engine.core.jsonsafe import jsonable
from ._numbers import HOURS, MG, number

NAME = "calibrate"
HELP = "autocalibrate a recording (fit only, no corrected output; --json, --plot, --store)"
KEEPS_EXISTING_OUTPUTS = True  # --overwrite replaces an existing output

JSON_KEYS = ("offset", "scale", "tempoffset", "temperature_ref", "error_before_mg",
             "error_after_mg", "windows", "iterations", "status", "reason")


def add_fit_arguments(parser) -> None:
    """Options shared by ``calibrate`` and ``calibrate-features``."""
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--no-temperature", action="store_true",
                        help="fit offset and scale only (C1), no temperature term")
    parser.add_argument("--ggir-compatible", action="store_true",
                        help="GGIR's stopping rule and error rounding (same numbers as GGIR)")
    parser.add_argument("--variant", choices=("auto", "c1", "c2", "offset", "scale"),
                        default="auto", help="model: auto (C2 when temperature is usable, else "
                        "C1), c1 offset+scale, c2 +temperature, offset only, scale only")
    parser.add_argument("--plot", metavar="PNG", help="write the calibration report figure "
                        "(needs matplotlib: pip install 'stillpoint[plot]')")


def add_arguments(parser) -> None:
    parser.add_argument("file", nargs="+",
                        help="recording(s): .cwa (AX3/AX6), .bin (GENEActiv), .mcap; .gz ok")
    add_fit_arguments(parser)
    parser.add_argument("--jobs", "-j", type=number(1, 256, integer=True), default=1,
                        help="files processed in parallel (processes; default 1)")
    parser.add_argument("--first-hours", type=HOURS, default=72.0,
                        help="first load of the schedule in hours (default 72; GGIR >= 3.0: 168)")
    parser.add_argument("--chunk-hours", type=HOURS, default=12.0,
                        help="data added per refit when the first load is not enough (default 12)")
    parser.add_argument("--sd-threshold-mg", type=MG, default=13.0,
                        help="nonmovement threshold on each axis' SD (default 13 mg)")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress on stderr")
    parser.add_argument("--read-all", action="store_true",
                        help="read the whole file even when the schedule is satisfied early")
    parser.add_argument("--store", action="store_true",
                        help="record the estimate in the per-device calibration store")
    parser.add_argument("--store-dir", metavar="DIR",
                        help="calibration store root (default $STILLPOINT_HOME or "
                             "~/.local/share/stillpoint)")


def estimate_json(est) -> dict:
    """The CLI's JSON object: the documented keys first, then the rest of the estimate."""
    d = est.to_dict()
    out = {k: d[k] for k in JSON_KEYS}
    extra = d.pop("extra", {}) or {}
    for k, v in d.items():
        if k not in out:
            out[k] = v
    for k in ("flags", "temperature_used", "temperature_reason", "converged", "stop_rule",
              "schedule", "error_before_g", "error_after_g", "variant", "ggir_compatible",
              "windows_offered", "repeats_collapsed", "windows_total", "samples_read",
              "read_to_end", "recording_hours", "rejected_fit", "warnings",
              "uncertainty_blocks", "temperature_dropped"):
        if k in extra:
            out[k] = extra[k]
    return jsonable(out)



def uncertainty_lines(est, indent: str = "  ") -> str:
    """The standard errors (one SE, the coefficients' units shown as above) as text lines."""
    u = est.uncertainty

    def f(vals, scale, spec):
        return "  ".join(f"{a} " + ("n/a" if v is None else format(v * scale, spec))
                         for a, v in zip("xyz", vals))
    t = u.get("temperature_ref")
    lines = [f"{indent}+- offset    {f(u['offset'], 1.0, '.6f')}  (one standard error)",
             f"{indent}+- scale     {f(u['scale'], 1.0, '.6f')}"]
    if any(v is not None for v in u["tempoffset"]):
        lines.append(f"{indent}+- tempoff   {f(u['tempoffset'], 1000.0, '.4f')}  mg/degC"
                     + ("" if t is None else f"  (T_ref +- {t:.2f} degC)"))
    blocks = est.extra.get("uncertainty_blocks")
    if blocks is not None:
        lines.append(f"{indent}             over {blocks} independent blocks of windows")
    return "\n".join(lines) + "\n"


def fmt_hours(h: float) -> str:
    return f"{h:.1f} h" if h >= 1.0 else f"{h * 60:.1f} min"


def print_human(est, out=None, title: str = "") -> None:
    out = out or sys.stdout
    w = out.write
    if title:
        w(f"{title}\n")
    w(f"  status       {est.status}\n")
    w(f"  reason       {est.reason}\n")
    w(f"  method       {est.method}\n")
    hours = "" if est.hours_used is None else f" ({fmt_hours(est.hours_used)} of data used)"
    w(f"  windows      {est.windows}{hours}\n")
    if est.error_before_mg is None:
        w("  error        n/a (no calibration windows)\n")
    elif est.error_after_mg is None:
        w(f"  error        {est.error_before_mg:.2f} mg (not calibrated)\n")
    else:
        ggir = ""
        if "error_before_g" in est.extra and "error_after_g" in est.extra:
            ggir = (f"  (GGIR prints {est.extra['error_before_g']:g} g -> "
                    f"{est.extra['error_after_g']:g} g)")
        w(f"  error        {est.error_before_mg:.2f} mg before -> "
          f"{est.error_after_mg:.2f} mg after{ggir}\n")
    w("  offset (g)   " + "  ".join(f"{a} {v:+.6f}" for a, v in zip("xyz", est.offset)) + "\n")
    w("  scale        " + "  ".join(f"{a} {v:.6f}" for a, v in zip("xyz", est.scale)) + "\n")
    w("  tempoffset   " + "  ".join(f"{a} {v * 1000:+.4f}" for a, v in zip("xyz", est.tempoffset))
      + f"  mg/degC (T_ref {est.temperature_ref:.2f} degC)\n")
    u = getattr(est, "uncertainty", None)
    if u:
        w(uncertainty_lines(est))
    diag = est.diagnostics
    rule = diag.stop_rule
    if rule:
        conv = "converged" if diag.converged else "NOT converged"
        w(f"  iterations   {est.iterations} ({conv}; "
          f"{'GGIR rule |d res| < 1e-10' if rule == 'ggir-res' else 'parameter change < 1e-9'})\n")
    flags = diag.flags
    if flags:
        w(f"  flags        {', '.join(flags)}\n")


def finish_output(args, est, windows, title: str) -> int:
    """Shared tail of both commands: plot, then JSON or human output. Exit code 0: a result was
    produced (see ``status`` for its quality)."""
    if getattr(args, "plot", None):
        from stillpoint.engine.calibration.plot import plot_calibration

        plot_calibration(windows, est, args.plot, title=title)
    if args.json:
        print(json.dumps(estimate_json(est), sort_keys=False))
    else:
        print_human(est, title=title)
        if getattr(args, "plot", None):
            print(f"  plot         {args.plot}")
    return 0


def _calibrate_one(path: str, opts: dict, progress=None) -> tuple:
    """Worker: (estimate dict, device key, plot path or None); runs in a child with --jobs."""
    from stillpoint.engine.calibration.recording import calibrate_recording

    plot = opts.pop("plot", None)
    title = opts.pop("title", path)
    res = calibrate_recording(path, progress=progress, **opts)
    est = res.estimate
    if plot:
        from stillpoint.engine.calibration.plot import plot_calibration

        plot_calibration(res.windows, est, plot, title=f"{title} ({res.info.device_key})")
    return est.to_dict(), res.info.device_key, plot


def _calibrate_safe(path: str, opts: dict) -> tuple:
    """Pool worker: typed input errors come back as text (they do not pickle)."""
    from stillpoint.engine.core.errors import StillpointError

    try:
        return _calibrate_one(path, opts), None
    except StillpointError as e:
        return None, str(e)
    except Exception as e:  # one file's failure never stops the others
        return None, f"{path}: unexpected {type(e).__name__}: {e}"


def _plot_path(args, path: str, many: bool):
    if not args.plot:
        return None
    if not many:
        return args.plot
    from pathlib import Path

    return str(Path(args.plot) / (Path(path).name + ".png"))


def _check_outputs(args, many: bool) -> None:
    """Plot destination and store are checked before any file is read."""
    from pathlib import Path

    from stillpoint.engine.core.outputs import OutputError, check_output_path, describe_os_error
    if args.plot and many:  # --plot names a folder: one PNG per file
        d = Path(args.plot)
        try:
            d.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise OutputError(d, f"cannot create the plot folder: {describe_os_error(e)}") from None
        check_output_path(d / "plot.png", what="plot")
    elif args.plot:
        check_output_path(args.plot, what="plot")


def run(args) -> int:
    from stillpoint.engine.core.errors import StillpointError

    if args.first_hours <= 0 or args.chunk_hours <= 0:
        raise StillpointError("--first-hours and --chunk-hours must be positive")
    if args.jobs < 1:
        raise StillpointError("--jobs must be at least 1")
    if args.store_dir is not None and not args.store:
        raise StillpointError("--store-dir names the store --store records in; give --store too "
                              "(it would be ignored here)")
    files = list(args.file)
    many = len(files) > 1
    base = dict(first_hours=args.first_hours, chunk_hours=args.chunk_hours,
                temperature=not args.no_temperature, ggir_compatible=args.ggir_compatible,
                variant=args.variant, sd_threshold=args.sd_threshold_mg / 1000.0,
                read_all=args.read_all)
    _check_outputs(args, many)
    plots, seen = [], {}
    for f in files:  # one PNG per input; a name met twice gets a number (never one shared file)
        pp = _plot_path(args, f, many)
        if pp is not None and many:
            k = seen[pp] = seen.get(pp, 0) + 1
            if k > 1:
                pp = pp[:-len(".png")] + f".{k}.png"
        plots.append(pp)
    jobs = [(f, dict(base, plot=pp, title=f)) for f, pp in zip(files, plots)]
    store = None
    if args.store:
        from stillpoint.engine.calibration.store import CalibrationStore

        store = CalibrationStore(args.store_dir)
        store.check()

    from stillpoint.engine.progress import ByteSpans, Progress
    bar = Progress("calibrate", quiet=args.quiet)
    spans = ByteSpans(bar, files)

    def results():
        if args.jobs == 1 or not many:
            for i, (f, o) in enumerate(jobs):
                spans.start(i)
                try:
                    out = _calibrate_one(f, o, progress=bar.update)
                except StillpointError as e:
                    if not many:
                        raise
                    yield f, None, e
                    continue
                except Exception as e:  # one file's failure never stops the others
                    if not many:
                        raise
                    yield f, None, f"{f}: unexpected {type(e).__name__}: {e}"
                    continue
                yield f, out, None
        else:
            from concurrent.futures import ProcessPoolExecutor

            with ProcessPoolExecutor(max_workers=min(args.jobs, len(jobs))) as ex:
                futs = [(f, ex.submit(_calibrate_safe, f, o)) for f, o in jobs]
                for i, (f, fut) in enumerate(futs):
                    try:
                        out, err = fut.result()
                    except Exception as e:  # e.g. a worker killed by the system
                        out, err = None, f"{f}: the worker failed ({type(e).__name__}: {e})"
                    spans.finish(i)
                    yield f, out, err

    try:
        failed = _report(args, results(), store, many, bar)
    except BaseException:
        bar.close(completed=False)
        raise
    bar.close()
    return 2 if failed else 0


def _report(args, results, store, many: bool, bar) -> int:
    """Print each file's result as it comes; returns the number that failed."""
    from stillpoint.engine.calibration.estimate import CalibrationEstimate
    failed = 0
    for f, out, err in results:
        if err is not None:
            failed += 1
            bar.message(f"stillpoint calibrate: error: {err}")
            if args.json:
                print(json.dumps({"file": f, "status": "error", "reason": str(err)}))
            else:
                print(f"{f}\n  status       error\n  reason       {err}")
            continue
        d, key, plot = out
        est = CalibrationEstimate.from_dict(d)
        if store is not None:
            store.add(est, source=f)
            if not args.json:
                bar.message(f"stored for {est.device_key} in {store.dir}")
        if args.json:
            obj = estimate_json(est)
            if many:
                obj = {"file": f, **obj}
            print(json.dumps(obj), flush=True)
        else:
            print_human(est, title=f"{f} ({key})")
            if plot:
                print(f"  plot         {plot}")
    return failed
