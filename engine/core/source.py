"""The Source interface: an iterator of Blocks plus DeviceInfo and a QC report.

Every driver (``.cwa``, ``.bin``, MCAP replay, USB device, simulator) implements this. A source
is single-pass; open it again for a second pass (batch mode reads a file twice).
"""

from __future__ import annotations

from typing import Iterator, Protocol, runtime_checkable

from .blocks import Block, DeviceInfo, QCReport


@runtime_checkable
class Source(Protocol):
    """A reader as a block source: ``info`` before iterating, ``qc`` complete after."""
    info: DeviceInfo  # available before iteration starts
    qc: QCReport  # complete once iteration has finished

    def __iter__(self) -> Iterator[Block]: ...

    def close(self) -> None:
        """Release the file or device."""
