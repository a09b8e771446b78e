"""``stillpoint calibrate FILE``: batch autocalibration of a recording, fit only (no corrected
output): the fast path for cohort QC.

One streaming pass computes 10 s window features, keeps the nonmovement windows and fits by the
72 h + 12 h schedule (van Hees 2014), stopping the read as soon as the fit is good (error
< 10 mg, sphere covered). ``--json`` prints one object with keys ``offset``, ``scale``,
``tempoffset`` (GGIR form), ``temperature_ref``, ``error_before_mg``, ``error_after_mg``,
``windows``, ``iterations``, ``status``, ``reason`` and more. ``--store`` records the estimate in
the per-device calibration store; ``--plot PNG`` draws the calibration report.
"""

from __future__ import annotations

import json
import math
import sys

NAME = "calibrate"
HELP = "autocalibrate a recording (fit only, no corrected output; --json, --plot, --store)"

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
    parser.add_argument("file", help="recording: .cwa (AX3/AX6), .bin (GENEActiv), .mcap; .gz ok")
    add_fit_arguments(parser)
    parser.add_argument("--first-hours", type=float, default=72.0,
                        help="first load of the schedule in hours (default 72; GGIR >= 3.0: 168)")
    parser.add_argument("--chunk-hours", type=float, default=12.0,
                        help="data added per refit when the first load is not enough (default 12)")
    parser.add_argument("--sd-threshold-mg", type=float, default=13.0,
                        help="nonmovement threshold on each axis' SD (default 13 mg)")
    parser.add_argument("--read-all", action="store_true",
                        help="read the whole file even when the schedule is satisfied early")
    parser.add_argument("--store", action="store_true",
                        help="record the estimate in the per-device calibration store")
    parser.add_argument("--store-dir", metavar="DIR",
                        help="calibration store root (default $STILLPOINT_HOME or "
                             "~/.local/share/stillpoint)")


def estimate_json(est) -> dict:
    """The CLI's JSON object: the issue's keys first, then the rest of the estimate."""
    d = est.to_dict()
    out = {k: d[k] for k in JSON_KEYS}
    extra = d.pop("extra", {}) or {}
    for k, v in d.items():
        if k not in out:
            out[k] = v
    for k in ("flags", "temperature_used", "temperature_reason", "converged", "stop_rule",
              "schedule", "error_before_g", "error_after_g", "variant", "ggir_compatible",
              "windows_offered", "repeats_collapsed", "windows_total", "samples_read",
              "read_to_end", "recording_hours", "rejected_fit"):
        if k in extra:
            out[k] = extra[k]
    return _finite(out)


def _finite(x):
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, dict):
        return {k: _finite(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_finite(v) for v in x]
    return x


def _num(v, fmt):
    return "n/a" if v is None else format(v, fmt)


def print_human(est, out=None, title: str = "") -> None:
    out = out or sys.stdout
    w = out.write
    if title:
        w(f"{title}\n")
    w(f"  status       {est.status}\n")
    w(f"  reason       {est.reason}\n")
    w(f"  method       {est.method}\n")
    hours = "" if est.hours_used is None else f" ({est.hours_used:.1f} h of data used)"
    w(f"  windows      {est.windows}{hours}\n")
    w(f"  error        {_num(est.error_before_mg, '.2f')} mg before -> "
      f"{_num(est.error_after_mg, '.2f')} mg after\n")
    w("  offset (g)   " + "  ".join(f"{a} {v:+.6f}" for a, v in zip("xyz", est.offset)) + "\n")
    w("  scale        " + "  ".join(f"{a} {v:.6f}" for a, v in zip("xyz", est.scale)) + "\n")
    w("  tempoffset   " + "  ".join(f"{a} {v * 1000:+.4f}" for a, v in zip("xyz", est.tempoffset))
      + f"  mg/degC (T_ref {est.temperature_ref:.2f} degC)\n")
    rule = est.extra.get("stop_rule")
    if rule:
        conv = "converged" if est.extra.get("converged") else "NOT converged"
        w(f"  iterations   {est.iterations} ({conv}; "
          f"{'GGIR rule |d res| < 1e-10' if rule == 'ggir-res' else 'parameter change < 1e-9'})\n")
    flags = est.extra.get("flags") or []
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


def run(args) -> int:
    from stillpoint.engine.calibration.recording import calibrate_recording

    if args.first_hours <= 0 or args.chunk_hours <= 0:
        from stillpoint.drivers.errors import StillpointError

        raise StillpointError("--first-hours and --chunk-hours must be positive")
    res = calibrate_recording(args.file, first_hours=args.first_hours,
                              chunk_hours=args.chunk_hours,
                              temperature=not args.no_temperature,
                              ggir_compatible=args.ggir_compatible, variant=args.variant,
                              sd_threshold=args.sd_threshold_mg / 1000.0,
                              read_all=args.read_all)
    est = res.estimate
    if args.store:
        from stillpoint.engine.calibration.store import CalibrationStore

        store = CalibrationStore(args.store_dir)
        store.add(est, source=args.file)
        if not args.json:
            print(f"stored for {est.device_key} in {store.dir}", file=sys.stderr)
    return finish_output(args, est, res.windows, title=f"{args.file} ({res.info.device_key})")
