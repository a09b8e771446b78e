"""The actions the dashboard can ask of a running station, each checked here, logged in the
ledger (``actions``: who, from where, the result) and carried out by the station's own code:

* ``retry``: the device's ended flow runs again (``Station.rerun``), with the station's own
  options: a device configured for its current session is never configured again by a retry.
* ``verify``: the device re-read past the cache (the flow's bounded ``reread``) and the raw copy
  hashed again; both must equal the ledger's verified download of the device's session.
* ``clear``: only after a verified download of the device's session; the flow runs again with
  the clear after verification, i.e. through the one clear path (``clearing.clear_verified``,
  which checks the bytes once more right before the erase).
* ``configure``: only a cleared or empty device, from the station's study profile or a setting
  code (``setting_code.profile_from_code``: typed or scanned, checked by the profile's rules); the flow
  runs again with the configuration, the subject id (typed or scanned) added to the metadata so
  it is written to the device's annotations, the ledger's configuration row and, with a
  profile's ``file_name`` template, the name of the device's next download. A device already
  configured for its current session is configured again only when the request names the session
  that makes (``reconfigure=N``, which the page's confirmation states): its printed handover
  sheet is superseded, and the sheet of the old session says so.

``Actions(station).ask(action, device_key, who=, origin=, subject=, code=)`` -> (HTTP status, message).
A refusal touches no device.
"""

from __future__ import annotations

import dataclasses
import threading
from typing import Optional

from stillpoint.drivers.names import safe_name_part

from .records import parse_device_key

ACTIONS = ("retry", "verify", "clear", "configure")


class Refused(Exception):
    def __init__(self, status: int, reason: str):
        super().__init__(reason)
        self.status, self.reason = status, reason


