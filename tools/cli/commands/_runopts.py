"""Shared options and output for `process`, `replay` and `demo` (settings, progress, summary)."""

from __future__ import annotations

import json

from stillpoint.engine.core.errors import StillpointError

from ._numbers import MG, setting


class OptionError(StillpointError):
    """A command-line option value is unusable."""


def add_setting_arguments(p, *, defaults_from_input: bool = False) -> None:
    """Options that map to RunSettings. With ``defaults_from_input`` every default is None
    (meaning: keep the value logged in the input MCAP)."""
    d = (lambda v: None) if defaults_from_input else (lambda v: v)
    g = p.add_argument_group("processing settings")
    g.add_argument("--mode", choices=("batch", "online"), default=d("batch"),
                   help="batch: two passes, final estimate applied from the start; online: one pass, "
                        "refit every 12 h of data, each estimate applied from its boundary")
    g.add_argument("--no-calibrate", dest="calibrate", action="store_const", const=False,
                   default=d(None), help="write raw g as the corrected stream (no autocalibration)")
    g.add_argument("--no-temperature", dest="temperature", action="store_const", const=False,
                   default=d(None), help="fit offset and scale only (no temperature term)")
    g.add_argument("--ggir-compatible", dest="ggir_compatible", action="store_const", const=True,
                   default=d(None), help="GGIR's stopping rule and error rounding (batch only)")
    g.add_argument("--first-hours", type=setting("first_hours"), default=None,
                   help="batch schedule: hours of data in the first fit (default 72; GGIR>=3.0 uses 168)")
    g.add_argument("--chunk-hours", type=setting("chunk_hours"), default=None,
                   help="hours added per refit (batch) / between refits (online); default 12")
    g.add_argument("--sd-threshold-mg", type=MG, default=None,
                   help="nonmovement: window SD below this on all axes (default 13 mg)")
    g.add_argument("--epoch-s", type=setting("epoch_s"), default=None, help="metric epoch length (default 5 s)")
    g.add_argument("--bfen-band", choices=("ggir", "vanhees"), default=None,
                   help="BFEN band-pass: ggir = 0.2-15 Hz (default), vanhees = 0.5-15 Hz")
    g.add_argument("--counts", choices=("normal", "lfe"), default=None,
                   help="ActiLife activity counts per epoch (axis1 = Y, axis2 = X, axis3 = Z, vm; "
                        "lfe: the low-frequency extension); needs a whole-second epoch")
    g.add_argument("--mims", dest="mims", action="store_const", const=True, default=d(None),
                   help="MIMS-units per epoch (John et al. 2019, as R MIMSunit); needs a whole-second epoch")
    g.add_argument("--flush-every-s", type=setting("flush_every_s"), default=None,
                   help="flush the MCAP every N s of data time (default 10: a kill loses <= 10 s)")
    g.add_argument("--compression", choices=("zstd", "lz4", "none"), default=None,
                   help="MCAP chunk compression (default zstd)")
    g.add_argument("--view-hz", type=setting("view_hz"), default=None,
                   help="samples per second on the plottable /view/accel topic (default 1; 0 = off)")
    g.add_argument("--log", choices=("full", "lean"), default=None,
                   help="what the MCAP keeps: full (default) or lean: settings, estimates, QC, epoch "
                        "metrics, sleep and the view stream, without the per-sample raw and "
                        "corrected streams (keep the recording: `replay LOG --raw RECORDING`)")


def settings_overrides(args) -> dict:
    o = {
        "mode": args.mode, "calibrate": args.calibrate, "temperature": args.temperature,
        "ggir_compatible": args.ggir_compatible, "first_hours": args.first_hours,
        "chunk_hours": args.chunk_hours, "epoch_s": args.epoch_s,
        "flush_every_s": args.flush_every_s, "compression": args.compression,
        "view_hz": getattr(args, "view_hz", None),
        "counts": getattr(args, "counts", None), "mims": getattr(args, "mims", None),
        "log": getattr(args, "log", None),
        "sd_threshold_g": None if args.sd_threshold_mg is None else args.sd_threshold_mg / 1000.0,
        "bfen_band_hz": {None: None, "ggir": (0.2, 15.0), "vanhees": (0.5, 15.0)}[args.bfen_band],
    }
    for k in ("first_hours", "chunk_hours", "epoch_s", "sd_threshold_g"):
        if o[k] is not None and o[k] <= 0:
            raise OptionError(f"--{k.replace('_', '-')} must be positive")
    if (o["counts"] or o["mims"]) and o["epoch_s"] is not None and not float(o["epoch_s"]).is_integer():
        raise OptionError(f"--counts and --mims need a whole-second --epoch-s, not {o['epoch_s']:g}")
    if o["view_hz"] is not None and o["view_hz"] < 0:
        raise OptionError("--view-hz must be 0 (off) or positive")
    return {k: v for k, v in o.items() if v is not None}


