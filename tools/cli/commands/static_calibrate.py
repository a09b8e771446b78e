"""`stillpoint static-calibrate FILE`: six-orientation static calibration (Oh et al. 2024)."""

from __future__ import annotations

import json
from pathlib import Path

from ._numbers import number

NAME = "static-calibrate"
HELP = "estimate offset, gain, misalignment and noise per axis from a six-orientation recording"
KEEPS_EXISTING_OUTPUTS = True  # --overwrite replaces an existing output
DESCRIPTION = (HELP + ". The user puts the device on a level surface on each of its six faces "
               "for about 10 s (any order). Modes: reference = the HBCD release's search "
               "exactly (incl. its quirks); paper = SD cut-off 0.01 g; robust = still on all "
               "axes, longest hold per face, offsets from the face-pair midpoints, per-face quality "
               "(recommended for new data). Cross-axis coupling is reported separately.")


def add_arguments(p) -> None:
    p.add_argument("file", type=Path, help="six-orientation recording (.cwa, .cwa.gz, .bin)")
    p.add_argument("--mode", choices=("reference", "paper", "robust"), default="reference")
    p.add_argument("--full-matrix", action="store_true",
                   help="also fit the affine model (beyond the paper): the 3x3 matrix with the "
                        "gains on its diagonal and the cross-axis coupling off it, the face-pair "
                        "midpoints as offset; `movements` applies it (level surface only: a tilt "
                        "enters the coupling)")
    p.add_argument("--allow-nan", action="store_true",
                   help="reference mode: reproduce the reference code's NaNs for missing faces "
                        "instead of failing")
    p.add_argument("--window-s", type=number(1, 3600, integer=True, unit="s"), default=None,
                   help="search window length (default 5 s)")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.add_argument("-o", "--output", type=Path, help="write the calibration JSON here "
                                                     "(for `movements --calibration`)")
    p.add_argument("--plot", type=Path, metavar="PNG", help="figure: windows and per-face readings")
    p.add_argument("--store", nargs="?", const="", default=None, metavar="DIR",
                   help="add the estimate to the calibration store (default location, or DIR)")
    p.add_argument("--mcap", type=Path, metavar="OUT.mcap",
                   help="log the estimate (topic /static_calibration) to an MCAP file")


def _fmt(v, f="{:+.4f}"):
    return "nan" if v is None or v != v else f.format(v)


def human(cal) -> str:
    lines = [f"{cal.device_key}: six-orientation static calibration, {cal.mode} mode: {cal.status}",
             "axis   offset_g    gain      misalign_signed_g  misalign_abs_g  noise_g"]
    for k, ax in enumerate("xyz"):
        lines.append(f"  {ax}   {_fmt(cal.offset_g[k])}   {_fmt(cal.gain[k], '{:.5f}')}   "
                     f"{_fmt(cal.misalignment_signed_g[k]):>17}  {_fmt(cal.misalignment_abs_g[k], '{:.4f}'):>14}"
                     f"  {_fmt(cal.noise_g[k], '{:.4f}')}")
    cross = getattr(cal, "cross_axis_g", None)
    if cross is not None:
        lines.append("cross-axis coupling, % (jk: axis j's reading per g along axis k): " + ", ".join(
            f"{'xyz'[j]}{'xyz'[k]} {_fmt(cross[j][k] * 100, '{:+.2f}')}"
            for j in range(3) for k in range(3) if j != k))
    lines.append("face  start_s   end_s  window_s  band_g          SD_g")
    for f, d in cal.faces.items():
        if not d.get("samples"):
            lines.append(f"  {f}  not found")
            continue
        band = d.get("band_g")
        band_s = f"[{band[0]:.2f}, {band[1]:.2f}]" if band else "still, all axes"
        extra = "" if d.get("tested", True) else "  (untested window, reference quirk)"
        if "corrected_norm_error_g" in d:
            extra += (f"  after correction |norm-1| {d['corrected_norm_error_g'] * 1000:.2f} mg, "
                      f"tilt {d['corrected_tilt_deg']:.2f} deg")
        lines.append(f"  {f}  {d['start_s']:7.2f} {d['end_s']:7.2f}  {d['window_s']:8.2f}  "
                     f"{band_s:<16}{d['sd_g']:.4f}{extra}")
    if cal.matrix is not None:
        lines.append("full matrix S (rows = measured axes): " +
                     "; ".join(" ".join(f"{v:+.5f}" for v in row) for row in cal.matrix))
    for w in cal.warnings:
        lines.append(f"warning: {w}")
    return "\n".join(lines)


def run(args) -> int:
    from stillpoint.engine.core.outputs import atomic_output, check_distinct_outputs, check_output_path
    from stillpoint.engine.calibration.static import (read_calibration_recording,
                                                      static_calibration_file)
    from stillpoint.engine.core.jsonsafe import dumps
    from ._runopts import OptionError
    if args.allow_nan and args.mode != "reference":
        raise OptionError("--allow-nan reproduces the reference code: only with --mode reference")
    check_distinct_outputs({"calibration JSON": args.output, "plot": args.plot, "MCAP": args.mcap})
    for p in (args.output, args.plot, args.mcap):
        if p is not None:
            check_output_path(p)
    cal = static_calibration_file(args.file, mode=args.mode, full_matrix=args.full_matrix,
                                  allow_nan=args.allow_nan, window_s=args.window_s)
    doc = json.loads(dumps(cal.to_dict()))
    outputs = {}
    if args.output:
        with atomic_output(args.output, binary=False, what="calibration JSON") as f:
            f.write(json.dumps(doc, indent=1, sort_keys=True) + "\n")
        outputs["calibration"] = str(args.output)
    if args.plot:
        from stillpoint.engine.calibration.static_plot import plot_static_calibration
        t, acc, _ = read_calibration_recording(args.file)
        plot_static_calibration(t, acc, cal, args.plot)
        outputs["plot"] = str(args.plot)
    if args.mcap:
        from stillpoint.engine.movements.mcap_out import write_static_mcap
        write_static_mcap(args.mcap, cal)
        outputs["mcap"] = str(args.mcap)
    if args.store is not None:
        if cal.status != "ok":
            raise OptionError(f"{args.file}: an incomplete calibration ({cal.status}) is not stored")
        from stillpoint.engine.calibration import CalibrationStore
        store = CalibrationStore(args.store or None)
        store.add(cal.to_estimate(), source=str(args.file))
        outputs["store"] = str(store.dir)
    doc["outputs"] = outputs
    if args.json:
        print(json.dumps(doc, indent=1, sort_keys=True))
    else:
        print(human(cal))
        if outputs:
            print("outputs: " + ", ".join(f"{k} {v}" for k, v in outputs.items()))
    return 0
