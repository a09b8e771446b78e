"""The dashboard's connection handling: a fixed number of threads whatever the clients do.

``BoundedHTTPServer(address, handler_class, limits)``: one thread waits on every connection at
once (``selectors``) and reads each request whole (head up to ``HEAD_LIMIT`` bytes, a body up to
``limits.max_body``) before a worker thread (``limits.workers`` of them) answers it; a connection
between requests costs no thread. Limits (``Limits``; each refusal is one rate-limited log line):

* connections open at once: ``max_connections`` in total, ``max_per_client`` per client address;
  a connection over either is answered 503 and closed at once;
* a request must arrive whole within ``request_timeout_s`` of its first byte (else 408 and the
  connection is closed: a slow sender holds no worker), a kept-alive connection idle for
  ``idle_timeout_s`` is closed;
* a body over ``max_body`` bytes (by its Content-Length), a head over ``HEAD_LIMIT`` bytes or a
  chunked body is refused (413 / 431 / 411) and the connection closed, never read on as a second
  request;
* answers are written with a timeout (``write_timeout_s``), so a client that stops reading frees
  its worker.

A handler that keeps its connection (the dashboard's live stream) calls ``detach()`` and owns
the socket from then on. ``handler_class`` is a ``BaseHTTPRequestHandler`` subclass; it reads
the request from memory and answers one request per dispatch.
"""

from __future__ import annotations

import io
import logging
import queue
import selectors
import socket
import threading
import time
from dataclasses import dataclass
from typing import Optional

HEAD_LIMIT = 16384  # bytes of a request line and headers
log = logging.getLogger("stillpoint.dashboard")


@dataclass(frozen=True)
class Limits:
    workers: int = 4
    max_connections: int = 256
    max_per_client: int = 32
    idle_timeout_s: float = 30.0
    request_timeout_s: float = 10.0
    write_timeout_s: float = 60.0
    max_body: int = 4096
    max_streams: int = 16  # live streams (each a kept connection), in total
    max_streams_per_client: int = 4


class _Conn:
    __slots__ = ("sock", "addr", "buf", "last", "started", "closed")

    def __init__(self, sock, addr):
        self.sock, self.addr = sock, addr
        self.closed = False
        self.buf = bytearray()
        self.last = time.monotonic()
        self.started: Optional[float] = None  # first byte of the request being read


class _SocketWriter(io.BufferedIOBase):
    """``wfile`` of a handler: every write is one ``sendall`` (under the socket's timeout)."""

    def __init__(self, sock):
        self._sock = sock

    def writable(self):
        return True

    def write(self, b):
        self._sock.sendall(b)
        return len(b)


def _status_line(status: int, reason: str, text: str) -> bytes:
    body = (text + "\n").encode()
    return (f"HTTP/1.1 {status} {reason}\r\nContent-Type: text/plain; charset=utf-8\r\n"
            f"Content-Length: {len(body)}\r\nConnection: close\r\n\r\n").encode() + body


def _answer_and_close(sock, data: bytes) -> None:
    """Best effort on a non-blocking socket: the answer, the end of our side, what the client
    already sent read away (so the close is an orderly one, not a reset), then close."""
    try:
        sock.send(data)
        sock.shutdown(socket.SHUT_WR)
        for _ in range(16):
            if not sock.recv(65536):
                break
    except OSError:
        pass
    try:
        sock.close()
    except OSError:
        pass


def _content_length(head: bytes) -> tuple[Optional[int], Optional[str]]:
    """(body length, None) or (None, why the head is refused)."""
    n = 0
    for line in head.split(b"\r\n")[1:]:
        name, sep, value = line.partition(b":")
        if not sep:
            continue
        name = name.strip().lower()
        if name == b"transfer-encoding":
            return None, "chunked"
        if name == b"content-length":
            v = value.strip()
            if not v.isdigit() or len(v) > 12:
                return None, "bad length"
            n = int(v)
    return n, None


