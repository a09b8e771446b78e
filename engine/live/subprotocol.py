"""The WebSocket front of every live server: it accepts clients that speak the protocol under its
older name, and says why a handshake failed.

foxglove-sdk's server selects only the subprotocol ``foxglove.sdk.v1`` (and ``foxglove.sdk.v1.1``)
and answers any other client with HTTP 400. Older Foxglove releases and Lichtblick offer only
``foxglove.websocket.v1``, the same protocol under its first name (ws-protocol docs/spec.md
"Protocol overview"; Lichtblick PR #819: "currently this subprotocol is identical to
foxglove.websocket.v1"). The front listens where the user asked; the SDK server listens on a
loopback port of its own. For each connection the front reads the HTTP upgrade request, renames
an offered ``foxglove.websocket.v1`` to ``foxglove.sdk.v1`` when the client does not offer the
new name, renames the selected subprotocol back in the server's answer, and then passes bytes
through unchanged in both directions. A request it cannot read, or a client offering neither
name, is logged with the reason (logger ``stillpoint.live``: rate-limited and never blocking,
engine/core/ratelog.py) and left to the SDK to refuse. At most ``MAX_CLIENTS`` connections are
served at once; one more is closed at once (and logged).
"""

from __future__ import annotations

import logging
import socket
import threading
from typing import Optional

SDK_PROTOCOLS = ("foxglove.sdk.v1", "foxglove.sdk.v1.1")  # what foxglove-sdk 0.30 selects
LEGACY_PROTOCOL = "foxglove.websocket.v1"  # the older name of foxglove.sdk.v1
HEAD_LIMIT = 16384  # bytes of an HTTP upgrade request (or response) head
HANDSHAKE_TIMEOUT_S = 10.0  # for the request head to arrive, and for the SDK's answer
CHUNK = 65536
MAX_CLIENTS = 64  # connections at once (each holds two threads while it lasts); more are closed

log = logging.getLogger("stillpoint.live")


def _split_head(buf: bytes) -> Optional[int]:
    i = buf.find(b"\r\n\r\n")
    return None if i < 0 else i + 4


def _read_head(sock: socket.socket) -> tuple[bytes, bytes]:
    """(head, bytes read past it); ValueError when no complete head arrives."""
    buf = b""
    sock.settimeout(HANDSHAKE_TIMEOUT_S)
    while True:
        end = _split_head(buf)
        if end is not None:
            sock.settimeout(None)
            return buf[:end], buf[end:]
        if len(buf) > HEAD_LIMIT:
            raise ValueError(f"HTTP head longer than {HEAD_LIMIT} bytes")
        try:
            part = sock.recv(4096)
        except socket.timeout:
            raise ValueError(f"no complete HTTP request within {HANDSHAKE_TIMEOUT_S:g} s") from None
        if not part:
            raise ValueError("the connection closed before the HTTP head ended")
        buf += part


def offered_protocols(head: bytes) -> list[str]:
    """The subprotocols a WebSocket upgrade request offers (Sec-WebSocket-Protocol, any case,
    possibly over several header lines)."""
    out = []
    for line in head.decode("latin-1").split("\r\n")[1:]:
        name, sep, value = line.partition(":")
        if sep and name.strip().lower() == "sec-websocket-protocol":
            out += [v.strip() for v in value.split(",") if v.strip()]
    return out


def rename_request(head: bytes) -> tuple[bytes, bool]:
    """(request head for the SDK, whether the client speaks only the older name)."""
    offered = offered_protocols(head)
    if any(p in SDK_PROTOCOLS for p in offered) or LEGACY_PROTOCOL not in offered:
        return head, False
    lines = head.decode("latin-1").split("\r\n")
    for i, line in enumerate(lines):
        name, sep, value = line.partition(":")
        if sep and name.strip().lower() == "sec-websocket-protocol":
            vals = [v.strip() for v in value.split(",")]
            lines[i] = f"{name}: " + ", ".join(SDK_PROTOCOLS[0] if v == LEGACY_PROTOCOL else v
                                                for v in vals if v)
    return "\r\n".join(lines).encode("latin-1"), True


def rename_response(head: bytes) -> bytes:
    """The SDK's answer with the selected subprotocol given its older name again."""
    lines = head.decode("latin-1").split("\r\n")
    for i, line in enumerate(lines):
        name, sep, value = line.partition(":")
        if sep and name.strip().lower() == "sec-websocket-protocol" and \
                value.strip() in SDK_PROTOCOLS:
            lines[i] = f"{name}: {LEGACY_PROTOCOL}"
    return "\r\n".join(lines).encode("latin-1")


