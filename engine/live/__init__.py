"""Live views in Foxglove over its WebSocket protocol (the optional ``live`` extra,
``foxglove-sdk``): a logged MCAP played back with playback control (``playback``), the
station's devices live (``station``), a device's STREAM preview live (``preview``), the layouts
generated from the topics (``layouts``) and a reader that follows an MCAP while it is written
(``follow``). The log of record is always our own MCAP writer (engine/mcap); these modules only
serve what it wrote or what a device reports.

Modules import ``foxglove`` only through ``sdk.load()``: without the extra a command says so in
one line (exit code 2).
"""
