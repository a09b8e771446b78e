"""`stillpoint simulate --scenario sixface|infant`: the six-orientation calibration session and the
infant ankle recording simulators (engine.sim.sixface / engine.sim.infant)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from ._numbers import DEVICE_ID, number, number_pair


def add_arguments(p) -> None:
    g = p.add_argument_group("scenarios sixface / infant")
    g.add_argument("--scenario", choices=("free-living", "sixface", "infant"), default="free-living",
                   help="free-living (default): the wearer simulator; sixface: a six-orientation "
                        "calibration session; infant: an infant ankle recording with kicks")
    g.add_argument("--sensor-errors", choices=("table2", "none"), default="table2",
                   help="sixface/infant: Table-2-like offset/gain/noise drawn from --seed, or none")
    g.add_argument("--cross-axis", type=number(0, 1), default=0.0,
                   help="sixface/infant: maximum |cross-axis term| of the drawn errors (default 0)")
    g.add_argument("--coupling", type=number(0, 0.2), default=0.0, metavar="FRACTION",
                   help="sixface/infant: symmetric cross-axis coupling (non-orthogonal axes), each "
                        "axis pair drawn within ±FRACTION (e.g. 0.02 = 2 %%); added to the drawn "
                        "errors, or alone with --sensor-errors none")
    g.add_argument("--table-tilt-deg", type=number(0, 30, unit="deg"), default=0.0,
                   help="sixface: the table tilted by this angle, the device at a random yaw on it "
                        "per hold (six faces alone cannot tell this tilt from coupling)")
    g.add_argument("--hold-s", type=number(0, 3600, lo_open=True, unit="s"), default=10.0,
                   help="sixface: seconds per face")
    g.add_argument("--order", default=None, help="sixface: face order, e.g. +x,-x,+y,-y,+z,-z "
                                                 "(default random; repeats allowed)")
    g.add_argument("--minutes", type=number(0, 31 * 1440, lo_open=True, unit="min"), default=20.0,
                   help="infant: recording length")
    g.add_argument("--sleep", action="append", default=[], metavar="START_MIN:LEN_MIN",
                   type=number_pair(number(0, 31 * 1440, unit="min"), form="START_MIN:LEN_MIN"),
                   help="infant: a sleep block (repeatable)")
    g.add_argument("--controls", action="store_true",
                   help="infant: add negative controls (perpendicular-only, no-rotation, rhythmic)")
    g.add_argument("--skew-ppm", type=number(-100_000, 100_000, unit="ppm"), default=0.0,
                   help="infant: device clock skew")
    g.add_argument("--device-id", type=DEVICE_ID, default=None, help="sixface/infant: device serial")


def run(args) -> int:
    """The scenario; a value the writers refuse (an AX rate that is not 3200/2^k Hz, ...) is
    one line (``ModelError``), not a traceback."""
    from stillpoint.engine.core.errors import StillpointError
    from stillpoint.engine.sim.model import ModelError
    try:
        return _run(args)
    except ValueError as e:
        if isinstance(e, StillpointError):
            raise
        raise ModelError(f"{args.output}: {e}") from None


def _run(args) -> int:
    import numpy as np

    from stillpoint.engine.sim.model import ModelError
    from stillpoint.engine.sim.static_errors import StaticErrors
    out = Path(args.output)
    if args.device == "geneactiv" or not out.name.endswith(".cwa"):
        raise ModelError(f"{out}: the {args.scenario} scenario writes an AX3/AX6 .cwa file")
    rng = np.random.default_rng((args.seed, 5))
    errors = (StaticErrors.draw(rng, cross_max=args.cross_axis, coupling_max=args.coupling)
              if args.sensor_errors == "table2" else StaticErrors.ideal())
    if args.coupling and args.sensor_errors != "table2":
        errors.symmetric = list(rng.uniform(-args.coupling, args.coupling, 3))
    hz = args.hz if args.hz != 100.0 else 25.0  # the scenarios default to the AX6's 25 Hz
    dev_id = args.device_id if args.device_id is not None else 4000 + args.seed
    range_g = args.range_g or 8
    if args.scenario == "sixface":
        from stillpoint.engine.sim.sixface import simulate_sixface, write_sixface
        order = args.order.split(",") if args.order else None
        try:
            s = simulate_sixface(fs=hz, hold_s=args.hold_s, order=order, errors=errors, seed=args.seed,
                                 table_tilt_deg=args.table_tilt_deg)
        except ValueError as e:
            raise ModelError(str(e)) from None
        res = write_sixface(out, s, device=args.device, device_id=dev_id, range_g=range_g,
                            truth_path=args.truth)
        text = (f"{res['path']}: {args.device} six-orientation session, {res['samples']} samples at "
                f"{hz:g} Hz, faces {','.join(s.settings['order'])}; truth {res['truth']}")
    else:
        from stillpoint.engine.sim.infant import make_infant, write_infant
        sleep = list(args.sleep)  # (start, length) pairs checked when parsed
        sim = make_infant(minutes=args.minutes, fs=hz, seed=args.seed, errors=errors,
                          sleep_blocks=sleep, controls=args.controls, clock_skew_ppm=args.skew_ppm)
        res = write_infant(out, sim, device=args.device, device_id=dev_id, range_g=range_g,
                           truth_path=args.truth)
        text = (f"{res['path']}: {args.device} infant ankle recording, {args.minutes:g} min at "
                f"{hz:g} Hz, {res['kicks']} kicks; truth {res['truth']}")
    if args.json:
        json.dump(dict(res, errors=errors.to_dict()), sys.stdout, indent=1)
        print()
    else:
        print(text)
    return 0
