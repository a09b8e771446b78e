"""The dashboard's HTTP server: a fixed number of threads (engine/station/web/serving.py: one
waiting on every connection, ``Limits.workers`` answering, one pushing every live stream), caps on
connections and live streams per client and in total, read, idle and write timeouts.

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
404 for an unknown page, device or file (files outside the folder are unknown; no page names the
folder), 409 when the device's state forbids the action, 400 for a malformed request, 503 over a
connection or live-stream limit, 413 for a body over ``FORM_MAX_BYTES`` (the connection is
closed). Refusals and failures are logged to stderr through the rate-limited, non-blocking log
(engine/core/ratelog.py, logger ``stillpoint.dashboard``).
"""

from __future__ import annotations

import json
import mimetypes
import os
import threading
import time
from http.server import BaseHTTPRequestHandler
from importlib import resources
from pathlib import Path
from typing import Optional
from urllib.parse import parse_qs, quote, unquote, urlsplit

from . import access, pages
from .actions import Actions
from .live import LiveDock
from .records import Records, parse_device_key
from .serving import BoundedHTTPServer, Limits, OneRequestHandler, log

PUSH_MIN_S = 0.5  # the live stream sends at most this often (a change is shown within 1 s)
KEEPALIVE_S = 15.0
FORM_MAX_BYTES = 4096
STREAM_WRITE_TIMEOUT_S = 2.0  # a live stream that does not take a push in this time is closed
PATH_SHOWN = 80  # characters of an unknown path repeated in its 404 page


class Dashboard:
    def __init__(self, folder, station=None, *, host: str = "127.0.0.1", port: int = 0,
                 token: Optional[str] = None, read_only: bool = False,
                 limits: Optional[Limits] = None):
        from stillpoint.engine.core import ratelog
        ratelog.install(log.name)
        self.folder = Path(folder)
        self.records = Records(self.folder)
        self.station = station
        self.read_only = read_only or station is None
        self.loopback = access.is_loopback(host)
        if token is not None and not self.loopback:
            access.check_token(token, f"--web {host}:{port}")
        self.token = token or access.new_token()
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
        limits = limits or Limits(max_body=FORM_MAX_BYTES)
        try:
            self.httpd = BoundedHTTPServer((host, port), handler, limits)
        except (OSError, OverflowError, ValueError) as e:
            raise access.AddressError(f"--web {host}:{port}: cannot serve there: "
                                      f"{getattr(e, 'strerror', None) or e}") from None
        self.streams = _Streams(self)
        self._thread: Optional[threading.Thread] = None

    @property
    def url(self) -> str:
        host, port = self.httpd.server_address[:2]
        return f"http://{host if ':' not in host else '[' + host + ']'}:{port}/"

    def start(self) -> str:
        self._thread = threading.Thread(target=self.httpd.serve_forever, kwargs={"poll_interval": 0.5},
                                        daemon=True, name="dashboard")
        self._thread.start()
        if self.live is not None:
            self.streams.start()
        return self.url

    def close(self) -> None:
        self.stopping.set()
        if self.live is not None:
            self.live.wake()
        self.httpd.shutdown()
        if self._thread is not None:
            self._thread.join(timeout=5)
        self.streams.close()
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


