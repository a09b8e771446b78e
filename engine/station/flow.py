"""One device through the station's states (``DeviceFlow.run`` on its own thread).

States: [``busy`` ->] ``identifying`` -> ``empty`` (nothing recorded) | ``downloading`` -> ``verifying`` ->
``verified`` -> [``clearing`` -> ``cleared``] -> [``configuring`` -> ``configured``]; or ``error``
(with the reason) from any state. Every state change is one ledger transaction (``events``).

* busy: another station of this computer holds the device's host-wide lock (``hostlock``):
  "held by the station on OUT (pid N)"; nothing is touched until it is free. The lock is held from
  identifying to the end of configuring, and the serial port is opened only under it.
* identifying: a preview left streaming is stopped; ``ID`` must name the device id and type
  the USB serial says; clock offset, battery and session are read; a clear of this device a
  killed station left at ``sent`` is settled from the device (``completion.resolve_sent_clear``).
* downloading/verifying: in a worker process with the stall bound (``worker``,
  ``download.run_download``); the ledger completes the download (``completion.complete``: row
  ``completing``, the renames, row ``verified``). A session the ledger already holds verified,
  with the device's size, is not downloaded again (``verified``, "already downloaded"). An
  unplug during the copy ends in ``error`` ("... resumes when it comes back"): when the same
  device and session return, the download resumes from the verified prefix of the partial copy.
* clearing (``--clear-after-verify``): the same byte rule whether this run downloaded the data
  or the ledger already held it (``clearing.clear_verified``; the device re-read in a worker with
  the stall bound, ``reread``); a device whose data changed between two reads of one session (a
  ``changed`` download, in this ledger or in the host-wide record any station of the computer
  wrote) is never cleared here. A profile the device cannot record is refused before the clear.
* configuring (``--configure-after`` with a profile): a cleared or empty device, from the profile
  (``configure.configure_device``; "increment" counts from the session its last clear erased). An
  empty device that a station of this computer already configured for its current session (no
  clear since) is left ``configured`` unless ``reconfigure`` asks for it (never silently).
* The verification's repairs (ranges re-read, ranges patched) go to the download row, a
  ``repaired`` event and the state line.

The calibration prior: with a calibration store (``StationOptions.store``), the log is corrected
from its first sample with the device's latest good estimate in the store (the online refits
still follow every 12 h), and the verified download's final estimate is added to the store; the
ledger's download row and the log's ``station`` record say which prior was used.

The analysis products (``products``): once a download is verified (or found verified without
them), its epoch, day and nights tables and its report are made in a worker process while the
flow goes on to clear and configure; the flow finishes when they are done. They are computed
with the recording's final calibration estimate (or the store prior the online trust rule kept)
applied from the first sample, not with what the live log applied (``products``). The log and
the products are in the zone of ``station_timezone``. Each product's result is a
ledger row; a product that fails never un-verifies the download or holds back its clear.

After a COMMIT or an erase the drive is waited for (``wait_volume``) and, on a headless station
where nothing mounts it again, mounted by the station.
"""

from __future__ import annotations

import json
import os
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Optional

from stillpoint.drivers import constants as C
from stillpoint.drivers.ax.discovery import Attached, discover
from stillpoint.drivers.ax.errors import DeviceError, IdentityMismatch
from stillpoint.drivers.ax.protocol import AxClient
from stillpoint.engine.core.errors import StillpointError
from stillpoint.engine.core.times import iso_utc

from .clearing import clear_verified, session_before_clear
from .configure import clock_offset_s, configure_device
from . import names
from .completion import CompletionError, complete, resolve_sent_clear
from .device_read import DeviceDigest, device_digest
from .download import DownloadJob, repairs_text
from .hostlock import (DeviceBusy, DeviceLock, HostRecordError, changed_record, configured_record,
                       forget_configured, holder_text, key_of, record_changed, record_configured)
from .ledger import Ledger, host_timezone, kill_point, station_id
from .profile import StudyProfile
from .download import DownloadWorker
from .study import download_stem

