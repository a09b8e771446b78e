"""The typed errors of unreadable input live in the core layer (``engine/core/errors.py``); this
name is kept for code written against the drivers' path."""

from stillpoint.engine.core.errors import (CorruptRecordingError, RecordingError,  # noqa: F401
                                           StillpointError, TruncatedRecordingError,
                                           UnsupportedFormatError)
