"""``stillpoint calibration list|show DEVICE|export [-o FILE]``: the per-device calibration store.

``list``: one line per device (records, good ones, last fit). ``show DEVICE``: every estimate of
a device (``--json`` for the records). ``export``: the whole store as one JSON document (stdout
or ``-o FILE``). The store lives in ``$STILLPOINT_HOME`` or ``~/.local/share/stillpoint``
(``--store-dir`` overrides); ``stillpoint calibrate --store`` and online processing write to it.
"""

from __future__ import annotations

import argparse
import json
import sys

from stillpoint.engine.core.errors import StillpointError
from stillpoint.engine.calibration.estimate import FitDiagnostics

NAME = "calibration"
HELP = "the per-device calibration store: list | show DEVICE | export [-o FILE]"
KEEPS_EXISTING_OUTPUTS = True  # --overwrite replaces an existing output


def add_arguments(parser) -> None:
    parser.add_argument("--store-dir", metavar="DIR",
                        help="store root (default $STILLPOINT_HOME or ~/.local/share/stillpoint)")
    sub = parser.add_subparsers(dest="action", metavar="ACTION")
    p = sub.add_parser("list", help="devices in the store")
    p.add_argument("--json", action="store_true")
    p = sub.add_parser("show", help="every estimate of one device")
    p.add_argument("device", help="device key, e.g. AX3-39434 (see `list`)")
    p.add_argument("--json", action="store_true")
    p = sub.add_parser("export", help="the whole store as one JSON document")
    p.add_argument("-o", "--output", metavar="FILE", help="write here instead of stdout")
    p.add_argument("--overwrite", action="store_true", default=argparse.SUPPRESS,
                   help="replace FILE if it exists (without it an existing file is refused)")


def _fmt(v, spec=".2f"):
    return "-" if v is None else format(v, spec)


def run(args) -> int:
    from stillpoint.engine.calibration.store import CalibrationStore

    store = CalibrationStore(args.store_dir)
    action = getattr(args, "action", None)
    if action is None:
        raise StillpointError("choose an action: list, show DEVICE or export")
    if action == "list":
        rows = store.summary()
        if args.json:
            print(json.dumps(rows))
            return 0
        if not rows:
            print(f"no calibrations stored in {store.dir}")
            return 0
        print(f"{'device':<24} {'records':>7} {'good':>5}  {'last data end':<24} "
              f"{'status':<18} {'error after (mg)':>16}")
        for r in rows:
            print(f"{r['device_key']:<24} {r['records']:>7} {r['good']:>5}  "
                  f"{r['last_data_end'] or '-':<24} {r['last_status'] or '-':<18} "
                  f"{_fmt(r['last_error_after_mg']):>16}")
        return 0
    if action == "show":
        recs = store.records(args.device)
        if not recs:
            known = ", ".join(store.devices()) or "none"
            raise StillpointError(f"no calibration stored for device {args.device!r} in "
                                  f"{store.dir} (known devices: {known})")
        if args.json:
            print(json.dumps({"device_key": args.device, "records": recs}))
            return 0
        print(f"{args.device}: {len(recs)} estimate(s)")
        for r in recs:
            e, q = r["estimate"], r.get("quality") or {}
            print(f"- data {r.get('data_start') or '?'} .. {r.get('data_end') or '?'}  "
                  f"[{r['status']}, {r['method']}]  stored {r.get('stored_at')}")
            print(f"    error {_fmt(q.get('error_before_mg'))} -> "
                  f"{_fmt(q.get('error_after_mg'))} mg"
                  f" on {q.get('windows')} windows, {_fmt(q.get('hours_used'), '.1f')} h")
            print("    offset " + " ".join(f"{v:+.6f}" for v in e["offset"]) +
                  "  scale " + " ".join(f"{v:.6f}" for v in e["scale"]) +
                  "  tempoffset " + " ".join(f"{v:+.3e}" for v in e["tempoffset"]) +
                  f"  T_ref {e.get('temperature_ref', 0.0):.2f}")
            if e.get("uncertainty"):
                from stillpoint.engine.calibration import CalibrationEstimate
                from .calibrate import uncertainty_lines
                print(uncertainty_lines(CalibrationEstimate.from_dict(e), indent="    "), end="")
            for wn in FitDiagnostics.from_extra(e.get("extra")).warnings or ():
                print(f"    warning: {wn['message']}")
            if r.get("source"):
                print(f"    source {r['source']}")
            print(f"    {r.get('reason', '')}")
        return 0
    if action == "export":
        doc = json.dumps(store.export(), indent=1)
        if args.output:
            from stillpoint.engine.core.outputs import atomic_output
            with atomic_output(args.output, binary=False, what="store export") as f:
                f.write(doc + "\n")
            print(f"exported {len(store.devices())} device(s) to {args.output}", file=sys.stderr)
        else:
            print(doc)
        return 0
    raise StillpointError(f"unknown action {action!r}")