@dataclass
class StationOptions:
    out_dir: str
    profile: Optional[StudyProfile] = None
    clear_after_verify: bool = False
    configure_after: bool = False
    stall_s: float = 30.0  # a download without progress this long is stopped (hung read)
    inline: bool = False  # downloads on threads instead of worker processes (tests)
    throttle_bps: Optional[float] = None
    run_settings: dict = field(default_factory=dict)
    static_from_store: Optional[str] = None  # apply the store's static calibration ("" = default store)
    erase: str = "quick"  # "quick" (FORMAT QC) | "wipe" (FORMAT WC): the clear's erase level
    store: Optional[str] = None  # calibration store: prior from it, final estimate to it ("" = default)
    products: bool = True  # the tables and report of each verified download
    reconfigure: bool = False  # configure even a device configured for its current session (asked for)
    wait_when_busy: bool = True  # another station holds the device: wait (False: an error now)
    remount_s: float = C.AX_COMMIT_REMOUNT_S
    volume_wait_s: float = C.AX_BOOTLOADER_S
    pipeline: bool = True


def station_timezone(profile: Optional[StudyProfile]) -> str:
    """The zone of a station's logs and products: the profile's ``[station] timezone``, else this
    computer's zone, whose wall-clock time the station sets the device clocks from
    (``engine.timezones.host_zone``; the ledger's ``host_time_zone`` labels it)."""
    if profile is not None and profile.timezone:
        return profile.timezone
    from stillpoint.engine.timezones import host_zone
    return host_zone().name


