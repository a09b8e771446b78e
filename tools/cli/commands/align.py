"""`stillpoint align REFERENCE OTHER`: estimate the clock offset and drift between two recordings
worn together and resample OTHER onto REFERENCE's clock.

Exit codes: 0 aligned; 2 unreadable input (one line on stderr); 3 cannot align (too few active
1 h blocks, no overlap in time): the reason is printed and, with ``--json``, the JSON result has
``"aligned": false`` and a ``reason`` (no confident wrong answer is ever returned).
"""

from __future__ import annotations

import json
import sys

from ._numbers import RATE_HZ, SECONDS_DAY, number, number_or
from stillpoint.engine.core.errors import StillpointError
from stillpoint.engine.core.outputs import atomic_output, check_distinct_outputs, check_output_path
from stillpoint.engine.core.jsonsafe import jsonable

NAME = "align"
HELP = "align two recordings worn together (clock offset, drift, halts; Brønd et al. 2021)"
KEEPS_EXISTING_OUTPUTS = True  # --overwrite replaces an existing output
DESCRIPTION = (
    "Estimate the clock offset and drift of OTHER relative to REFERENCE from the acceleration "
    "itself (per 1 h block cross-correlation of the activity signal, Brønd et al. 2021) and "
    "optionally write OTHER resampled onto REFERENCE's clock to an MCAP file. "
    "Exit codes: 0 aligned, 2 unreadable input, 3 cannot align (reason printed).")

EXIT_CANNOT_ALIGN = 3
# the common rate must be above twice the activity band-pass's upper edge (7 Hz,
# engine/alignment/signal.py BAND_HZ): the filter cannot be designed below it
MIN_COMMON_RATE_HZ = 14.0
COMMON_RATE = number(MIN_COMMON_RATE_HZ, RATE_HZ.hi, lo_open=True, unit="Hz")


def add_arguments(p) -> None:
    p.add_argument("reference", help="reference recording (.cwa, .bin, MCAP); its clock is kept")
    p.add_argument("other", help="second recording, resampled onto the reference clock")
    p.add_argument("-o", "--output", metavar="OUT.mcap",
                   help="write block lags, estimates and the aligned OTHER stream to this MCAP")
    p.add_argument("--json", action="store_true", help="print the full result as JSON on stdout")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress on stderr")
    p.add_argument("--json-out", metavar="PATH", help="also write the JSON result to PATH")
    p.add_argument("--plot", metavar="PNG", help="lag-vs-time with fit and correlograms (matplotlib)")
    p.add_argument("--method", choices=("brond", "robust"), default="robust",
                   help="brond: the paper (integer lags, +-1000 samples, iterative exclusion); "
                        "robust (default): sub-sample lags at activity-weighted block times, "
                        "+-600 s search, trimmed fit with CIs, halt/step detection, temperature term")
    p.add_argument("--interpolation", choices=("previous", "linear", "cubic"), default="previous",
                   help="resampling of OTHER (default previous: keeps amplitudes, as the paper)")
    p.add_argument("--rate", type=number_or("native", COMMON_RATE), default="30",
                   help="common rate, Hz (default 30, the paper's), or 'native': the reference's "
                        "own rate (sub-sample lags at the native rate; slower)")
    p.add_argument("--out-rate", type=RATE_HZ, default=None,
                   help="rate of the aligned stream (default: OTHER's nominal rate)")
    p.add_argument("--block-minutes", type=number(1, 10_080, unit="min"), default=None,
                   help="block length (default 60 for brond, 10 for robust)")
    p.add_argument("--max-lag-s", type=SECONDS_DAY, default=None,
                   help="lag search half-width, s (default 1000 samples for brond, 600 s robust)")
    p.add_argument("--block-time", choices=("start", "centre", "centroid"), default="start",
                   help="brond: time given to a block's lag (default start, as the authors' code)")
    p.add_argument("--min-blocks", type=number(1, 100_000, integer=True), default=None,
                   help="valid blocks needed (default 4 for brond, 12 ten-minute blocks robust)")
    p.add_argument("--no-temperature", action="store_true",
                   help="robust: do not consider the crystal-temperature drift term")
    p.add_argument("--no-steps", action="store_true", help="robust: no step (halt) detection")
    p.add_argument("--online", action="store_true",
                   help="also log the estimate refreshed after every valid block (MCAP)")


