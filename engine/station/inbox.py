"""The inbox: recordings dropped in a folder, ingested through the same correction and ledger path.

GENEActiv devices have no public USB protocol (usb-protocols.md Part B), so the station never
talks to them: the vendor software extracts ``.bin`` files into a folder, and ``.cwa`` files can
be dropped there too. ``Inbox(folder, out_dir)`` ingests each file once its size and mtime have
been stable for ``stable_s``, under the name ``<type>-<device>_<stem>`` (``<type>``: GENEActiv,
AX3, AX6, since a GENEActiv serial can equal an AX id; ``<device>``: the header's free-text
serial; ``<stem>``: the file's; each part through ``drivers.names.safe_name_part``, so a serial
such as ``../x`` or ``/tmp/x`` names a file inside ``<out>``, never a path): the raw copy with
its SHA-256, written to ``<name>.<ext>.part`` and fsynced, and the online pipeline's log
``<name>.unverified.mcap``. The ledger then completes them as it completes a download
(``completion.complete``: row ``completing``, the renames to ``<name>.<ext>`` and
``<name>.mcap``, row ``verified``), so a station killed in between leaves what
``completion.reconcile`` resolves at the next start, never an output without its ledger row.
Completeness is checked from the reader's QC: a page count that disagrees with the header,
sequence gaps, a last page cut inside its data line make the record ``error`` (the outputs are
kept under their names, not verified). Each file is ingested once (its SHA-256 is remembered in
the ledger).
"""

from __future__ import annotations

import hashlib
import os
import threading
import time
from pathlib import Path
from typing import Optional

from stillpoint.drivers.byteio import sha256_file
from stillpoint.drivers.names import safe_child, safe_name_part
from stillpoint.engine.core.outputs import AtomicOutput, describe_os_error, fsync_folder

from .completion import complete, part_of, place_log, place_raw, unverified_log_of

INCOMPLETE = ("page_count_mismatch", "sequence_gap", "truncated_page", "truncated",
              "restart")
SUFFIXES = (".bin", ".cwa")