class BoundedHTTPServer:
    def __init__(self, address: tuple, handler_class, limits: Limits = Limits()):
        host, port = address
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        self.socket = socket.create_server((host, port), family=family, backlog=128)
        self.socket.setblocking(False)
        self.server_address = self.socket.getsockname()
        self.handler_class = handler_class
        self.limits = limits
        self._sel = selectors.DefaultSelector()
        self._sel.register(self.socket, selectors.EVENT_READ, "accept")
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)
        self._sel.register(self._wake_r, selectors.EVENT_READ, "wake")
        self._lock = threading.Lock()
        self._open: dict = {}  # client host -> connections open (waiting, being answered, streams)
        self._waiting: dict = {}  # socket -> _Conn, waiting for (the rest of) a request
        self._back: queue.SimpleQueue = queue.SimpleQueue()  # connections a worker kept alive
        self._work: queue.Queue = queue.Queue()
        self._streams: dict = {}  # client host -> live streams
        self._stop = threading.Event()
        self._threads: list = []
        self.refused = 0  # connections refused by a limit (tests, figures)

    # ------------------------------------------------------------------ counts
    def open_connections(self) -> int:
        with self._lock:
            return sum(self._open.values())

    def _release(self, host: str) -> None:
        with self._lock:
            n = self._open.get(host, 0) - 1
            if n > 0:
                self._open[host] = n
            else:
                self._open.pop(host, None)

    def reserve_stream(self, host: str) -> bool:
        """Count one more live stream of ``host``; False when a stream limit is reached."""
        lim = self.limits
        with self._lock:
            if (sum(self._streams.values()) >= lim.max_streams
                    or self._streams.get(host, 0) >= lim.max_streams_per_client):
                return False
            self._streams[host] = self._streams.get(host, 0) + 1
            return True

    def unreserve_stream(self, host: str) -> None:
        """Undo ``reserve_stream`` (the stream never started; its connection is the worker's)."""
        with self._lock:
            n = self._streams.get(host, 0) - 1
            if n > 0:
                self._streams[host] = n
            else:
                self._streams.pop(host, None)

    def release_stream(self, host: str) -> None:
        """A detached stream ended: its stream and its connection are no longer counted."""
        self.unreserve_stream(host)
        self._release(host)

    # ------------------------------------------------------------------ life
    def serve_forever(self, poll_interval: float = 0.5) -> None:
        for i in range(self.limits.workers):
            t = threading.Thread(target=self._work_loop, name=f"dashboard-worker-{i}", daemon=True)
            t.start()
            self._threads.append(t)
        try:
            self._loop(poll_interval)
        finally:
            for _ in self._threads:
                self._work.put(None)
            for c in list(self._waiting.values()):
                self._close(c)
            while True:
                try:
                    self._close(self._back.get_nowait(), registered=False)
                except queue.Empty:
                    break

    def shutdown(self) -> None:
        self._stop.set()
        self._wake()

    def server_close(self) -> None:
        self._stop.set()
        for s in [self.socket, self._wake_r, self._wake_w]:
            try:
                s.close()
            except OSError:
                pass
        for c in list(self._waiting.values()):
            self._close(c)

    def _wake(self) -> None:
        try:
            self._wake_w.send(b"x")
        except OSError:
            pass

    # ------------------------------------------------------------------ the waiting thread
    def _loop(self, poll_interval: float) -> None:
        lim = self.limits
        while not self._stop.is_set():
            for key, _ in self._sel.select(timeout=min(poll_interval, 1.0)):
                if key.data == "accept":
                    self._accept()
                elif key.data == "wake":
                    try:
                        while self._wake_r.recv(4096):
                            pass
                    except OSError:
                        pass
                else:
                    self._read(key.data)
            while True:
                try:
                    c = self._back.get_nowait()
                except queue.Empty:
                    break
                self._resume(c)
            now = time.monotonic()
            for c in list(self._waiting.values()):
                if c.started is not None and now - c.started > lim.request_timeout_s:
                    self._refuse(c, 408, "Request Timeout", "the request did not arrive in "
                                 f"{lim.request_timeout_s:g} s")
                elif c.started is None and now - c.last > lim.idle_timeout_s:
                    self._close(c)

    def _accept(self) -> None:
        lim = self.limits
        while True:
            try:
                sock, addr = self.socket.accept()
            except (BlockingIOError, InterruptedError):
                return
            except OSError as e:  # out of descriptors: the waiting ones still get answers
                log.warning("cannot accept a connection: %s", e.strerror or e)
                return
            host = addr[0]
            with self._lock:
                total, mine = sum(self._open.values()), self._open.get(host, 0)
                ok = total < lim.max_connections and mine < lim.max_per_client
                if ok:
                    self._open[host] = mine + 1
            if not ok:
                self.refused += 1
                log.warning("refused a connection from %s: %s", host,
                            f"{mine} open from it (limit {lim.max_per_client})"
                            if mine >= lim.max_per_client
                            else f"{total} open (limit {lim.max_connections})")
                sock.setblocking(False)
                _answer_and_close(sock, _status_line(503, "Service Unavailable",
                                                     "too many connections"))
                continue
            sock.setblocking(False)
            c = _Conn(sock, addr)
            self._waiting[sock] = c
            self._sel.register(sock, selectors.EVENT_READ, c)

    def _read(self, c: _Conn) -> None:
        try:
            data = c.sock.recv(65536)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            data = b""
        if not data:
            return self._close(c)
        if c.started is None:
            c.started = time.monotonic()
        c.buf += data
        self._dispatch_if_whole(c)

    def _dispatch_if_whole(self, c: _Conn) -> None:
        end = c.buf.find(b"\r\n\r\n")
        if end < 0:
            if len(c.buf) > HEAD_LIMIT:
                self._refuse(c, 431, "Request Header Fields Too Large",
                             f"the request head is over {HEAD_LIMIT} bytes")
            return
        end += 4
        if end > HEAD_LIMIT:
            return self._refuse(c, 431, "Request Header Fields Too Large",
                                f"the request head is over {HEAD_LIMIT} bytes")
        n, why = _content_length(bytes(c.buf[:end]))
        if why == "chunked":
            return self._refuse(c, 411, "Length Required", "a body needs a Content-Length")
        if n is None:
            return self._refuse(c, 400, "Bad Request", "the Content-Length is not a number")
        if n > self.limits.max_body:
            return self._refuse(c, 413, "Content Too Large",
                                f"a body must be at most {self.limits.max_body} bytes")
        if len(c.buf) < end + n:
            return
        raw = bytes(c.buf[:end + n])
        del c.buf[:end + n]
        self._sel.unregister(c.sock)
        del self._waiting[c.sock]
        self._work.put((c, raw))

    def _resume(self, c: _Conn) -> None:
        """A connection a worker answered and kept alive: wait for its next request."""
        if self._stop.is_set():
            return self._close(c, registered=False)
        c.last = time.monotonic()
        c.started = time.monotonic() if c.buf else None
        try:
            c.sock.setblocking(False)
            self._sel.register(c.sock, selectors.EVENT_READ, c)
        except (OSError, ValueError):
            return self._close(c, registered=False)
        self._waiting[c.sock] = c
        if c.buf:  # the client sent its next request with the last one
            self._dispatch_if_whole(c)

    def _refuse(self, c: _Conn, status: int, reason: str, text: str) -> None:
        log.warning("refused a request from %s: %s %s", c.addr[0], status, reason)
        _answer_and_close(c.sock, _status_line(status, reason, text))
        self._close(c)

    def _close(self, c: _Conn, registered: bool = True) -> None:
        if c.closed:
            return
        c.closed = True
        if registered and self._waiting.pop(c.sock, None) is not None:
            try:
                self._sel.unregister(c.sock)
            except (KeyError, ValueError, OSError):
                pass
        try:
            c.sock.close()
        except OSError:
            pass
        self._release(c.addr[0])

    # ------------------------------------------------------------------ workers
    def _work_loop(self) -> None:
        while True:
            item = self._work.get()
            if item is None:
                return
            c, raw = item
            keep = False
            try:
                c.sock.settimeout(self.limits.write_timeout_s)
                h = self.handler_class(c.sock, c.addr, self, raw)
                if h.detached:
                    continue  # the handler owns the socket (and its count) now
                keep = not h.close_connection and not self._stop.is_set()
            except Exception as e:  # noqa: BLE001 - a worker never dies of one client
                log.warning("request from %s failed: %s", c.addr[0], type(e).__name__)
            if keep:
                self._back.put(c)
                self._wake()
            else:
                self._close(c, registered=False)


class OneRequestHandler:
    """Mixin for a ``BaseHTTPRequestHandler`` served by ``BoundedHTTPServer``: the request is
    read from memory (``raw``), one request per dispatch; ``detach()`` keeps the socket."""

    detached = False

    def __init__(self, request, client_address, server, raw: bytes):
        self.raw_request = raw
        super().__init__(request, client_address, server)  # type: ignore[call-arg]

    def setup(self):
        self.connection = self.request
        self.rfile = io.BytesIO(self.raw_request)
        self.wfile = _SocketWriter(self.request)

    def handle(self):
        self.close_connection = True
        self.handle_one_request()

    def finish(self):
        pass

    def detach(self) -> None:
        self.detached = True
