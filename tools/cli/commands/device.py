"""`stillpoint device ACTION [ID]`: one device at a time (download, verify, clear, configure,
sync-time, stream) and `device emulate` (emulated AX3/AX6 devices for trying the station)."""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

from stillpoint.drivers import constants as C
from stillpoint.engine.core.errors import StillpointError

from ._numbers import DAYS, EMULATED_ID, MB_PER_S, PORT, SECONDS_DAY, SECONDS_YEAR, number

NAME = "device"
HELP = "act on one attached AX3/AX6 (download, verify, clear, configure, sync-time, stream) or emulate devices"


def add_arguments(p) -> None:
    sub = p.add_subparsers(dest="action", metavar="ACTION", required=True)

    def dev(name, help_):
        s = sub.add_parser(name, help=help_, description=help_)
        s.add_argument("id", nargs="?", default=None,
                       help="device id or USB serial (optional when one device is attached)")
        s.add_argument("--port", default=None, help="serial port (manual override)")
        s.add_argument("--volume", default=None, help="the device's drive (manual override)")
        return s

    s = dev("download", "verified download + corrected MCAP into OUTDIR (the device is not cleared)")
    s.add_argument("-o", "--output", type=Path, required=True, help="output folder (holds the ledger)")
    s.add_argument("--stall-s", type=SECONDS_DAY, default=30.0,
                   help="stop a download without progress this long")
    from .station import add_store_arguments
    add_store_arguments(s)
    s = dev("verify", "re-read the device (bypassing the cache) and the raw copy on disk and compare "
                      "both with the ledger's verified download")
    s.add_argument("-o", "--output", type=Path, required=True, help="the station output folder")
    s = dev("clear", "clear the device: only if the device, the raw copy in OUTDIR and its ledger's "
                     "verified download hold the same bytes")
    s.add_argument("-o", "--output", type=Path, required=True, help="the station output folder")
    s.add_argument("--erase", choices=("quick", "wipe"), default="quick",
                   help="quick (FORMAT QC, default) or wipe (FORMAT WC: the memory wiped too; slower)")
    s = dev("configure", "configure for the next wearer from a study profile (TOML); the device "
                         "must be cleared")
    s.add_argument("--profile", type=Path, required=True)
    s.add_argument("-o", "--output", type=Path, default=None, help="record it in this folder's ledger")
    s.add_argument("--reconfigure", action="store_true",
                   help="configure it even if a station or this command already configured it for "
                        "its current session (a new session; the printed handover sheet is "
                        "superseded)")
    dev("sync-time", "set the device clock to host local time (as OMGui does) and read it back")
    s = dev("stream", "log the STREAM preview (irregular, not analysis data) to MCAP")
    s.add_argument("-o", "--output", type=Path, required=True, help="preview MCAP")
    s.add_argument("--seconds", type=SECONDS_DAY, default=10.0)
    s.add_argument("--foxglove", nargs="?", type=PORT, const=8765, default=None, metavar="PORT",
                   help="also serve the preview live to Foxglove on ws://localhost:PORT (default "
                        "8765), corrected by the device's stored calibration (needs the live extra)")
    s = sub.add_parser("emulate", help="run emulated AX3/AX6 devices until Ctrl-C",
                       description="Run emulated devices (pseudo-terminal serial ports, a folder as "
                                   "each drive, a simulated recording) that `stillpoint devices` and "
                                   "`stillpoint station` in another terminal find with no flags.")
    s.add_argument("--count", type=number(1, 100, integer=True), default=3)
    s.add_argument("--days", type=DAYS, default=1.0, help="simulated recording length per device")
    s.add_argument("--ax6", type=number(0, 100, integer=True), default=0,
                   help="how many of them are AX6")
    s.add_argument("--faults", default="", help="NAME[:DEVICE],... (DEVICE: 1-based index or id; "
                                                "none: every device). Names: see --list-faults")
    s.add_argument("--list-faults", action="store_true")
    s.add_argument("--dir", type=Path, default=None,
                   help="where the emulated drives live (default: a new folder in this session's "
                        "runtime folder)")
    s.add_argument("--keep", action="store_true",
                   help="leave the drives (and their recordings) on exit; by default the drives "
                        "this run made are removed when it stops, Ctrl-C included")
    s.add_argument("--session", default=None, metavar="NAME",
                   help="register the devices in this emulator session (default: the login "
                        "session); other programs see them with STILLPOINT_EMULATOR_SESSION=NAME")
    s.add_argument("--battery", type=number(0, 100, unit="%"), default=None, metavar="PCT",
                   help="battery level at plug-in (default: charged, 100 %%; the low-battery "
                        "fault: 15 %%)")
    s.add_argument("--first-id", type=EMULATED_ID, default=10001)
    s.add_argument("--read-mbps", type=MB_PER_S, default=None,
                   help="emulate the drive's USB read speed in MB/s (full speed is ~1.2); default unlimited")
    s.add_argument("--seconds", type=SECONDS_YEAR, default=None,
                   help="stop after this long (default: Ctrl-C)")


