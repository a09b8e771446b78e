"""`stillpoint station OUTDIR`: the download-and-correct station (docs/station.md)."""

from __future__ import annotations

import signal
import sys
import threading
from pathlib import Path

from ._numbers import PORT, SECONDS_DAY

NAME = "station"
HELP = "watch for AX3/AX6 devices: verified download + corrected MCAP, clear only after verification, configure"


def add_arguments(p) -> None:
    p.add_argument("outdir", type=Path, nargs="?", default=None,
                   help="output folder (raw copies, MCAP logs, tables, reports, the ledger); it "
                        "must exist (a missing folder is refused, never created)")
    p.add_argument("--profile", type=Path, default=None, help="study profile (TOML)")
    p.add_argument("--write-profile", type=Path, default=None, metavar="FILE",
                   help="write the example study profile (every key, commented) to FILE, a new "
                        "file, and exit; edit it for a study, then --profile FILE")
    p.add_argument("--clear-after-verify", action="store_true", default=None,
                   help="clear each device once its download is verified (also from the profile)")
    p.add_argument("--configure-after", action="store_true", default=None,
                   help="configure each cleared (or empty) device from the profile")
    p.add_argument("--reconfigure", action="store_true",
                   help="with --configure-after: configure even a device that a station already "
                        "configured for its current session (by default it is left as it is; its "
                        "printed handover sheet would be superseded)")
    p.add_argument("--erase", choices=("quick", "wipe"), default=None,
                   help="how a clear erases: quick (FORMAT QC, the default) or wipe (FORMAT WC, the "
                        "memory wiped too; slower); also [station] erase in the profile")
    p.add_argument("--inbox", type=Path, default=None,
                   help="also ingest .bin/.cwa files dropped in this folder (GENEActiv extractions)")
    p.add_argument("--once", action="store_true", help="handle the devices attached now, then exit")
    p.add_argument("--stall-s", type=SECONDS_DAY, default=30.0,
                   help="stop a download that makes no progress for this long (hung read)")
    p.add_argument("--plain", action="store_true", help="plain lines even on a terminal")
    p.add_argument("--static-from-store", nargs="?", const="", default=None, metavar="DIR",
                   help="apply each device's latest six-orientation static calibration from the "
                        "store (default location, or DIR) instead of the autocalibration")
    p.add_argument("--foxglove", nargs="?", type=PORT, const=8765, default=None, metavar="PORT",
                   help="serve each device live to Foxglove on ws://localhost:PORT (default 8765): "
                        "state, progress, battery, clock offset, the corrected stream while it "
                        "downloads, calibration estimates (needs the live extra)")
    add_web_arguments(p, station=True)
    add_store_arguments(p)


def add_web_arguments(p, station: bool) -> None:
    """--web, --token (and --read-only for the station): the dashboard (docs/dashboard.md)."""
    p.add_argument("--web", nargs="?", const="", default=None if station else "", metavar="[HOST:]PORT",
                   type=_web_address,
                   help="serve the web dashboard (default 127.0.0.1 and a free port, printed at "
                        "start; any other address than loopback needs the token)")
    p.add_argument("--token", default=None,
                   help="the dashboard's token (default: a new random one, printed at start)")
    if station:
        p.add_argument("--read-only", action="store_true",
                       help="the dashboard shows the station but takes no action")


def _web_address(text: str) -> str:
    import argparse
    from stillpoint.engine.station.web.access import AddressError, parse_address
    try:
        parse_address(text)
    except AddressError as e:
        raise argparse.ArgumentTypeError(str(e)) from None
    return text


def start_dashboard(args, folder, station=None):
    """The dashboard of ``folder`` (live with ``station``) started; prints its address."""
    from stillpoint.engine.station.web import Dashboard
    from stillpoint.engine.station.web.access import parse_address
    host, port = parse_address(args.web)
    dash = Dashboard(folder, station, host=host, port=port, token=args.token,
                     read_only=getattr(args, "read_only", False))
    url = dash.start()
    print(f"dashboard: {url}?token={dash.token}"
          + (" (read-only)" if dash.read_only else "")
          + ("" if dash.loopback else " (not loopback: the token is needed to see it)"), flush=True)
    return dash