def _pipe(src: socket.socket, dst: socket.socket) -> None:
    try:
        while True:
            data = src.recv(CHUNK)
            if not data:
                break
            dst.sendall(data)
    except OSError:
        pass
    finally:
        for s, how in ((dst, socket.SHUT_WR), (src, socket.SHUT_RD)):
            try:
                s.shutdown(how)
            except OSError:
                pass


class ProtocolFront:
    """Listens on ``host:port`` (0: any free port) and, once started, hands each connection to
    the SDK server on ``127.0.0.1:backend_port`` as described above."""

    def __init__(self, host: str, port: int, *, what: str = "live view"):
        self.backend_port = 0
        self.what = what
        self._sock = socket.create_server((host, port))
        self.port = self._sock.getsockname()[1]
        self._conns: set = set()
        self._clients = 0  # connections being served
        self._lock = threading.Lock()
        self._closed = False
        self._thread = threading.Thread(target=self._accept_loop, name="live-front", daemon=True)

    def start(self, backend_port: int) -> None:
        """Accept connections (bound since construction) for the server on ``backend_port``."""
        self.backend_port = backend_port
        self._thread.start()

    def _accept_loop(self) -> None:
        while not self._closed:
            try:
                conn, addr = self._sock.accept()
            except OSError:
                return
            with self._lock:
                full = self._clients >= MAX_CLIENTS
                self._clients += not full
            if full:
                log.warning("%s: refusing %s: %d clients already connected", self.what, addr[0],
                            MAX_CLIENTS)
                conn.close()
                continue
            threading.Thread(target=self._serve, args=(conn, addr), name="live-front-conn",
                             daemon=True).start()

    def _track(self, *socks) -> None:
        with self._lock:
            self._conns.update(socks)

    def _serve(self, client: socket.socket, addr) -> None:
        who = f"{addr[0]}:{addr[1]}"
        backend = None
        self._track(client)
        try:
            try:
                head, rest = _read_head(client)
            except (ValueError, OSError) as e:
                log.warning("%s: handshake with %s failed: %s", self.what, who, e)
                return
            offered = offered_protocols(head)
            head, legacy = rename_request(head)
            if b"upgrade" in head.lower() and not legacy and \
                    not any(p in SDK_PROTOCOLS for p in offered):
                log.warning("%s: refusing %s: it offers the subprotocol(s) %s; stillpoint serves "
                            "%s and %s", self.what, who, ", ".join(offered) or "(none)",
                            SDK_PROTOCOLS[0], LEGACY_PROTOCOL)
            backend = socket.create_connection(("127.0.0.1", self.backend_port),
                                               timeout=HANDSHAKE_TIMEOUT_S)
            self._track(backend)
            backend.sendall(head + rest)
            try:
                answer, after = _read_head(backend)
            except (ValueError, OSError) as e:
                log.warning("%s: handshake with %s failed: the server did not answer (%s)",
                            self.what, who, e)
                return
            status = answer.split(b"\r\n", 1)[0].decode("latin-1", "replace")
            if " 101 " not in status + " ":
                log.warning("%s: handshake with %s failed: %s", self.what, who, status)
            if legacy:
                answer = rename_response(answer)
            client.sendall(answer + after)
            t = threading.Thread(target=_pipe, args=(backend, client), name="live-front-out",
                                 daemon=True)
            t.start()
            _pipe(client, backend)
            t.join()
        except OSError:
            pass
        finally:
            with self._lock:
                self._clients -= 1
            for s in (client, backend):
                if s is not None:
                    try:
                        s.close()
                    except OSError:
                        pass
                    with self._lock:
                        self._conns.discard(s)

    def close(self) -> None:
        self._closed = True
        try:
            self._sock.close()
        except OSError:
            pass
        with self._lock:
            conns = list(self._conns)
        for s in conns:
            try:
                s.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass


class FrontedServer:
    """The SDK server behind a ``ProtocolFront``: ``port`` is the front's, ``stop()`` closes
    both; everything else is the SDK server's."""

    def __init__(self, server, front: ProtocolFront):
        self._server = server
        self._front = front

    @property
    def port(self) -> int:
        return self._front.port

    def stop(self) -> None:
        self._front.close()
        self._server.stop()

    def __getattr__(self, name):
        return getattr(self._server, name)
