"""The dashboard's HTTP server (standard library ``ThreadingHTTPServer``, one thread per request).

``Dashboard(folder, station=None, host=, port=, token=None, read_only=False)``; ``start()`` serves
on a thread and returns the address; ``close()`` stops. With a ``station`` the dock is live (a
station listener, ``LiveDock``) and actions can be asked for; without one every page is read from
the ledger and nothing can be changed.

=====================================  ===============================================================
GET  /                                 the dock (``?token=`` sets the token cookie)
GET  /events                           server-sent events: the dock's changing part, at most 2 a second
GET  /api/dock                         the dock's rows and disk as JSON
GET  /device/<type>-<id>               one device's history and trends
GET  /device/<type>-<id>/sheet         its printable handover sheet (?session=N: the sheet of that
                                       session's configuration, marked when superseded)
GET  /files/<path>                     a file inside the output folder (raw copy, MCAP, report)
GET  /static/<name>                    the page's own CSS and script
POST /action/<action>/<type>-<id>      retry | verify | clear | configure (form: token, confirm=yes,
                                       who, subject, code; reconfigure=N to configure a configured
                                       device again as session N); 303 back to the dock, or the
                                       refusal's status
=====================================  ===============================================================

Refusals answer with one line (in a small page): 403 without the token or in read-only mode,
404 for an unknown page, device or file (files outside the folder are unknown), 409 when the
device's state forbids the action, 400 for a malformed request.
"""

from __future__ import annotations

import json
import mimetypes
import os
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from pathlib import Path
from typing import Optional
from urllib.parse import parse_qs, quote, unquote, urlsplit

from . import access, pages
from .actions import Actions
from .live import LiveDock
from .records import Records, parse_device_key

PUSH_MIN_S = 0.5  # the live stream sends at most this often (a change is shown within 1 s)
KEEPALIVE_S = 15.0
FORM_MAX_BYTES = 4096


class Dashboard:
    def __init__(self, folder, station=None, *, host: str = "127.0.0.1", port: int = 0,
                 token: Optional[str] = None, read_only: bool = False):
        self.folder = Path(folder)
        self.records = Records(self.folder)
        self.station = station
        self.read_only = read_only or station is None
        self.token = token or access.new_token()
        self.loopback = access.is_loopback(host)
        self.live: Optional[LiveDock] = None
        self.actions = None if self.read_only else Actions(station)
        if station is not None:
            self.live = LiveDock()
            station.add_listener(self.live.on_change)
            for f in list(station.flows.values()):
                self.live.on_change(f)
        self._facts: dict = {}
        self._facts_at = (-1, 0.0)
        self._facts_lock = threading.Lock()
        self.stopping = threading.Event()
        handler = type("Handler", (_Handler,), {"dash": self})
        try:
            self.httpd = ThreadingHTTPServer((host, port), handler)
        except OSError as e:
            raise access.AddressError(f"--web {host}:{port}: cannot serve there: "
                                      f"{e.strerror or e}") from None
        self.httpd.daemon_threads = True
        self._thread: Optional[threading.Thread] = None

    @property
    def url(self) -> str:
        host, port = self.httpd.server_address[:2]
        return f"http://{host if ':' not in host else '[' + host + ']'}:{port}/"

    def start(self) -> str:
        self._thread = threading.Thread(target=self.httpd.serve_forever, kwargs={"poll_interval": 0.5},
                                        daemon=True, name="dashboard")
        self._thread.start()
        return self.url

    def close(self) -> None:
        self.stopping.set()
        if self.live is not None:
            self.live.wake()
        self.httpd.shutdown()
        self.httpd.server_close()

    # ------------------------------------------------------------------ what the pages show
    def _ledger_facts(self) -> tuple[dict, dict]:
        """Battery, clock offset and calibration per device and the disk, re-read from the ledger
        only when a device's state changed (or every 5 s): progress updates cost no I/O."""
        sv = self.live.state_version if self.live else 0
        with self._facts_lock:
            if self._facts_at[0] != sv or time.monotonic() - self._facts_at[1] > 5.0:
                facts = {}
                if self.live is not None:
                    for r in self.live.rows():
                        facts[(r["device_type"], r["device_id"])] = \
                            self.records.latest(r["device_type"], r["device_id"])
                self._facts = {"devices": facts, "disk": self.records.disk()}
                self._facts_at = (sv, time.monotonic())
            return self._facts["devices"], self._facts["disk"]

    def dock_rows(self) -> tuple[list[dict], dict]:
        if self.live is None:
            rows = self.records.devices()
            return rows, self.records.disk()
        facts, disk = self._ledger_facts()
        rows = self.live.rows()
        prof = self.station.opts.profile if self.station is not None else None
        for r in rows:
            r.update(facts.get((r["device_type"], r["device_id"]), {}))
            if prof is not None and r.get("configured_session") is not None:
                # configuring it again makes this session (the confirmation names it)
                r["next_session"] = prof.session_for(r["configured_session"])
        return rows, disk

    def setting_code(self) -> Optional[str]:
        prof = self.station.opts.profile if self.station is not None else None
        if prof is None:
            return None
        from ..setting_code import setting_code
        return setting_code(prof)

    def return_file_name(self, hist: dict) -> Optional[str]:
        """The raw copy's name when the device comes back (the profile's ``file_name``)."""
        prof = self.station.opts.profile if self.station is not None else None
        ok = [c for c in hist["configurations"] if c.get("result") == "ok"]
        if prof is None or not prof.file_name or not ok:
            return None
        from ..study import file_stem
        s = ok[-1].get("settings") or {}
        if s.get("session") is None:
            return None
        return file_stem(prof.file_name, device_type=hist["device_type"],
                         device_id=hist["device_id"], session=int(s["session"]),
                         metadata={**prof.metadata, **(s.get("metadata") or {})}) + ".cwa"

    def fragment(self, with_token: bool) -> str:
        rows, disk = self.dock_rows()
        token = self.token if (with_token and not self.read_only) else None
        return pages.dock_fragment(rows, disk, token=token, live=self.live is not None)