class Actions:
    def __init__(self, station):
        self.station = station
        self._busy: set[str] = set()
        self._lock = threading.Lock()

    def _flow(self, key: str):
        dev = parse_device_key(key)
        if dev is None:
            raise Refused(404, f"no device {key!r}")
        for f in list(self.station.flows.values()):
            if (f.att.device_type, f.att.device_id) == dev:
                return f
        raise Refused(409, f"{key} is not attached to this station")

    def ask(self, action: str, key: str, *, who: str, origin: str,
            subject: Optional[str] = None, code: Optional[str] = None,
            reconfigure: Optional[str] = None) -> tuple[int, str]:
        if action not in ACTIONS:
            return 404, f"no action {action!r} (one of {', '.join(ACTIONS)})"
        dev = parse_device_key(key)
        if dev is None:
            return 404, f"no device {key!r}"
        ledger = self.station.ledger
        detail = {k: v for k, v in (("subject", subject), ("code", code),
                                    ("reconfigure", reconfigure)) if v} or None
        aid = ledger.action_asked(dev[1], dev[0], action, who=who, origin=origin, detail=detail)
        try:
            flow = self._flow(key)
            with self._lock:
                if flow.att.serial in self._busy or not flow.finished.is_set():
                    raise Refused(409, f"{key} is busy ({flow.state}); try again when it has ended")
            msg = (self._configure(flow, subject, code, reconfigure) if action == "configure"
                   else getattr(self, "_" + action)(flow, subject))
        except Refused as e:
            ledger.action_result(aid, "refused", e.reason)
            return e.status, f"{action} {key} refused: {e.reason}"
        except ValueError as e:  # Station.rerun: detached or busy meanwhile
            ledger.action_result(aid, "refused", str(e))
            return 409, f"{action} {key} refused: {e}"
        if action == "verify":
            self._verify_later(flow, aid, key)
        else:
            ledger.action_result(aid, "started")
        return 202, msg

    # ------------------------------------------------------------------ each action
    def _retry(self, flow, subject) -> str:
        self.station.rerun(flow.att.serial)
        return f"retry of {flow.att.device_type}-{flow.att.device_id} started"

    def _verified(self, flow):
        if flow.state != "verified":
            raise Refused(409, f"the device is {flow.state}: only a device whose download is "
                               "verified (and not yet cleared) is verified again or cleared")
        rec = None
        if flow.session is not None:
            rec = self.station.ledger.verified_download(flow.att.device_id, flow.session,
                                                        device_type=flow.att.device_type)
        if rec is None:
            raise Refused(409, "the ledger holds no verified download of the device's session "
                               f"{flow.session if flow.session is not None else '(unknown)'}")
        return rec

    def _verify(self, flow, subject) -> str:
        self._verified(flow)
        return f"verification of {flow.att.device_type}-{flow.att.device_id} started"

    def _verify_later(self, flow, aid: int, key: str) -> None:
        from ..clearing import copy_sha256
        rec = self._verified(flow)
        with self._lock:
            self._busy.add(flow.att.serial)

        def run():
            ledger = self.station.ledger
            try:
                cn, csha = copy_sha256(rec.cwa_path)
                d = flow.reread(flow.att.data_file)
                if (cn, csha) != (rec.bytes, rec.sha256):
                    ledger.action_result(aid, "error", f"the raw copy ({cn} bytes, SHA-256 "
                                         f"{csha[:16]}) differs from the verified download")
                elif (d.bytes, d.sha256) != (rec.bytes, rec.sha256):
                    ledger.action_result(aid, "error", f"the device file ({d.bytes} bytes, SHA-256 "
                                         f"{d.sha256[:16]}) differs from the verified download")
                else:
                    ledger.action_result(aid, "ok", f"device, copy and ledger hold the same "
                                         f"{rec.bytes} bytes (SHA-256 {rec.sha256[:16]})")
            except OSError as e:
                ledger.action_result(aid, "error", f"{getattr(e, 'filename', None) or key}: "
                                     f"{e.strerror or e}")
            except Exception as e:  # noqa: BLE001 - recorded, never kills the server
                ledger.action_result(aid, "error", f"{type(e).__name__}: {e}")
            finally:
                with self._lock:
                    self._busy.discard(flow.att.serial)
        threading.Thread(target=run, daemon=True, name=f"verify-{key}").start()

    def _clear(self, flow, subject) -> str:
        self._verified(flow)
        self.station.rerun(flow.att.serial, clear_after_verify=True)
        return f"clear of {flow.att.device_type}-{flow.att.device_id} started (after the byte check)"

    def _configure(self, flow, subject, code=None, reconfigure=None) -> str:
        from ..setting_code import profile_from_code
        from ..study import StudyRecordError
        prof = self.station.opts.profile
        if code:
            try:
                prof = profile_from_code(code, prof)
            except StudyRecordError as e:
                raise Refused(400, str(e)) from None
        if prof is None:
            raise Refused(409, "the station runs without a study profile (--profile) and no "
                               "setting code was given: nothing to configure from")
        try:
            prof.check_device(flow.att.device_type)
        except Exception as e:  # noqa: BLE001 - ProfileError: the profile's own one-line reason
            raise Refused(400, str(e)) from None
        if flow.state not in ("cleared", "empty", "configured"):
            raise Refused(409, f"the device is {flow.state}: only a cleared or empty device is "
                               "configured")
        if subject:
            if safe_name_part(subject) != subject:
                raise Refused(400, f"subject id {subject!r}: letters, digits, '.', '_' and '-' only")
            prof = dataclasses.replace(prof, metadata={**prof.metadata, "subject": subject})
            try:
                prof.annotation_slots()
            except Exception as e:  # noqa: BLE001 - the profile's own one-line reason
                raise Refused(400, str(e)) from None
        again = flow.state == "configured" and flow.configured_session is not None
        if again:  # only when asked for by the session it makes (never a silent new session)
            new = prof.session_for(flow.configured_session)
            if reconfigure != str(new):
                raise Refused(409, f"the device is configured for session "
                                   f"{flow.configured_session} (its handover sheet names it); "
                                   f"configuring it again makes session {new} and supersedes "
                                   f"that sheet: confirm naming session {new} (reconfigure={new})")
        self.station.rerun(flow.att.serial, configure_after=True, profile=prof, reconfigure=again)
        return (f"configure of {flow.att.device_type}-{flow.att.device_id} started"
                + (f" for subject {subject}" if subject else "")
                + (f" as session {prof.session_for(flow.configured_session)}, superseding "
                   f"session {flow.configured_session}" if again else ""))
