"""Atomic outputs live in the core layer (``engine/core/outputs.py``); this name is kept for code
written against the drivers' path."""

from stillpoint.engine.core.outputs import *  # noqa: F401,F403
