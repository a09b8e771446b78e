"""The station's web dashboard: the dock live in a browser, each device's history from the ledger,
a printable handover sheet, and actions (retry, verify, clear, configure) guarded by a token.

Standard library only (``http.server``); pages drawn on the server (HTML and SVG), one small
script of our own for the live stream (server-sent events) and the confirmations. Modules:
``server`` (HTTP), ``pages`` (HTML), ``charts`` (SVG trends), ``records`` (ledger reads),
``live`` (the station listener), ``actions`` (what a POST may do), ``access`` (address, token).
See docs/dashboard.md.
"""

from .server import Dashboard  # noqa: F401