def _summary(d: dict) -> str:
    if not d["aligned"]:
        return f"not aligned: {d['reason']}"
    lines = [f"model            {d['model']} ({d['method']})",
             f"initial offset   {d['initial_offset_s']:+.4f} s (other clock minus reference)",
             f"drift            {d['drift_s_per_day']:+.4f} s/day",
             f"drift at day 7   {d['drift_day7_s']:+.3f} s",
             f"blocks used      {d['blocks_used']} of {d['blocks_valid']} valid, "
             f"{d['blocks_total']} total ({d['blocks_excluded']} excluded by the fit)",
             f"rmse             {d['rmse_samples']:.3f} samples at {d['rate_hz']:g} Hz"]
    ci = d.get("ci") or {}
    if ci:
        lo, hi = ci["initial_offset_s"]
        lines.append(f"95% CI offset    [{lo:+.4f}, {hi:+.4f}] s")
        lo, hi = ci["drift_day7_s"]
        lines.append(f"95% CI day 7     [{lo:+.3f}, {hi:+.3f}] s")
    for s in d.get("steps", []):
        if s.get("kind") == "gap":  # a sampling interruption: no lag step, only its place
            lines.append(f"sampling gap     {s['duration_s']:.3f} s on the {s['device']} device at "
                         f"{s['time_s'] / 3600:.2f} h")
            continue
        lines.append(f"step             {s['size_s']:+.3f} s at {s['time_s'] / 3600:.2f} h "
                     f"(within {s['window_s'][0] / 3600:.2f}-{s['window_s'][1] / 3600:.2f} h)")
    return "\n".join(lines)


def run(args) -> int:
    from stillpoint.engine.recordings import open_recording
    from stillpoint.engine.alignment.operator import AlignConfig, run_alignment

    config = AlignConfig(method=args.method,
                         rate=None if args.rate == "native" else args.rate,
                         block_s=None if args.block_minutes is None else args.block_minutes * 60.0,
                         max_lag_s=args.max_lag_s, block_time=args.block_time,
                         min_blocks=args.min_blocks, temperature=not args.no_temperature,
                         detect_steps=not args.no_steps, keep_correlograms=bool(args.plot))
    with open_recording(args.reference) as ref:  # fail early (exit 2) on unreadable input
        native = ref.info.sample_rate_nominal
    if args.rate == "native" and not (native or 0) > MIN_COMMON_RATE_HZ:
        raise StillpointError(f"{args.reference}: --rate native needs a reference rate above "
                              f"{MIN_COMMON_RATE_HZ:g} Hz (twice the activity band's 7 Hz upper "
                              f"edge); its nominal rate is {native} Hz: give --rate 30")
    open_recording(args.other).close()
    check_distinct_outputs({"MCAP output": args.output, "JSON output": args.json_out,
                            "plot": args.plot})
    for path, what in ((args.output, "MCAP output"), (args.json_out, "JSON output"),
                       (args.plot, "plot")):
        if path:
            check_output_path(path, what=what)  # before the work, not after it
    from stillpoint.engine.progress import Progress, Reporting
    bar = Progress("align", quiet=args.quiet)
    passes = 2 if args.output else 1  # the reference read once; the other again to be written
    opened = []

    def open_reference():
        bar.phase(0, passes)
        return Reporting(open_recording(args.reference), bar.update)

    def open_other():
        opened.append(1)
        if len(opened) == 1:
            return open_recording(args.other)
        bar.phase(1, passes)
        return Reporting(open_recording(args.other), bar.update)

    with bar:
        res = run_alignment(open_reference, open_other, config, out_mcap=args.output,
                            interpolation=args.interpolation, out_rate=args.out_rate,
                            online=args.online)
    d = res.as_dict()
    d["reference"]["path"] = str(args.reference)
    d["other"]["path"] = str(args.other)
    text = json.dumps(jsonable(d), indent=1, allow_nan=False)
    if args.json_out:
        with atomic_output(args.json_out, binary=False, what="JSON output") as f:
            f.write(text + "\n")
    if args.json:
        print(text)
    else:
        print(_summary(d))
    if args.plot:
        from stillpoint.engine.alignment.plot import plot_alignment
        plot_alignment(res, args.plot)
    if not res.ok:
        if args.json:
            print(f"stillpoint align: not aligned: {res.reason}", file=sys.stderr)
        return EXIT_CANNOT_ALIGN
    return 0