class DeviceFlow:
    def __init__(self, att: Attached, opts: StationOptions, ledger: Ledger, backend=None,
                 on_change: Optional[Callable[["DeviceFlow"], None]] = None):
        self.att = att
        self.opts = opts
        self.ledger = ledger
        self.backend = backend
        self.on_change = on_change or (lambda f: None)
        self.state = "attached"
        self.reason: Optional[str] = None
        self.info: str = ""
        self.session: Optional[int] = None
        self.done_bytes = 0
        self.total_bytes = 0
        self.mbps: Optional[float] = None
        self.battery_pct: Optional[int] = None  # read when identified
        self.clock_offset_s: Optional[float] = None  # device clock minus host local time
        self.result = None
        self.detached = False
        self.worker: Optional[DownloadWorker] = None
        self.products_worker = None  # the tables and report of the verified download
        self.outputs: Optional[str] = None  # what became of them (one phrase, when done)
        self._products_for: Optional[tuple] = None  # (download id, log path)
        self._store_note: Optional[dict] = None  # the calibration store entry's product row
        self._prior = None  # the store estimate the log started from
        self.lock: Optional[DeviceLock] = None  # the host-wide device lock, while held
        self.configured_session: Optional[int] = None  # the session it is configured for (found or set)
        self.cancel = threading.Event()
        self.finished = threading.Event()
        self.thread = threading.Thread(target=self.run, daemon=True, name=f"flow-{att.serial}")

    # ------------------------------------------------------------------ state
    def _set(self, state: str, reason: Optional[str] = None) -> None:
        self.state, self.reason = state, reason
        try:
            self.ledger.event(self.att.device_id, self.att.serial, state, reason)
        except StillpointError:
            pass
        self.on_change(self)

    def start(self) -> "DeviceFlow":
        self.thread.start()
        return self

    def run(self) -> None:
        try:
            self._run()
        except (DeviceError, StillpointError) as e:
            self._set("error", getattr(e, "reason", None) or str(e))
        except OSError as e:
            self._set("error", f"{e.strerror or e}")
        except Exception as e:  # noqa: BLE001 - one device's bug never stops the station
            self._set("error", f"unexpected {type(e).__name__}: {e}")
        finally:
            if self.worker is not None and not self.worker.finished:
                self.worker.cancel()
            try:
                self._finish_products()
            except Exception as e:  # noqa: BLE001 - a product never changes the device's state
                self.outputs = f"failed: {type(e).__name__}: {e}"
            self.finished.set()
            self.on_change(self)  # views learn that the flow (products included) has ended

    def stop(self) -> None:
        self.cancel.set()
        if self.worker is not None and not self.worker.finished:
            self.worker.cancel()
        if self.products_worker is not None and not self.products_worker.finished:
            self.products_worker.cancel()

    # ------------------------------------------------------------------ products
    def _start_products(self, download_id: int, mcap_path: Optional[str]) -> None:
        """The tables and report of a verified download, in a worker (module docstring)."""
        if not self.opts.products or self.ledger is None:
            return
        if not mcap_path:
            self.ledger.product(download_id, "tables", None, "skipped",
                                "no corrected log for this download")
            return
        from .products import make_products
        from .worker import Worker
        self._products_for = (download_id, mcap_path)
        self.products_worker = Worker(make_products, {"mcap": mcap_path}, inline=self.opts.inline,
                                      stall_s=max(self.opts.stall_s, 120.0), what="products",
                                      name=f"products-{Path(mcap_path).stem}").start()

    def _finish_products(self) -> None:
        w = self.products_worker
        if w is None:
            return
        while not w.finished and not self.cancel.is_set():
            w.poll(0.2)
        if self.cancel.is_set():  # stopped: not recorded, made when the device comes back
            w.cancel()
            return
        download_id, mcap_path = self._products_for
        r = w.result or {}
        products = r.get("products") or [
            {"product": "tables", "path": mcap_path, "result": "failed",
             "reason": r.get("error", "no result")}]
        for p in products:
            try:
                self.ledger.product(download_id, p["product"], p.get("path"), p["result"],
                                    p.get("reason"))
            except StillpointError:
                pass
        from .products import describe
        self.outputs = describe(products + ([self._store_note] if self._store_note else []))
        self.on_change(self)

    # ------------------------------------------------------------------ calibration store
    def _store(self):
        from stillpoint.engine.calibration import CalibrationStore
        return CalibrationStore(self.opts.store or None)

    def _calibration_prior(self, settings: dict) -> dict:
        """Put the device's latest good estimate from the store into ``settings`` as the online
        prior; return what was used, for the ledger and the log."""
        key = f"{self.att.device_type}-{self.att.device_id}"
        if self.opts.static_from_store is not None:
            return {"source": "static", "device_key": key,
                    "detail": "the store's six-orientation static calibration"}
        if self.opts.store is None:
            return {"source": "none", "device_key": key,
                    "detail": "no calibration store: identity until the first refit"}
        store = self._store()
        try:
            est = store.prior_for(key)
        except StillpointError as e:
            return {"source": "none", "device_key": key, "store": str(store.dir),
                    "detail": f"the calibration store could not be read ({e}): identity until "
                              "the first refit"}
        if est is None:
            return {"source": "none", "device_key": key, "store": str(store.dir),
                    "detail": "the calibration store holds no estimate of this device: identity "
                              "until the first refit"}
        settings["prior"] = est.to_dict()
        self._prior = est
        from stillpoint.engine.calibration.store import _iso
        return {"source": "store", "device_key": key, "store": str(store.dir),
                "method": est.method, "status": est.status,
                "fitted_on": f"{_iso(est.fit_start_ns)}..{_iso(est.fit_end_ns)}",
                "error_after_mg": est.error_after_mg,
                "detail": f"the store's latest estimate of {key}"}

    def _store_final(self, summary: Optional[dict], raw_copy: str) -> Optional[dict]:
        """Add the verified download's final estimate to the store (the rule of ``process
        --store``); the product row that says what happened."""
        if self.opts.store is None or self.opts.static_from_store is not None:
            return None
        from stillpoint.engine.calibration.estimate import CalibrationEstimate
        from stillpoint.engine.calibration.outcome import store_refusal
        store = self._store()
        row = {"product": "calibration store", "path": str(store.dir)}
        try:
            est = CalibrationEstimate.from_dict(dict((summary or {}).get("calibration") or {}))
        except Exception as e:  # noqa: BLE001 - recorded, never raised
            return dict(row, result="failed", reason=f"no final estimate in the summary ({e})")
        p = self._prior
        if p is not None and (est.fit_start_ns, est.fit_end_ns, list(est.offset), list(est.scale)) \
                == (p.fit_start_ns, p.fit_end_ns, list(p.offset), list(p.scale)):
            return dict(row, result="kept", reason="no refit was accepted: the estimate in force "
                                                   "is the store's own")
        refusal = store_refusal(est)
        if refusal is not None:
            return dict(row, result="skipped", reason=refusal)
        try:
            store.add(est, device_key=f"{self.att.device_type}-{self.att.device_id}",
                      source=raw_copy)
        except (StillpointError, OSError) as e:
            return dict(row, result="failed", reason=str(e))
        return dict(row, result="written", reason=None)

    def reread(self, data_file) -> DeviceDigest:
        """Size, SHA-256 and header of the device's data file, re-read past the page cache in a
        worker with the download's stall bound (a hung read ends in ``ReadStalled``, an
        ``OSError``)."""
        return device_digest(data_file, faults=tuple(self.att.faults), control=self.att.control,
                             stall_s=self.opts.stall_s, inline=self.opts.inline)

    # ------------------------------------------------------------------ finding the drive again
    def _find(self) -> Optional[Attached]:
        for a in discover(self.backend):
            if a.serial == self.att.serial:
                return a
        return None

    def wait_volume(self, timeout_s: Optional[float] = None) -> str:
        """Wait for this device's drive (after a delayed activation or enumeration); returns the
        data file path. A drive that is back but not mounted (a headless station: nothing mounts
        it again after a COMMIT) is mounted by the station (``drivers/ax/mount.py``) once an
        automounter has had its grace period; a drive that cannot be mounted is an error."""
        from stillpoint.drivers.ax.discovery import CombinedBackend
        from stillpoint.drivers.ax.mount import AUTOMOUNT_GRACE_S, remount
        limit = timeout_s if timeout_s is not None else self.opts.remount_s
        end = time.monotonic() + limit
        unmounted_since: Optional[float] = None
        mounted = None
        while True:
            if self.cancel.is_set():
                raise DeviceError(self.att.device_id, "stopped")
            a = self._find()
            if a is not None and a.volume and a.data_file.exists():
                self.att.volume = a.volume
                return str(a.data_file)
            now = time.monotonic()
            if a is not None and a.block_device and mounted is None:
                unmounted_since = unmounted_since if unmounted_since is not None else now
                if now - unmounted_since >= min(AUTOMOUNT_GRACE_S, limit / 4):
                    remount(a, self.backend or CombinedBackend())  # MountError: one line, the reason
                    mounted = a.block_device
            if now >= end:
                raise DeviceError(self.att.device_id, "the drive did not come back within "
                                  f"{limit:g} s (after COMMIT/CLEAR or enumeration"
                                  + (f"; the station mounted {mounted} but no {C.AX_DATA_FILE} "
                                     "appeared" if mounted else "")
                                  + (f"; {a.problem}" if a is not None and a.problem and not mounted
                                     and not a.problem.startswith("no drive found") else "")
                                  + "); unplug and re-plug the device")
            time.sleep(0.1)

    # ------------------------------------------------------------------ the flow
    def _run(self) -> None:
        att, opts = self.att, self.opts
        if not self._hold():
            return  # the device left while another station held it
        try:
            self._set("identifying")
            if not att.volume:
                self.wait_volume(opts.volume_wait_s)
            client = AxClient.open(att.port, f"{att.device_id}")  # only under the device lock
            try:
                self._with_client(client)
            finally:
                client.close()
        finally:
            self._release()

    def _hold(self, poll_s: float = 0.5, look_s: float = 2.0) -> bool:
        """Take the host-wide lock of this device (``hostlock``); while another station holds it
        the flow is ``busy`` ("held by the station on OUT (pid N)") and waits, touching nothing.
        False: the device left (or the station stopped) meanwhile."""
        lock = DeviceLock(key_of(self.att), self.opts.out_dir)
        looked = time.monotonic()
        while True:
            try:
                self.lock = lock.acquire(self.att.device_id)
                return True
            except DeviceBusy as e:
                if not self.opts.wait_when_busy:
                    raise DeviceError(self.att.device_id, f"busy: {e.reason}") from None
                if (self.state, self.reason) != ("busy", e.reason):
                    self._set("busy", e.reason)
            if self.cancel.wait(poll_s):
                return False
            if time.monotonic() - looked >= look_s:
                looked = time.monotonic()
                if self._find() is None:
                    return False

    def _release(self) -> None:
        if self.lock is not None:
            self.lock.release()
            self.lock = None

    def _configured_before(self, session: int) -> Optional[str]:
        """Why this empty device counts as configured for ``session`` already (a station of this
        computer configured it and no clear came after), or None."""
        att = self.att
        try:
            rec = configured_record(key_of(att))
        except HostRecordError as e:
            return f"the host-wide record cannot be read ({e}); not configured again"
        if rec is not None and rec.get("session") == session:
            return (f"already configured for session {session} by {holder_text(rec)} at "
                    f"{rec.get('time_utc', '?')}")
        row = self.ledger.configured_since_clear(att.device_id, session, att.device_type)
        if row is not None:
            return (f"already configured for session {session} by this station at "
                    f"{iso_utc(int(row[0]) * 10**9)}")
        return None

    def _changed_elsewhere(self, session: int) -> Optional[str]:
        """The host-wide ``changed`` verdict on this device's session (any station's), or None."""
        try:
            rec = changed_record(key_of(self.att))
        except HostRecordError as e:
            return str(e)
        if rec is None or rec.get("session") != session:
            return None
        return (f"{holder_text(rec)} found its data changed between two reads of session "
                f"{session} (download {rec.get('download_id', '?')}, {rec.get('time_utc', '?')})")

    def _with_client(self, client: AxClient) -> None:
        att, opts = self.att, self.opts
        client.stream_stop()  # a preview left running would hide every reply [USB] A6
        ident = client.identify()
        if ident.device_id != att.device_id:
            raise IdentityMismatch(att.device_id, f"ID names device {ident.device_id} but the USB serial "
                                                  f"{att.serial} and the drive label say {att.device_id}")
        if ident.device_type != att.device_type:
            raise IdentityMismatch(att.device_id, f"ID says {ident.device_type}, the USB serial "
                                                  f"{att.device_type}")
        self.ledger.device_seen(att.device_id, ident.device_type, att.serial, ident.firmware, att.slot)
        offset = clock_offset_s(client)
        batt = client.battery()
        session = client.session()
        self.session = session
        self.battery_pct, self.clock_offset_s = batt.percent, offset
        self.info = f"fw {ident.firmware}, battery {batt.percent} %, clock {offset:+.1f} s"
        data_file = att.data_file
        for line in resolve_sent_clear(self.ledger, att.device_id, data_file,
                                       device_type=att.device_type, reread=self.reread):
            self.info += f"; {line}"
        size = os.stat(data_file).st_size
        self.total_bytes = size
        if size <= C.AX_EMPTY_DATA_BYTES:
            self._set("empty", "no data on the device")
        else:
            rec = self.ledger.verified_download(att.device_id, session, device_type=att.device_type)
            if rec is not None and rec.bytes == size:
                self.done_bytes = size
                self._set("verified", f"already downloaded: {Path(rec.cwa_path).name}")
                from .products import products_wanted
                if rec.mcap_path and products_wanted(rec.mcap_path):  # a station stopped first
                    self._start_products(rec.id, rec.mcap_path)
            else:
                self._download(data_file, session, offset, batt.percent)
        configure = opts.configure_after and opts.profile is not None
        if configure and self.state in ("verified", "empty"):
            opts.profile.check_device(ident.device_type)  # refused before the device is touched
        changed = self.ledger.data_changed(att.device_id, session, att.device_type) \
            if opts.clear_after_verify and self.state == "verified" else None
        if changed is not None:
            raise DeviceError(att.device_id, f"not cleared: the device's data changed between two "
                                             f"reads in download {changed.id} of this session "
                                             "(its copy is kept); check the device, then clear it by "
                                             "hand (`stillpoint device clear`)")
        elsewhere = self._changed_elsewhere(session) \
            if opts.clear_after_verify and self.state == "verified" else None
        if elsewhere is not None:  # the verdict binds every station of this computer
            raise DeviceError(att.device_id, f"not cleared: {elsewhere}; check the device, then "
                                             "clear it by hand (`stillpoint device clear`)")
        if opts.clear_after_verify and self.state == "verified":
            # the same byte rule whether this run downloaded it or the ledger says it was
            # ("already downloaded"): copy, device and ledger must agree before the erase
            self._set("clearing")
            clear_verified(client, self.ledger, att.device_id, session, self.att.data_file,
                           self.wait_volume, device_type=ident.device_type, erase=opts.erase,
                           reread=self.reread)
            self._set("cleared", self.info)
            try:
                forget_configured(key_of(att))  # the erase ended the configuration before it
            except (HostRecordError, OSError):
                pass
        if configure and self.state == "empty" and not opts.reconfigure:
            before = self._configured_before(session)
            if before is not None:  # never configured again unless asked for explicitly
                self.configured_session = session
                self._set("configured", f"{before}; not configured again (ask for it "
                                        "explicitly: --reconfigure, or the dashboard's Configure)")
                return
        if configure and self.state in ("cleared", "empty"):
            self._set("configuring")
            try:
                settings, warnings = configure_device(client, opts.profile, data_file=self.att.data_file,
                                                      wait_volume=self.wait_volume,
                                                      session_now=session_before_clear(
                                                          self.ledger, att.device_id, session,
                                                          att.device_type))
            except DeviceError as e:
                self.ledger.configured(att.device_id, None, {}, "error", e.reason,
                                       device_type=att.device_type)
                raise
            self.ledger.configured(att.device_id, settings["session"], settings, "ok",
                                   "; ".join(warnings) or None, device_type=att.device_type)
            try:
                record_configured(key_of(att), settings["session"], opts.out_dir,
                                  start=settings.get("start"), stop=settings.get("stop"))
            except (HostRecordError, OSError) as e:
                warnings.append(f"the host-wide record was not written ({e})")
            self.configured_session = settings["session"]
            from stillpoint.drivers.ax.protocol import display_time
            self._set("configured", f"session {settings['session']}, start "
                      f"{display_time(settings['start'])}"
                      + (f" (warning: {'; '.join(warnings)})" if warnings else ""))

    def _download(self, data_file: Path, session: int, offset: float, battery: int) -> None:
        att, opts = self.att, self.opts
        out = Path(opts.out_dir)
        stem = download_stem(opts.profile, self.ledger, att.device_type, att.device_id, session)
        settings = dict(opts.run_settings)
        settings.setdefault("timezone", station_timezone(opts.profile))
        prior = self._calibration_prior(settings)
        dl_id = self.ledger.download_started(att.device_id, session, clock_offset_s=offset,
                                             battery_pct=battery,
                                             cwa_path=str(names.raw_copy(out, stem)),
                                             mcap_path=str(names.log_final(out, stem)),
                                             device_type=att.device_type, prior=prior)
        meta = {"station": {"station_id": station_id(), "host_time_zone": host_timezone(),
                            "clock_offset_s": f"{offset:.3f}",
                            "clock_offset_vs_utc_s": f"{offset + time.localtime().tm_gmtoff:.3f}",
                            "device_serial": att.serial,
                            "dock_slot": att.slot, "battery_pct": str(battery),
                            "attached_utc": iso_utc(time.time_ns()),
                            "calibration_prior": json.dumps(prior, sort_keys=True)}}
        if opts.static_from_store is not None:
            from stillpoint.engine.calibration.static import with_static_calibration
            settings = with_static_calibration(settings, opts.static_from_store,
                                               f"{att.device_type}-{att.device_id}")
        job = DownloadJob(att.device_id, session, str(data_file), str(out), att.device_type,
                          tuple(att.faults), att.control, meta, settings,
                          opts.throttle_bps or att.read_bps, pipeline=opts.pipeline, file_stem=stem)
        self._set("downloading")
        self.worker = w = DownloadWorker(job, stall_s=opts.stall_s, inline=opts.inline).start()
        t0 = time.monotonic()
        phase = "copy"
        copying = False
        while not w.finished:
            if self.cancel.is_set():
                w.cancel()
                why = "stopped by the user; the partial copy is kept"
                self.ledger.download_failed(dl_id, why, w.done)
                raise DeviceError(att.device_id, why)
            ph, self.done_bytes, total = w.poll(0.2)
            self.total_bytes = total or self.total_bytes
            if self.done_bytes and not copying:  # the worker is under way
                copying = True
                kill_point("download:copying")
            if ph == "copy":
                el = time.monotonic() - t0
                self.mbps = self.done_bytes / el / 1e6 if el > 0 else None
            if ph != phase and ph in ("verify", "finishing"):
                phase = ph
                self._set("verifying")
            self.on_change(self)
        r = self.result = w.result
        if not r.ok:
            self.ledger.download_failed(dl_id, r.reason, r.bytes,
                                        state="changed" if r.changed else "error")
            if r.changed:  # every station of this computer honours it (``hostlock``)
                try:
                    record_changed(key_of(att), session, opts.out_dir, download_id=dl_id,
                                   reason=r.reason)
                except (HostRecordError, OSError) as e:
                    r.reason += f" (the host-wide record was not written: {e})"
            raise DeviceError(att.device_id, r.reason + (" (resumes when the same device and "
                                                         "session come back)"
                                                         if "unplugged" in (r.reason or "") else ""))
        # the ledger completes the download: row 'completing', the renames, row 'verified'
        try:
            with_log = r.mcap_part is not None or (r.adopted and os.path.lexists(r.mcap_path))
            complete(self.ledger, dl_id, cwa_path=r.cwa_path,
                     mcap_path=r.mcap_path if with_log else None,
                     sha256=r.sha256, bytes_=r.bytes, bad_sectors=r.bad_sectors,
                     summary={"calibration": (r.summary or {}).get("calibration"),
                              "samples": (r.summary or {}).get("samples")},
                     with_log=with_log,
                     reason=("adopted: the final copy was already there and equals the device"
                             if r.adopted else None),
                     reread_ranges=r.reread_ranges, patched_ranges=r.patched_ranges)
        except (CompletionError, OSError) as e:
            why = str(e) if isinstance(e, CompletionError) else f"{e.filename}: {e.strerror or e}"
            self.ledger.download_failed(dl_id, why, r.bytes)
            raise DeviceError(att.device_id, why) from None
        if not with_log:
            r.mcap_path = None
        cal = (r.summary or {}).get("calibration") or {}
        repairs = repairs_text(r.reread_ranges, r.patched_ranges)
        if repairs:  # every repair on record: an event of its own, then the state line says it
            try:
                self.ledger.event(att.device_id, att.serial, "repaired",
                                  f"download {dl_id}: {repairs}")
            except StillpointError:
                pass
        self.info = (f"{r.bytes / 1e6:.1f} MB, {r.bad_sectors} bad sectors"
                     + (f", {repairs}" if repairs else "") + ", calibration "
                     f"{cal.get('status', '-')}"
                     + (f" ({cal['error_before_mg']:.1f} -> {cal['error_after_mg']:.1f} mg)"
                        if cal.get("error_after_mg") is not None and cal.get("error_before_mg") is not None
                        else ""))
        self._store_note = self._store_final(r.summary, r.cwa_path)
        if self._store_note is not None:
            n = self._store_note
            try:
                self.ledger.product(dl_id, n["product"], n["path"], n["result"], n["reason"])
            except StillpointError:
                pass
        self._set("verified", self.info)
        self._start_products(dl_id, r.mcap_path)