class _Err(StillpointError):
    pass


def _find(args):
    from stillpoint.drivers.ax.discovery import discover
    atts = discover(port=args.port, volume=args.volume)
    if args.id is None:
        if len(atts) != 1:
            raise _Err(f"{len(atts)} devices attached: name one (device id or serial)")
        return atts[0]
    named = [a for a in atts if args.id == a.serial] or \
        [a for a in atts if args.id == str(a.device_id)]
    if len(named) > 1:  # an AX3 and an AX6 may carry the same id
        raise _Err(f"device {args.id}: {len(named)} attached devices have this id ("
                   + ", ".join(f"{a.device_type} {a.serial}"
                               for a in sorted(named, key=lambda a: (a.device_type, a.serial)))
                   + "): name one by its USB serial")
    if not named:
        raise _Err(f"device {args.id}: not attached (see `stillpoint devices`)")
    return named[0]


def _say(msg: str) -> None:
    print(msg, flush=True)


def run(args) -> int:
    if args.action == "emulate":
        return _emulate(args)
    prof = None
    if getattr(args, "foxglove", None) is not None:  # the extra is checked before any device is touched
        from stillpoint.engine.live.sdk import load
        load("--foxglove")
    if args.action == "configure":  # every profile value checked before any device is touched
        from stillpoint.engine.station.profile import load_profile
        prof = load_profile(args.profile)
    att = _find(args)
    if args.action in ("download", "clear", "verify"):
        return _with_ledger(args, att)
    with _device_lock(att, getattr(args, "output", None)):
        return _with_port(args, att, prof)


def _device_lock(att, out):
    """The host-wide lock of the device (``engine.station.hostlock``): its port is opened only
    while no station holds it; "busy: held by the station on OUT (pid N)" otherwise."""
    from stillpoint.engine.station.hostlock import DeviceBusy, DeviceLock, key_of
    lock = DeviceLock(key_of(att), out, what="stillpoint device command")
    try:
        return lock.acquire(att.device_id)
    except DeviceBusy as e:
        raise _Err(f"device {att.device_id}: busy: {e.reason}") from None


def _with_port(args, att, prof) -> int:
    from stillpoint.drivers.ax.protocol import AxClient
    from stillpoint.engine.station import configure as cfg
    with AxClient.open(att.port, str(att.device_id)) as client:
        client.stream_stop()
        ident = client.identify()
        if ident.device_id != att.device_id:
            raise _Err(f"device {att.device_id}: ID names device {ident.device_id}")
        if args.action == "sync-time":
            before = cfg.clock_offset_s(client)
            after = cfg.sync_time(client)
            _say(f"device {att.device_id}: clock offset {before:+.3f} s -> {after:+.3f} s (host local time)")
            return 0
        if args.action == "stream":
            from stillpoint.engine.station.preview import PREVIEW_SCHEMA, stream_preview
            live = None
            if args.foxglove is not None:
                from stillpoint.engine.live.preview import PreviewLive, stored_calibration
                key = f"{att.device_type}-{att.device_id}"
                cal = stored_calibration(key)
                live = PreviewLive(key, PREVIEW_SCHEMA.encode(), port=args.foxglove, calibration=cal)
                _say(f"foxglove: ws://127.0.0.1:{live.port} (preview of {key}; "
                     + (f"corrected by the stored {cal.method} calibration)" if cal is not None
                        else "no stored calibration: uncorrected)"))
            try:
                r = stream_preview(client, args.output, args.seconds, att.device_type,
                                   report=lambda m: print(m, file=sys.stderr, flush=True),
                                   on_reading=live.on_reading if live is not None else None)
            finally:
                if live is not None:
                    live.close()
            _say(f"device {att.device_id}: {r['readings']} preview readings at {r['rate_hz']} Hz -> "
                 f"{r['output']} (preview only, not analysis data)")
            return 0
        if args.action == "configure":
            prof.check_device(ident.device_type)
            ledger = None
            session_now = ident.session_id
            if args.output:
                from stillpoint.engine.station.ledger import Ledger, check_station_folder
                ledger = Ledger(check_station_folder(args.output))
                from stillpoint.engine.station.clearing import session_before_clear
                session_now = session_before_clear(ledger, att.device_id, session_now,
                                                   att.device_type)
            before = _configured_before(att, ident.session_id, ledger)
            if before is not None and not args.reconfigure:
                raise _Err(f"device {att.device_id}: {before}; not configured again: add "
                           f"--reconfigure to configure it anew (session "
                           f"{prof.session_for(session_now)}; its handover sheet is superseded)")
            flow_wait = _volume_waiter(att)
            settings, warnings = cfg.configure_device(client, prof, data_file=att.data_file,
                                                      wait_volume=flow_wait, session_now=session_now)
            if ledger is not None:
                ledger.configured(att.device_id, settings["session"], settings, "ok",
                                  "; ".join(warnings) or None, device_type=att.device_type)
                ledger.close()
            from stillpoint.engine.station import hostlock as H
            H.record_configured(H.key_of(att), settings["session"], args.output,
                                start=settings.get("start"), stop=settings.get("stop"))
            for w in warnings:
                print(f"warning: device {att.device_id}: {w}", file=sys.stderr)
            _say(f"device {att.device_id}: configured session {settings['session']}, rate "
                 f"{settings['rate_hz']:g} Hz +-{settings['range_g']} g, start {settings['start']}, "
                 f"stop {settings['stop']}")
            return 0
    raise _Err(f"unknown action {args.action}")


