"""The ``foxglove-sdk`` package (the ``live`` extra), loaded on demand, and the server every live
view starts: loopback by default, its own SDK context (so two servers in one process never share
channels), the layout offered as the asset ``package://stillpoint/layout.json``.
"""

from __future__ import annotations

from typing import Callable, Optional

from stillpoint.engine.core.errors import StillpointError

LAYOUT_URI = "package://stillpoint/layout.json"
# Foxglove's default WebSocket connection, ws://localhost:8765 (docs.foxglove.dev/docs/sdk/websocket-server,
# "Connecting"); the protocol: github.com/foxglove/ws-protocol docs/spec.md, served by foxglove-sdk
DEFAULT_PORT = 8765
EXTRA_HINT = "pip install 'stillpoint[live]' (foxglove-sdk)"


class LiveUnavailable(StillpointError):
    """The ``live`` extra is not installed, or the server cannot start."""


def load(what: str):
    """The ``foxglove`` module, or ``LiveUnavailable`` naming the option that needs it."""
    try:
        import foxglove  # noqa: F401
        from foxglove import websocket  # noqa: F401
    except ImportError:
        raise LiveUnavailable(f"{what} needs the optional extra `live`: {EXTRA_HINT}") from None
    return foxglove


def start(fg, ctx, what: str, *, port: int, host: str = "127.0.0.1", listener=None,
          layout: Optional[Callable[[], str]] = None, time_range=None, capabilities=(),
          backlog: Optional[int] = None):
    """A WebSocket server on ``host:port`` (0: any free port) for the channels of ``ctx`` (an
    ``fg.Context()``): the SDK's server on a loopback port behind the front that also accepts
    ``foxglove.websocket.v1`` clients (engine/live/subprotocol.py). With a ``time_range`` (playback) the channels must exist before the
    server starts: the SDK advertises later ones only to a server without one."""

    def assets(uri: str):
        if layout is not None and uri == LAYOUT_URI:
            return layout().encode()
        return None

    from stillpoint.engine.core import ratelog
    for name in ("stillpoint.live", "foxglove"):  # ours and the SDK's (one line per bad client
        ratelog.install(name)                    # message): rate-limited, never blocking
    from .subprotocol import FrontedServer, ProtocolFront
    try:  # the user's address is the front's (engine/live/subprotocol.py): first, so a port in
        # use is refused before the SDK starts
        front = ProtocolFront(host, port, what=f"stillpoint {what}")
    except (OSError, ValueError, OverflowError) as e:
        raise LiveUnavailable(f"cannot serve {what} on {host}:{port}: "
                              f"{getattr(e, 'strerror', None) or e}") from None
    try:
        server = fg.start_server(name=f"stillpoint {what}", host="127.0.0.1", port=0, context=ctx,
                                 server_listener=listener, asset_handler=assets,
                                 playback_time_range=time_range, capabilities=list(capabilities),
                                 message_backlog_size=backlog)
    except Exception as e:  # the SDK raises its own error types
        front.close()
        raise LiveUnavailable(f"cannot serve {what} on {host}:{port}: {e}") from None
    front.start(server.port)
    return FrontedServer(server, front)
