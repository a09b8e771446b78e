"""Who may see and do what on the dashboard.

* The address: ``[HOST:]PORT`` (``parse_address``); the host is 127.0.0.1 unless given, the port
  0 (or omitted) asks the system for a free one.
* The token: every dashboard has one (given with ``--token`` or made here, 128 random bits,
  printed at start with the address). On a loopback address the pages can be read without it,
  if the request names a loopback host (``Host``: a page of another site whose name was made to
  point at 127.0.0.1 cannot read them); on any other address every request needs it
  (``?token=`` once, then a same-site cookie).
* Actions are POST requests whose form carries the token (the cookie alone is never enough, so
  another site cannot make a browser act); a read-only dashboard refuses every action.
* Files are served only from inside the output folder (``Records.inside``).
"""

from __future__ import annotations

import hmac
import ipaddress
import secrets
from typing import Optional

from stillpoint.drivers.errors import StillpointError

COOKIE = "stillpoint_token"


class AddressError(StillpointError):
    """A --web address that cannot be used."""


def parse_address(text: Optional[str]) -> tuple[str, int]:
    """``[HOST:]PORT`` -> (host, port); None or '' -> (127.0.0.1, 0)."""
    if not text:
        return "127.0.0.1", 0
    host, sep, port = text.rpartition(":")
    if not sep:
        host, port = "127.0.0.1", text
    host = host.strip("[]") or "127.0.0.1"
    if not port.isdigit() or int(port) > 65535:
        raise AddressError(f"--web {text}: the port must be a number from 0 to 65535 "
                           "([HOST:]PORT; 0 picks a free port)")
    return host, int(port)


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def loopback_host(header: Optional[str]) -> bool:
    """The ``Host`` header names a loopback host (``127.0.0.1:8080``, ``localhost``, ``[::1]``)."""
    h = (header or "").strip()
    if h.startswith("["):
        h = h[1:h.find("]")] if "]" in h else h
    else:
        h = h.rsplit(":", 1)[0] if h.count(":") == 1 else h
    return bool(h) and is_loopback(h)


def new_token() -> str:
    return secrets.token_urlsafe(16)


def token_ok(given: Optional[str], token: str) -> bool:
    return bool(given) and hmac.compare_digest(given.encode(), token.encode())


def cookie_token(header: Optional[str]) -> Optional[str]:
    """The token from a ``Cookie`` header, if any."""
    for part in (header or "").split(";"):
        k, _, v = part.strip().partition("=")
        if k == COOKIE:
            return v
    return None