def _configured_before(att, session: int, ledger):
    """Why the device counts as configured for ``session`` already (the host-wide record, or
    this folder's ledger with no clear since), or None."""
    from stillpoint.engine.station import hostlock as H
    rec = H.configured_record(H.key_of(att))
    if rec is not None and rec.get("session") == session:
        return f"already configured for session {session} by {H.holder_text(rec)} at " \
               f"{rec.get('time_utc', '?')}"
    if ledger is not None and ledger.configured_since_clear(att.device_id, session,
                                                            att.device_type) is not None:
        return f"already configured for session {session} (the ledger {ledger.path})"
    return None


def _volume_waiter(att):
    from stillpoint.engine.station.flow import DeviceFlow, StationOptions
    f = DeviceFlow(att, StationOptions("."), ledger=None)
    return f.wait_volume


def _with_ledger(args, att) -> int:
    from stillpoint.engine.station.flow import DeviceFlow, StationOptions
    from stillpoint.engine.station.ledger import Ledger, acquire_station_lock, check_station_folder
    out = check_station_folder(args.output)
    fd = acquire_station_lock(out)
    try:
        # verify and clear hold the device's host-wide lock; a download's flow takes it itself
        lock = _device_lock(att, out) if args.action != "download" else None
    except BaseException:
        os.close(fd)
        raise
    ledger = Ledger(out)
    from stillpoint.engine.station.completion import reconcile
    for line in reconcile(ledger):  # what a killed station or download left between two states
        print(f"ledger: {line}", file=sys.stderr)
    # the device's flow: a download runs it; verify and clear use its bounded re-read and its
    # wait for the drive
    flow = DeviceFlow(att, StationOptions(str(out), stall_s=getattr(args, "stall_s", 30.0),
                                          store=getattr(args, "store", None),
                                          wait_when_busy=False), ledger,
                      on_change=_progress_printer())
    try:
        if args.action == "download":
            try:
                flow.run()
            except KeyboardInterrupt:
                flow.stop()
                raise
            print(file=sys.stderr) if sys.stderr.isatty() else None
            if flow.state == "error":
                print(f"stillpoint device download: error: device {att.device_id}: {flow.reason}",
                      file=sys.stderr)
                return 2
            r = flow.result
            _say(f"device {att.device_id}: {flow.state}: {flow.reason or flow.info}"
                 + (f" -> {r.cwa_path}, {r.mcap_path}" if r is not None else ""))
            if flow.outputs:
                _say(f"device {att.device_id}: outputs: {flow.outputs}")
            return 0
        if args.action == "verify":
            return _verify(att, ledger, flow.reread)
        if args.action == "clear":
            from stillpoint.drivers.ax.protocol import AxClient
            from stillpoint.engine.station.clearing import clear_verified
            with AxClient.open(att.port, str(att.device_id)) as client:
                client.stream_stop()
                session = client.session()
                clear_verified(client, ledger, att.device_id, session, att.data_file, flow.wait_volume,
                               device_type=att.device_type, erase=args.erase, reread=flow.reread)
            _say(f"device {att.device_id}: cleared by {C.AX_ERASE_COMMANDS[args.erase]}; it will not "
                 f"record until configured (session {session}: device, raw copy and {ledger.path} "
                 "held the same bytes)")
            settled = _settle_host_records(att, session)
            if settled:
                _say(f"device {att.device_id}: {settled}")
            return 0
    finally:
        ledger.close()
        if lock is not None:
            lock.release()
        os.close(fd)
    return 0