class _Handler(BaseHTTPRequestHandler):
    dash: Dashboard
    server_version = "stillpoint-dashboard"
    protocol_version = "HTTP/1.1"

    def log_message(self, fmt, *args):  # the station's terminal stays the station's
        pass

    # ------------------------------------------------------------------ answers
    def _send(self, status: int, body: bytes, ctype: str = "text/html; charset=utf-8",
              headers: Optional[dict] = None) -> None:
        self.send_response(status)
        self.send_header("Content-Type", ctype)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.send_header("X-Content-Type-Options", "nosniff")
        self.send_header("Content-Security-Policy",
                         "default-src 'self'; img-src 'self' data:; style-src 'self'; "
                         "script-src 'self'; frame-ancestors 'none'")
        for k, v in (headers or {}).items():
            self.send_header(k, v)
        self.end_headers()
        if self.command != "HEAD":
            self.wfile.write(body)

    def _page(self, status: int, text: str, headers: Optional[dict] = None) -> None:
        self._send(status, text.encode(), headers=headers)

    def _refuse(self, status: int, message: str) -> None:
        self._page(status, pages.message_page(status, message))

    # ------------------------------------------------------------------ the token
    def _token(self, query: dict) -> tuple[bool, Optional[str]]:
        """(valid token present, the token to set as a cookie)."""
        q = (query.get("token") or [None])[0]
        if access.token_ok(q, self.dash.token):
            return True, q
        return access.token_ok(access.cookie_token(self.headers.get("Cookie")), self.dash.token), None

    def _cookie(self, tok: Optional[str]) -> dict:
        if not tok:
            return {}
        return {"Set-Cookie": f"{access.COOKIE}={tok}; Path=/; HttpOnly; SameSite=Strict"}

    # ------------------------------------------------------------------ GET
    def _answer(self, handle) -> None:
        """``handle()``, with a client gone mid-answer ignored and any other failure one line
        (500), never a traceback."""
        try:
            handle()
        except (BrokenPipeError, ConnectionResetError):
            pass
        except Exception as e:  # noqa: BLE001 - one line, never a traceback
            try:
                self._refuse(500, f"{type(e).__name__}: {getattr(e, 'reason', None) or e}")
            except OSError:
                pass

    def do_GET(self):
        self._answer(self._get)

    do_HEAD = do_GET

    def _get(self):
        if urlsplit(self.path).path == "/events":
            return self._get_page()  # the stream lasts: each push reads the ledger afresh
        with self.dash.records.reading():  # a page: one snapshot of the ledger
            self._get_page()

    def _get_page(self):
        d = self.dash
        u = urlsplit(self.path)
        query = parse_qs(u.query)
        path = unquote(u.path)
        ok, set_tok = self._token(query)
        if path.startswith("/static/"):
            return self._static(path[len("/static/"):])
        if not ok and not (d.loopback and access.loopback_host(self.headers.get("Host"))):
            return self._refuse(403, "this dashboard needs its token: open the address the "
                                     "station printed (…/?token=…)")
        hdr = self._cookie(set_tok)
        if path == "/":
            msg = (query.get("done") or [""])[0][:300]
            body = pages.dock_page(d.fragment(ok), folder=str(d.folder), live=d.live is not None,
                                   read_only=d.read_only, message=msg, code=d.setting_code())
            return self._page(200, body, hdr)
        if path == "/events":
            return self._events(ok)
        if path == "/api/dock":
            rows, disk = d.dock_rows()
            return self._send(200, json.dumps({"devices": pages.sort_rows(rows), "disk": disk,
                                               "live": d.live is not None,
                                               "read_only": d.read_only}, default=str).encode(),
                              "application/json")
        if path.startswith("/device/"):
            rest = path[len("/device/"):]
            key, _, sub = rest.partition("/")
            dev = parse_device_key(key)
            if dev is None or sub not in ("", "sheet"):
                return self._refuse(404, f"no page {path}")
            hist = d.records.history(*dev)
            if not hist["known"]:
                return self._refuse(404, f"the ledger knows no device {key}")
            if sub == "sheet":
                asked = (parse_qs(urlsplit(self.path).query).get("session") or [""])[0]
                if asked and not asked.isdigit():
                    return self._refuse(400, f"session must be a number, not {asked[:20]!r}")
                page = pages.sheet_page(hist, file_name=d.return_file_name(hist),
                                        session=int(asked) if asked else None)
                if page is None:
                    return self._refuse(404, f"{key} was never configured for session {asked}")
                return self._page(200, page, hdr)
            return self._page(200, pages.device_page(d.records, hist), hdr)
        if path.startswith("/files/"):
            return self._file(path[len("/files/"):])
        return self._refuse(404, f"no page {path}")

    def _static(self, name: str):
        if name not in ("dashboard.css", "dashboard.js"):
            return self._refuse(404, f"no file /static/{name}")
        body = resources.files(__package__).joinpath("static", name).read_bytes()
        self._send(200, body, "text/css" if name.endswith(".css") else "text/javascript")

    def _file(self, rel: str):
        d = self.dash
        p = d.records.inside(str(d.folder / rel)) if rel and not os.path.isabs(rel) else None
        if p is None:
            return self._refuse(404, f"no file {rel} inside the output folder")
        ctype = mimetypes.guess_type(p.name)[0] or "application/octet-stream"
        size = p.stat().st_size
        self.send_response(200)
        self.send_header("Content-Type", ctype)
        self.send_header("Content-Length", str(size))
        self.send_header("Content-Disposition", f"attachment; filename=\"{quote(p.name)}\"")
        self.send_header("X-Content-Type-Options", "nosniff")
        self.end_headers()
        if self.command == "HEAD":
            return
        with open(p, "rb") as f:
            while True:
                chunk = f.read(1 << 20)
                if not chunk:
                    break
                self.wfile.write(chunk)

    def _events(self, with_token: bool):
        d = self.dash
        if d.live is None:
            return self._send(204, b"", "text/plain")  # no station: nothing will change
        self.send_response(200)
        self.send_header("Content-Type", "text/event-stream")
        self.send_header("Cache-Control", "no-store")
        self.send_header("Connection", "close")
        self.end_headers()
        self.close_connection = True
        if self.command == "HEAD":
            return
        version = d.live.version
        sent = d.fragment(with_token)
        self.wfile.write(pages.sse_payload(sent))
        self.wfile.flush()
        last = time.monotonic()
        while not d.stopping.is_set():
            new = d.live.wait(version, KEEPALIVE_S)
            if d.stopping.is_set():
                break
            if new == version:
                self.wfile.write(b": keepalive\n\n")
                self.wfile.flush()
                continue
            wait = PUSH_MIN_S - (time.monotonic() - last)
            if wait > 0:
                d.stopping.wait(wait)
            version = d.live.version
            frag = d.fragment(with_token)
            if frag != sent:  # progress that does not change the page sends nothing
                self.wfile.write(pages.sse_payload(frag))
                self.wfile.flush()
                sent = frag
            last = time.monotonic()

    # ------------------------------------------------------------------ POST
    def do_POST(self):
        self._answer(self._post)

    def _post(self):
        d = self.dash
        path = unquote(urlsplit(self.path).path)
        parts = path.strip("/").split("/")
        if len(parts) != 3 or parts[0] != "action":
            return self._refuse(404, f"no action at {path}")
        try:
            n = int(self.headers.get("Content-Length") or 0)
        except ValueError:
            n = -1
        if n < 0 or n > FORM_MAX_BYTES:
            return self._refuse(400, f"the form must be at most {FORM_MAX_BYTES} bytes")
        form = parse_qs(self.rfile.read(n).decode("utf-8", "replace"))

        def field(name):
            return (form.get(name) or [""])[0].strip()
        if not access.token_ok(field("token"), d.token):
            return self._refuse(403, "an action needs the dashboard's token in its form")
        if d.read_only or d.actions is None:
            return self._refuse(403, "this dashboard is read-only: no action can be taken here")
        if field("confirm") != "yes":
            return self._refuse(400, "the action was not confirmed (confirm=yes)")
        who = field("who")[:60] or "dashboard user"
        origin = f"{self.client_address[0]} ({(self.headers.get('User-Agent') or '-')[:80]})"
        status, msg = d.actions.ask(parts[1], parts[2], who=who, origin=origin,
                                    subject=field("subject") or None, code=field("code") or None,
                                    reconfigure=field("reconfigure") or None)
        if status >= 400:
            return self._refuse(status, msg)
        self._send(303, b"", headers={"Location": "/?done=" + quote(msg)})
