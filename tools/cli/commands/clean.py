"""`stillpoint clean OUT [--delete]`: list the partial files in a station output folder that a
verified output supersedes, and remove them only when asked.

A partial file (``<name>.part``, or one set aside as ``<name>.part.<UTC>[-n]``) is superseded when
``<name>`` (for a corrected log: the raw copy of the same download) is a verified download in the
folder's ledger, the file of that name is there and its SHA-256 is the ledger's, and, for a partial
raw copy, every byte it holds is the verified copy's (it is a prefix of it). Any other partial file
is listed as kept with the reason (it may hold the only copy of some bytes). Without ``--delete``
nothing is removed; with it, only superseded files are, while no station uses the folder.
"""

from __future__ import annotations

import os
from pathlib import Path

from stillpoint.engine.core.errors import StillpointError

NAME = "clean"
HELP = "list (and with --delete remove) partial files a verified station output supersedes"


def add_arguments(p) -> None:
    p.add_argument("outdir", type=Path, help="a station output folder (holds the ledger)")
    p.add_argument("--delete", action="store_true", help="remove the superseded partial files")


class CleanError(StillpointError):
    pass


def _target(name: str):
    """(output the partial file would have become, is it a raw copy) or None."""
    from stillpoint.engine.station import names
    m = names.SET_ASIDE_RE.match(name)
    base = m.group("name") if m else (name[: -len(names.PART)] if name.endswith(names.PART) else None)
    if base is None:
        if name.endswith(names.UNVERIFIED_LOG):  # a finished log of an unverified copy
            base = name
        else:
            return None
    if base.endswith(names.UNVERIFIED_LOG):
        base = base[: -len(names.UNVERIFIED_LOG)] + names.LOG
    return base, not base.endswith(names.LOG)


def _is_prefix(part: Path, whole: Path) -> bool:
    if part.stat().st_size > whole.stat().st_size:
        return False
    with open(part, "rb") as a, open(whole, "rb") as b:
        while True:
            x = a.read(1 << 20)
            if not x:
                return True
            if b.read(len(x)) != x:
                return False


def survey(out: Path, ledger) -> list[tuple[str, str, str]]:
    """(name, "superseded"|"kept", why) for every partial file in ``out``."""
    from stillpoint.drivers.byteio import sha256_file
    from stillpoint.engine.station import names
    verified = {}  # raw copy name -> record
    raw_of_log = {}  # corrected log name -> its raw copy's name (.cwa, or an inbox's .bin)
    for rec in ledger.downloads():
        if rec.verified and rec.state == "verified" and rec.cwa_path:
            verified[Path(rec.cwa_path).name] = rec
            if rec.mcap_path:
                raw_of_log[Path(rec.mcap_path).name] = Path(rec.cwa_path).name
    good: dict[str, bool] = {}  # raw copy name -> its SHA-256 is the ledger's

    def raw_ok(raw: str) -> bool:
        if raw not in good:
            rec = verified.get(raw)
            p = out / raw
            good[raw] = rec is not None and p.is_file() and not p.is_symlink() and \
                sha256_file(p) == rec.sha256
        return good[raw]

    rows = []
    for name in sorted(os.listdir(out)):
        p = out / name
        t = _target(name)
        if t is None or p.is_symlink() or not p.is_file():
            continue
        base, is_raw = t
        raw = base if is_raw else raw_of_log.get(base, base[: -len(names.LOG)] + names.RAW)
        if not raw_ok(raw):
            why = (f"{raw} is not a verified copy in the ledger" if raw not in verified else
                   f"{raw} is missing or no longer matches the ledger's SHA-256")
            rows.append((name, "kept", why))
        elif is_raw and not _is_prefix(p, out / raw):
            rows.append((name, "kept", f"holds bytes that {raw} does not (check it before removing)"))
        elif not is_raw and not (out / base).is_file():
            rows.append((name, "kept", f"{base} is not there"))
        else:
            rows.append((name, "superseded", f"by {base if not is_raw else raw}"))
    return rows


def run(args) -> int:
    from stillpoint.engine.core.outputs import check_output_folder
    from stillpoint.engine.station.ledger import LEDGER_NAME, Ledger, acquire_station_lock
    out = check_output_folder(args.outdir, what="station output folder")
    if not (out / LEDGER_NAME).is_file():
        raise CleanError(f"{out}: no station ledger ({LEDGER_NAME}) here: nothing is known to be "
                         "verified, nothing is removed")
    lock = acquire_station_lock(out) if args.delete else None  # no station may run meanwhile
    ledger = Ledger(out)
    try:
        rows = survey(out, ledger)
        removed = 0
        freed = 0
        for name, verdict, why in rows:
            action = verdict
            if verdict == "superseded" and args.delete:
                size = (out / name).stat().st_size
                os.unlink(out / name)
                removed += 1
                freed += size
                action = "removed"
            print(f"{action:<10} {name}  ({why})")
        n_sup = sum(1 for r in rows if r[1] == "superseded")
        if args.delete:
            print(f"{removed} file(s) removed ({freed / 1e6:.1f} MB); "
                  f"{len(rows) - n_sup} kept")
        else:
            print(f"{n_sup} superseded, {len(rows) - n_sup} kept; nothing removed "
                  "(--delete removes the superseded ones)")
    finally:
        ledger.close()
        if lock is not None:
            os.close(lock)
    return 0