def _settle_host_records(att, session: int):
    """A person cleared the device: the host-wide ``changed`` verdict and configuration record of
    it are settled (``engine.station.hostlock``); what was settled, in words."""
    from stillpoint.engine.station import hostlock as H
    key = H.key_of(att)
    rec = H.changed_record(key)
    H.forget_changed(key)
    H.forget_configured(key)
    if rec is None:
        return None
    return (f"the host-wide verdict of {H.holder_text(rec)} (its data changed between two reads "
            f"of session {rec.get('session')}) is settled by this clear")


def _progress_printer():
    last = [None, 0.0]

    def show(flow):
        if flow.state != last[0]:
            last[0] = flow.state
            print(f"device {flow.att.device_id}: {flow.state}" + (f": {flow.reason}" if flow.reason and
                                                                 flow.state != "error" else ""),
                  file=sys.stderr, flush=True)
        elif sys.stderr.isatty() and time.monotonic() - last[1] > 0.5 and flow.total_bytes:
            last[1] = time.monotonic()
            pct = 100.0 * flow.done_bytes / flow.total_bytes
            print(f"\r  {pct:5.1f} %  {flow.done_bytes / 1e6:8.1f} MB  "
                  f"{(flow.mbps or 0):5.2f} MB/s", end="", file=sys.stderr, flush=True)
    return show


def _verify(att, ledger, reread) -> int:
    """Device, raw copy and ledger: the three must hold the same bytes (size and SHA-256).
    ``reread``: the device re-read as before a clear (a worker with the stall bound)."""
    from stillpoint.drivers.ax.protocol import AxClient
    from stillpoint.engine.station.clearing import copy_sha256
    with AxClient.open(att.port, str(att.device_id)) as client:
        client.stream_stop()
        session = client.session()
    rec = ledger.verified_download(att.device_id, session, device_type=att.device_type)
    if rec is None:
        raise _Err(f"device {att.device_id}: the ledger {ledger.path} holds no verified download of "
                   f"session {session}")
    try:
        cn, csha = copy_sha256(rec.cwa_path)
    except OSError as e:
        raise _Err(f"device {att.device_id}: cannot read the raw copy {rec.cwa_path}: "
                   f"{e.strerror or e}") from None
    try:
        d = reread(att.data_file)
        n, sha = d.bytes, d.sha256
    except OSError as e:
        raise _Err(f"device {att.device_id}: cannot read the data file {att.data_file}: "
                   f"{e.strerror or e}") from None
    want = f"the ledger's verified download ({rec.bytes} bytes, SHA-256 {(rec.sha256 or '')[:16]})"
    if cn != rec.bytes or csha != rec.sha256:
        raise _Err(f"device {att.device_id}: the raw copy {rec.cwa_path} ({cn} bytes, SHA-256 "
                   f"{csha[:16]}) differs from {want}; the device is not to be cleared")
    if n != rec.bytes or sha != rec.sha256:
        raise _Err(f"device {att.device_id}: the device file ({n} bytes, SHA-256 {sha[:16]}) differs "
                   f"from {want} and its copy {rec.cwa_path}")
    _say(f"device {att.device_id}: session {session} matches the verified copy {rec.cwa_path}: the "
         f"device, the copy and the ledger hold the same {n} bytes (SHA-256 {rec.sha256[:16]}...)")
    return 0


def _parse_faults(text: str, ids: list[int]) -> dict:
    from stillpoint.drivers.ax.emulator import FAULTS
    out = {i: set() for i in ids}
    for item in [t.strip() for t in text.split(",") if t.strip()]:
        name, _, target = item.partition(":")
        if name not in FAULTS:
            raise _Err(f"unknown fault {name!r}; known: {', '.join(FAULTS)}")
        if not target:
            for i in ids:
                out[i].add(name)
            continue
        if not target.isdigit():
            raise _Err(f"fault {item!r}: DEVICE must be a 1-based index or a device id")
        t = int(target)
        dev = ids[t - 1] if 1 <= t <= len(ids) else t
        if dev not in out:
            raise _Err(f"fault {item!r}: no emulated device {target}")
        out[dev].add(name)
    return out