class Progress:
    """The pipeline's progress callback (``process_file(progress=...)``: label, stats) shown by
    ``engine.progress.Progress``: percentage and ETA on a terminal, a plain line every tenth (or
    30 s) otherwise, nothing when disabled (``-q``). A batch run's two passes share the bar
    (``engine.progress.BATCH_PASS_SPANS``)."""

    def __init__(self, enabled=None, stream=None, *, label: str = "process", tty=None,
                 clock=None):
        from stillpoint.engine.progress import Progress as _Progress
        kw = {} if clock is None else {"clock": clock}
        self.bar = _Progress(label, stream=stream, tty=tty, quiet=enabled is False, **kw)

    def __call__(self, label, st) -> None:
        from stillpoint.engine.progress import run_fraction
        self.bar.update(fraction=None if st.fraction is None else run_fraction(label, st.fraction),
                        detail=f"{label}, {st.data_s / 3600:.1f} h of data")

    def done(self, completed: bool = True) -> None:
        self.bar.close(completed=completed)


def _f(x, fmt="{:.2f}"):
    return "n/a" if x is None else fmt.format(x)


def human_summary(s: dict) -> str:
    c = s["calibration"]
    dev = s.get("device", {})
    lines = [
        f"{dev.get('type', '?')} {dev.get('id', '?')}: {s['samples']:,} samples, "
        f"{s['duration_s'] / 3600:.2f} h, {s.get('segments', 1)} segment(s), mode {s['mode']}",
        f"windows {s['windows']:,} (nonmovement {s['nonmovement_windows']:,}), epochs {s['epochs']:,}",
        f"calibration: {c['status']} - {c.get('reason', '')}",
        f"  error {_f(c['error_before_mg'])} -> {_f(c['error_after_mg'])} mg"
        f" (hours used {_f(c['hours_used'], '{:.1f}')})",
        "  offset " + " ".join(f"{v:+.5f}" for v in c["offset"]) +
        "  scale " + " ".join(f"{v:.5f}" for v in c["scale"]) +
        "  tempoffset " + " ".join(f"{v:+.6f}" for v in c["tempoffset"]),
        f"ENMO mean {_f(s['enmo_mean_mg'])} mg",
    ]
    qc = s.get("qc") or {}
    if qc.get("skipped") or qc.get("events"):
        lines.append(f"QC: {qc.get('skipped', 0)} {qc.get('unit', 'unit')}(s) skipped, "
                     f"{qc.get('events', 0)} event(s) {qc.get('reasons', {})}")
    clip = s.get("clipping") or {}
    if clip.get("flagged"):
        lines.append(f"clipping: {clip['seconds'] / 3600:.2f} h of data ({100 * clip['fraction']:.1f} % of "
                     f"samples) at the +-{clip['range_g']:g} g limit, longest run "
                     f"{(clip.get('longest_run_s') or 0) / 60:.1f} min: ENMO and the calibration are "
                     "biased there")
    lines.append("outputs: " + ", ".join(f"{k} {v}" for k, v in s["outputs"].items()))
    return "\n".join(lines)


def write_summary(summary: dict, path) -> None:
    """The run summary as JSON, written atomically (``<path>.part``, then renamed)."""
    from stillpoint.engine.core.outputs import atomic_output
    from stillpoint.engine.core.jsonsafe import dumps
    with atomic_output(path, binary=False, what="summary") as f:
        f.write(json.dumps(json.loads(dumps(summary)), indent=2, sort_keys=True) + "\n")
