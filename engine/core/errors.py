"""Typed errors for unreadable input. Every message names the file and what was wrong.

The CLI turns any ``StillpointError`` into exit code 2 and one line on stderr.
"""

from __future__ import annotations

from typing import Optional


class StillpointError(Exception):
    """Base class of every error the CLI reports as a one-line message (exit code 2)."""


class RecordingError(StillpointError, ValueError):
    """A recording could not be read. ``path`` names the file, ``where`` the sector/page/offset."""

    def __init__(self, path, message: str, where: Optional[str] = None):
        self.path = str(path) if path is not None else None
        self.where = where
        self.message = message
        loc = f" ({where})" if where else ""
        prefix = f"{self.path}{loc}: " if self.path else (f"{where}: " if where else "")
        super().__init__(prefix + message)


class UnsupportedFormatError(RecordingError):
    """The file is not a format we read (e.g. the original GENEA, a text file named .cwa)."""


class CorruptRecordingError(RecordingError):
    """The file claims a supported format but nothing (or its header) is readable."""


class TruncatedRecordingError(RecordingError):
    """The file ends before a structure that must be complete (e.g. the header)."""