def _emulate(args) -> int:
    from stillpoint.drivers.ax import registry
    from stillpoint.drivers.ax.emulator import FAULTS, EmulatedDevice
    from stillpoint.engine.sim.record import device_recording
    if args.list_faults:
        for k, v in FAULTS.items():
            print(f"{k:<22} {v}")
        return 0
    if args.count < 1 or args.ax6 < 0 or args.ax6 > args.count:
        raise _Err("--count must be >= 1 and --ax6 between 0 and --count")
    if args.first_id + args.count - 1 > EMULATED_ID.hi:
        raise _Err(f"--first-id {args.first_id} with --count {args.count}: an emulated device's id "
                   f"is at most {EMULATED_ID.hi} (7 digits in its drive label)")
    ids = [args.first_id + i for i in range(args.count)]
    faults = _parse_faults(args.faults, ids)
    if args.session is not None:
        os.environ[registry.SESSION_ENV] = args.session
    session = registry.session_name()  # a bad name: one line, before any device is made
    if args.dir is not None:
        root = args.dir
    else:
        import tempfile
        base = registry.session_dir()
        base.mkdir(parents=True, exist_ok=True)
        root = Path(tempfile.mkdtemp(prefix="emulated-", dir=base))
    made = [root / str(i) for i in ids if not (root / str(i)).exists()]  # removed at exit
    devs = []
    stop, restore = _stop_on_signals()
    try:
        for k, dev_id in enumerate(ids):
            if stop.is_set():
                break
            kind = "AX6" if k >= args.count - args.ax6 else "AX3"
            print(f"simulating {kind} {dev_id}: {args.days:g} days ...", file=sys.stderr, flush=True)
            d = EmulatedDevice(root / str(dev_id), dev_id, kind, make_recording=device_recording,
                               days=args.days, seed=k + 1,
                               faults=sorted(faults[dev_id]), slot=f"emu-{k + 1}", remount_s=1.0,
                               read_bps=args.read_mbps * 1e6 if args.read_mbps else None,
                               battery_pct=args.battery)
            devs.append(d)
            d.plug(pty=True)
            print(f"{kind} {dev_id} on {d.pty_path}, drive {d.volume}"
                  + (f", faults {', '.join(sorted(d.faults))}" if d.faults else ""), flush=True)
        print(f"{len(devs)} emulated device(s) attached in session {session!r}; run `stillpoint "
              "devices` or `stillpoint station OUTDIR` in another terminal"
              + (f" with STILLPOINT_EMULATOR_SESSION={session}" if args.session else "")
              + "; Ctrl-C to stop", flush=True)
        end = None if args.seconds is None else time.monotonic() + args.seconds
        seen = {d.serial: list(d.events) for d in devs}
        while (end is None or time.monotonic() < end) and not stop.is_set():
            stop.wait(0.2)
            for d in devs:
                new = d.events[len(seen.get(d.serial, [])):]
                for e in new:
                    print(f"{time.strftime('%H:%M:%S')} {d.kind} {d.device_id}: {e}", flush=True)
                seen[d.serial] = list(d.events)
    except KeyboardInterrupt:
        stop.set()
    finally:
        if stop.is_set():
            print("stopping the emulated devices", file=sys.stderr)
        for d in devs:
            d.shutdown()
        _remove_drives(root, made, keep=args.keep, default_root=args.dir is None)
        restore()
    return 0


def _stop_on_signals():
    """An event set by SIGINT (Ctrl-C), SIGTERM and SIGHUP (the terminal closed), so that the
    emulator always reaches its clean-up; and the function that puts the handlers back."""
    import signal
    import threading
    stop = threading.Event()
    old = {}

    def on_signal(signum, frame):
        stop.set()
    for name in ("SIGINT", "SIGTERM", "SIGHUP"):
        sig = getattr(signal, name, None)
        if sig is not None:
            try:
                old[sig] = signal.signal(sig, on_signal)
            except ValueError:  # not the main thread: Ctrl-C stays a KeyboardInterrupt
                pass

    def restore():
        for sig, handler in old.items():
            signal.signal(sig, handler)
    return stop, restore


def _remove_drives(root: Path, made: list, *, keep: bool, default_root: bool) -> None:
    """The drives this run made are removed (``--keep``: left, and said where); a folder that
    was there before (an earlier ``--keep``) is never removed."""
    import shutil
    if keep:
        print(f"the emulated drives are kept in {root}", file=sys.stderr)
        return
    for p in made:
        shutil.rmtree(p, ignore_errors=True)
    if default_root:
        try:
            root.rmdir()  # the run's own folder, empty now
        except OSError:
            pass
