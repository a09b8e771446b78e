"""Who may see and do what on the dashboard.

* The address: ``[HOST:]PORT`` (``parse_address``); the host is 127.0.0.1 unless given, the port
  0 (or omitted) asks the system for a free one.
* The token: every dashboard has one (given with ``--token`` or made here, 192 random bits,
  printed at start with the address); a given one is refused for an address other than
  loopback when it is shorter than ``TOKEN_MIN_CHARS`` or its entropy estimate is below
  ``TOKEN_MIN_BITS``. On a loopback address the pages can be read without it,
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

from stillpoint.engine.core.errors import StillpointError

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
    if not (port.isascii() and port.isdigit()) or len(port) > 5 or int(port) > 65535:
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


# a token for a network bind: at least this long, and at least TOKEN_MIN_BITS by the estimate of
# ``token_bits`` (a generated one: 32 characters of the URL-safe base64 alphabet, 192 random bits;
# OWASP's session-identifier guidance asks for 64 bits of entropy at least)
TOKEN_MIN_CHARS = 16
TOKEN_MIN_BITS = 64.0
TOKEN_BYTES = 24


class TokenError(StillpointError):
    """A --token too short or too predictable for a dashboard on a network address."""


def new_token() -> str:
    return secrets.token_urlsafe(TOKEN_BYTES)


def token_bits(token: str) -> float:
    """A conservative estimate of a token's entropy in bits: its length times the Shannon entropy
    of its own characters (``aaaa...`` is 0, a repeated short word little)."""
    import math
    from collections import Counter
    n = len(token)
    if not n:
        return 0.0
    h = -sum(c / n * math.log2(c / n) for c in Counter(token).values())
    return n * h


def check_token(token: str, where: str) -> None:
    """Refuse a given token that is too short or predictable for a network address."""
    if len(token) < TOKEN_MIN_CHARS or token_bits(token) < TOKEN_MIN_BITS:
        raise TokenError(f"{where}: --token is too guessable for an address other than loopback "
                         f"(at least {TOKEN_MIN_CHARS} characters and {TOKEN_MIN_BITS:g} bits "
                         "of entropy; leave --token out to get a random one)")


def token_ok(given: Optional[str], token: str) -> bool:
    return bool(given) and hmac.compare_digest(given.encode(), token.encode())


def cookie_token(header: Optional[str]) -> Optional[str]:
    """The token from a ``Cookie`` header, if any."""
    for part in (header or "").split(";"):
        k, _, v = part.strip().partition("=")
        if k == COOKIE:
            return v
    return None