class Inbox:
    def __init__(self, folder, out_dir, *, stable_s: float = 5.0, ledger=None):
        self.folder = Path(folder)
        self.out = Path(out_dir)
        self.stable_s = stable_s
        self.ledger = ledger
        self._seen: dict[str, tuple] = {}  # path -> (size, mtime, since)
        self.done: dict[str, str] = {}  # path -> state line
        self.errors: list[str] = []
        self._busy: Optional[threading.Thread] = None
        self._queue: list[Path] = []
        from stillpoint.engine.core.outputs import OutputError
        if not self.folder.is_dir():
            raise OutputError(self.folder, "inbox folder does not exist")
        if self.out.is_dir() and os.path.samefile(self.folder, self.out):
            raise OutputError(self.folder, "the inbox cannot be the station's output folder "
                                           "(its raw copies would be ingested again)")

    def idle(self) -> bool:
        self.step()
        return not self._queue and (self._busy is None or not self._busy.is_alive()) and \
            all(str(p) in self.done for p in self._candidates())

    def _candidates(self):
        return [p for p in sorted(self.folder.iterdir())
                if p.is_file() and p.suffix.lower() in SUFFIXES and not p.name.startswith(".")]

    def step(self) -> None:
        now = time.monotonic()
        for p in self._candidates():
            key = str(p)
            if key in self.done or p in self._queue:
                continue
            try:
                st = p.stat()
            except OSError:
                continue
            sig = (st.st_size, st.st_mtime_ns)
            old = self._seen.get(key)
            if old is None or old[:2] != sig:
                self._seen[key] = (*sig, now)
            elif now - old[2] >= self.stable_s and st.st_size > 0:
                self._queue.append(p)
        if self._queue and (self._busy is None or not self._busy.is_alive()):
            p = self._queue.pop(0)
            self.done[str(p)] = "ingesting"
            self._busy = threading.Thread(target=self._ingest_safe, args=(p,), daemon=True)
            self._busy.start()

    def lines(self) -> list[str]:
        return [f"inbox      {Path(k).name}: {v}" for k, v in self.done.items()]

    def _ingest_safe(self, p: Path) -> None:
        try:
            self.done[str(p)] = self.ingest(p)
        except Exception as e:  # noqa: BLE001 - one file's problem never stops the station
            msg = f"error: {getattr(e, 'reason', None) or e}"
            self.done[str(p)] = msg
            self.errors.append(f"{p}: {msg}")
        print(f"{time.strftime('%H:%M:%S')} inbox {p.name}: {self.done[str(p)]}", flush=True)

    def ingest(self, p: Path) -> str:
        from stillpoint.engine.recordings import open_recording
        from stillpoint.engine.run import RunSettings, process_file
        src = open_recording(p)
        info = src.info
        src.close()
        dev = str(info.device_id or "unknown")
        session = info.session_id if info.session_id is not None else 0
        # the device type is part of the name: a GENEActiv serial and an AX3/AX6 id can be equal
        stem = (f"{safe_name_part(info.device_type)}-{safe_name_part(dev)}_"
                f"{safe_name_part(p.stem, fallback='recording')}")
        raw_out = safe_child(self.out, f"{stem}{p.suffix.lower()}")
        mcap_out = safe_child(self.out, f"{stem}.mcap")
        if raw_out.exists():
            return f"already ingested as {raw_out.name}"
        if self.ledger is not None:  # the same bytes under another name
            done = self.ledger.verified_by_sha256(sha256_file(p))
            if done is not None:
                return f"already ingested as {Path(done.cwa_path).name} (same SHA-256)"
        dl = None
        dev_id = int(dev) if dev.isascii() and dev.isdigit() and len(dev) <= 18 else -1
        if self.ledger is not None:
            dl = self.ledger.download_started(dev_id, int(session), cwa_path=str(raw_out),
                                              mcap_path=str(mcap_out), device_type=info.device_type)
        ao = None
        try:
            ao = AtomicOutput(raw_out, what="raw copy")  # <name>.part: links and leftovers handled
            h = hashlib.sha256()
            n = 0
            try:
                with open(p, "rb") as f:
                    while True:
                        b = f.read(1 << 20)
                        if not b:
                            break
                        ao.file.write(b)
                        h.update(b)
                        n += len(b)
                ao.file.flush()
                os.fsync(ao.fd)
            except OSError as e:
                raise OSError(e.errno, f"copying {p}: {describe_os_error(e)}") from None
            sha = h.hexdigest()
            log = unverified_log_of(mcap_out)
            summary = process_file(p, log, RunSettings(mode="online"),
                                   metadata={"station": {"inbox_file": str(p), "sha256": sha}})
            reasons = (summary.get("qc") or {}).get("reasons", {})
            bad = {k: v for k, v in reasons.items() if k in INCOMPLETE}
            if self.ledger is not None and not bad:  # the ledger completes it, as a download
                complete(self.ledger, dl, cwa_path=raw_out, mcap_path=mcap_out, sha256=sha,
                         bytes_=n, bad_sectors=0,
                         summary={"calibration": summary.get("calibration")})
            else:  # outputs kept under their names, not verified
                place_raw(part_of(raw_out), raw_out, sha)
                place_log(log, mcap_out)
                fsync_folder(self.out)
            if bad:
                why = "incomplete: " + ", ".join(f"{k} x{v}" for k, v in bad.items())
                if self.ledger is not None:
                    self.ledger.download_failed(dl, why + "; outputs kept", n)
                self.errors.append(f"{p}: {why}")
                return f"error: {why} (outputs kept: {raw_out.name}, {mcap_out.name})"
            cal = (summary.get("calibration") or {}).get("status", "-")
            return f"ingested -> {raw_out.name}, {mcap_out.name} (calibration {cal})"
        except BaseException as e:
            if self.ledger is not None and dl is not None:
                self.ledger.download_failed(dl, str(getattr(e, "reason", None) or e))
            raise
        finally:
            if ao is not None:
                ao.abandon(remove_if_empty=False)  # our handle; the file has its name or stays .part