def add_store_arguments(p) -> None:
    """``--store DIR`` / ``--no-store`` (``station`` and ``device download``)."""
    g = p.add_mutually_exclusive_group()
    g.add_argument("--store", default="", metavar="DIR",
                   help="calibration store (default: $STILLPOINT_HOME or ~/.local/share/stillpoint): "
                        "each download is corrected from its first sample with the device's latest "
                        "good estimate there (online refits still every 12 h), and its final "
                        "estimate is added to it")
    g.add_argument("--no-store", dest="store", action="store_const", const=None,
                   help="neither read nor write a calibration store (identity until the first refit)")


def run(args) -> int:
    from stillpoint.engine.station.flow import StationOptions
    from stillpoint.engine.station.profile import ProfileError, load_profile
    from stillpoint.engine.station.station import Station
    if args.write_profile is not None:
        from stillpoint.engine.station.profile import write_example_profile
        p = write_example_profile(args.write_profile)
        load_profile(p)  # what was written is a profile the station accepts
        print(f"example study profile written to {p}: edit it for the study, then `stillpoint "
              f"station OUTDIR --profile {p}`", flush=True)
        return 0
    if args.outdir is None:
        raise ProfileError("an output folder is needed: `stillpoint station OUTDIR` (or "
                           "--write-profile FILE to write the example study profile)")
    if args.foxglove is not None:  # the extra is checked before anything is touched
        from stillpoint.engine.live.sdk import load
        load("--foxglove")
    prof = load_profile(args.profile) if args.profile else None
    clear = args.clear_after_verify if args.clear_after_verify is not None else bool(prof and prof.clear_after_verify)
    configure = args.configure_after if args.configure_after is not None else bool(prof and prof.configure_after)
    if configure and prof is None:
        raise ProfileError("--configure-after needs --profile study.toml (what to configure)")
    erase = args.erase or (prof.erase if prof else "quick")
    opts = StationOptions(str(args.outdir), profile=prof, clear_after_verify=clear,
                          configure_after=configure, stall_s=args.stall_s, erase=erase,
                          static_from_store=args.static_from_store, store=args.store,
                          reconfigure=args.reconfigure)
    inbox = None
    if args.inbox:
        from stillpoint.engine.station.inbox import Inbox
        inbox = Inbox(args.inbox, args.outdir)
    stop = threading.Event()

    def on_signal(signum, frame):
        stop.set()

    old = signal.signal(signal.SIGINT, on_signal)
    old_term = signal.signal(signal.SIGTERM, on_signal)
    try:
        with Station(opts, tty=False if args.plain else None, inbox=inbox) as st:
            if inbox is not None:
                inbox.ledger = st.ledger
            dash = start_dashboard(args, args.outdir, st) if args.web is not None else None
            live = None
            try:
                if args.foxglove is not None:
                    from stillpoint.engine.live.station import StationLive
                    live = StationLive(args.outdir, port=args.foxglove)
                    st.add_listener(live.on_change)
                    print(f"foxglove: ws://127.0.0.1:{live.port}", flush=True)
                if not (st.tty):
                    print(f"station on {args.outdir} (ledger {st.ledger.path}); clear after verify: "
                          f"{'yes' if clear else 'no'}; configure: {'yes' if configure else 'no'}; Ctrl-C stops",
                          flush=True)
                rc = st.run(once=args.once, stop=stop)
            finally:
                if dash is not None:
                    dash.close()
                if live is not None:
                    live.close()
            if stop.is_set():
                print("station stopped; partial downloads are kept and resume next time", file=sys.stderr)
    finally:
        signal.signal(signal.SIGINT, old)
        signal.signal(signal.SIGTERM, old_term)
    return rc