class _Streams:
    """Every live stream (``/events``) pushed by one thread: each change of the dock (at most one
    push per ``PUSH_MIN_S``) is rendered once per kind of stream (with or without the token) and
    written to every stream whose page it changes; a keep-alive comment every ``KEEPALIVE_S``
    finds the closed ones. A stream that does not take a push within ``STREAM_WRITE_TIMEOUT_S``
    is closed."""

    def __init__(self, dash: Dashboard):
        self.dash = dash
        # held while a new stream's first fragment is rendered, sent and adopted, and while the
        # push thread reads the dock's version with its list of streams: a change is either in the
        # first fragment or pushed afterwards, never lost between the two
        self.lock = threading.RLock()
        self._lock = self.lock
        self._streams: list = []  # [socket, client host, with token, last fragment sent]
        self._thread = threading.Thread(target=self._loop, name="dashboard-streams", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def __len__(self) -> int:
        with self._lock:
            return len(self._streams)

    def adopt(self, sock, host: str, with_token: bool, sent: str) -> None:
        sock.settimeout(STREAM_WRITE_TIMEOUT_S)
        with self._lock:
            self._streams.append([sock, host, with_token, sent])

    def _drop(self, st) -> None:
        with self._lock:
            if st not in self._streams:
                return
            self._streams.remove(st)
        try:
            st[0].close()
        except OSError:
            pass
        self.dash.httpd.release_stream(st[1])

    def _send(self, st, data: bytes) -> None:
        try:
            st[0].sendall(data)
        except OSError:
            self._drop(st)

    def _loop(self) -> None:
        d = self.dash
        version = d.live.version
        last = 0.0
        while not d.stopping.is_set():
            new = d.live.wait(version, KEEPALIVE_S)
            if d.stopping.is_set():
                break
            with self._lock:
                streams = list(self._streams)
            if new == version:
                for st in streams:
                    self._send(st, b": keepalive\n\n")
                continue
            wait = PUSH_MIN_S - (time.monotonic() - last)
            if wait > 0:
                d.stopping.wait(wait)
            with self._lock:
                version = d.live.version
                streams = list(self._streams)
            frags: dict = {}
            for st in streams:
                if st[2] not in frags:
                    frags[st[2]] = d.fragment(st[2])
                if frags[st[2]] != st[3]:  # progress that does not change the page sends nothing
                    st[3] = frags[st[2]]
                    self._send(st, pages.sse_payload(st[3]))
            last = time.monotonic()

    def close(self) -> None:
        with self._lock:
            streams = list(self._streams)
        for st in streams:
            self._drop(st)


class _Handler(OneRequestHandler, BaseHTTPRequestHandler):
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
        except OSError as e:
            if isinstance(e, (BrokenPipeError, ConnectionResetError, TimeoutError)):
                self.close_connection = True
                return
            self._fail(e)
        except Exception as e:  # noqa: BLE001 - one line, never a traceback
            self._fail(e)

    def _fail(self, e: Exception) -> None:
        """500 without the error's text (it may name the output folder); the log has it."""
        log.warning("%s %s failed: %s: %s", self.command, self.path[:PATH_SHOWN], type(e).__name__,
                    str(e)[:200])
        self.close_connection = True
        try:
            self._refuse(500, "the dashboard could not answer this request (the station's "
                              "terminal says why)")
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
                return self._refuse(404, f"no page {path[:PATH_SHOWN]}")
            hist = d.records.history(*dev)
            if not hist["known"]:
                return self._refuse(404, f"the ledger knows no device {key[:PATH_SHOWN]}")
            if sub == "sheet":
                asked = (parse_qs(urlsplit(self.path).query).get("session") or [""])[0]
                if asked and not (asked.isascii() and asked.isdigit() and len(asked) < 10):
                    return self._refuse(400, f"session must be a number, not {asked[:20]!r}")
                page = pages.sheet_page(hist, file_name=d.return_file_name(hist),
                                        session=int(asked) if asked else None)
                if page is None:
                    return self._refuse(404, f"{key} was never configured for session {asked}")
                return self._page(200, page, hdr)
            return self._page(200, pages.device_page(d.records, hist), hdr)
        if path.startswith("/files/"):
            return self._file(path[len("/files/"):])
        return self._refuse(404, f"no page {path[:PATH_SHOWN]}")

    def _static(self, name: str):
        if name not in ("dashboard.css", "dashboard.js"):
            return self._refuse(404, f"no file /static/{name[:PATH_SHOWN]}")
        body = resources.files(__package__).joinpath("static", name).read_bytes()
        self._send(200, body, "text/css" if name.endswith(".css") else "text/javascript")

    def _file(self, rel: str):
        d = self.dash
        try:
            p = d.records.inside(str(d.folder / rel)) if rel and not os.path.isabs(rel) else None
            size = p.stat().st_size if p is not None else 0
        except (OSError, ValueError):  # a name too long for the system, a NUL byte, ...
            p = None
        if p is None:
            return self._refuse(404, f"no file {rel[:PATH_SHOWN]} inside the output folder")
        ctype = mimetypes.guess_type(p.name)[0] or "application/octet-stream"
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
        host = self.client_address[0]
        if self.command != "HEAD" and not d.httpd.reserve_stream(host):
            log.warning("refused a live stream to %s: stream limit reached", host)
            self.close_connection = True
            return self._refuse(503, "too many live streams are open; the page still works "
                                     "(reload it to update)")
        self.send_response(200)
        self.send_header("Content-Type", "text/event-stream")
        self.send_header("Cache-Control", "no-store")
        self.send_header("Connection", "close")
        self.end_headers()
        self.close_connection = True
        if self.command == "HEAD":
            return
        with d.streams.lock:  # a change after this first fragment is pushed (``_Streams``)
            try:
                sent = d.fragment(with_token)
                self.wfile.write(pages.sse_payload(sent))
            except BaseException:
                d.httpd.unreserve_stream(host)  # the worker closes the connection
                raise
            self.detach()  # the stream thread pushes from now on (``_Streams``)
            d.streams.adopt(self.connection, host, with_token, sent)

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
            self.close_connection = True  # the body is never read as a next request
            return self._refuse(413, f"the form must be at most {FORM_MAX_BYTES} bytes")
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
