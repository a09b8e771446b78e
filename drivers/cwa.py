"""AX3/AX6 ``.cwa`` recordings: the public entry point (re-exports reader and writer).

* ``CwaReader`` / ``read_header`` — streaming reader (``cwa_reader``), a ``Source``.
* ``CwaWriter``, ``corrupt_sector``, ``patch_sector``, ``read_sector`` — writer and file surgery
  (``cwa_writer``).
* Layout helpers (structured dtype, timestamps, header, metadata) live in ``cwa_layout``.
"""

from __future__ import annotations

from .cwa_reader import CwaReader, read_header
from .cwa_writer import CwaWriter, corrupt_sector, fix_checksum, patch_sector, read_sector

__all__ = ["CwaReader", "read_header", "CwaWriter", "corrupt_sector", "fix_checksum", "patch_sector", "read_sector"]
