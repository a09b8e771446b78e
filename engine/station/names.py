"""The names of the files a download leaves in the station's output folder (one pattern each).

``<stem>`` is ``<type>-<device id>_<session>`` (``AX3-10001_1``): the device type is part of it
because an AX3 and an AX6 may carry the same id and session. Outputs of older versions
(``<device id>_<session>.cwa``) stay where their ledger rows say and are still found by them.

=================================  ===================================================  ==========================
pattern                            meaning                                              what to do
=================================  ===================================================  ==========================
``<stem>.cwa``                     the verified raw copy (ledger row ``verified``)      keep: the record of truth
``<stem>.mcap``                    the corrected log of that copy                       keep
``<stem>.cwa.part``                a copy being downloaded or interrupted               nothing: the next download
                                                                                        reuses its verified prefix
``<stem>.unverified.mcap``         the corrected log of a copy not yet verified         nothing: renamed to
                                                                                        ``<stem>.mcap`` or rebuilt
``<stem>.unverified.mcap.part``    that log while it is written                         nothing: rebuilt
``<stem>.cwa.part.<UTC>[-n]``      an earlier partial copy that differs from the        keep until checked;
                                   device (set aside, never deleted)                    ``stillpoint clean OUT``
                                                                                        lists the ones a verified
                                                                                        copy supersedes
``<stem>.epochs.csv.gz``            the epoch table of the verified download             keep
``<stem>.days.csv``                 the day table of the verified download               keep
``<stem>.nights.csv``               its nights table (sleep, in the study's zone)        keep
``<stem>.report.png`` / ``.html``   the one-page report of the verified download         keep
``*.part.<UTC>[-n]`` (other)       a partial output of a killed writer, set aside       as above
=================================  ===================================================  ==========================
"""

from __future__ import annotations

import re
from pathlib import Path

from stillpoint.engine.core.outputs import set_aside_name  # noqa: F401  (the one rule for set-aside names)

RAW = ".cwa"
LOG = ".mcap"
PART = ".part"
UNVERIFIED_LOG = ".unverified.mcap"

# what ``stillpoint clean`` considers a set-aside partial file: ``<name>.part.<UTC stamp>[-n]``
SET_ASIDE_RE = re.compile(r"^(?P<name>.+)\.part\.(?P<stamp>\d{8}T\d{6}Z)(?:-\d+)?$")


def stem(device_type: str, device_id: int, session_id: int) -> str:
    """``AX3-10001_1``: the device type, id and session of one download."""
    return f"{device_type}-{device_id}_{session_id}"


def raw_copy(out, stem_: str) -> Path:
    return Path(out) / f"{stem_}{RAW}"


def raw_part(out, stem_: str) -> Path:
    return Path(out) / f"{stem_}{RAW}{PART}"


def log_final(out, stem_: str) -> Path:
    return Path(out) / f"{stem_}{LOG}"


def log_unverified(out, stem_: str) -> Path:
    """Where the pipeline writes while the copy is not verified (its own ``.part`` while open)."""
    return Path(out) / f"{stem_}{UNVERIFIED_LOG}"


# every name a download or the ledger leaves in the output folder, with what it is
KINDS = (
    ("ledger", re.compile(r"^stillpoint-ledger\.sqlite(-wal|-shm|-journal)?$")),
    ("station lock", re.compile(r"^\.stillpoint-station\.lock$")),
    ("set aside", SET_ASIDE_RE),
    ("partial copy", re.compile(r"^(?!.*\.part\.)(?P<stem>.+)\.cwa\.part$")),
    ("unverified log, being written", re.compile(r"^(?!.*\.part\.)(?P<stem>.+)\.unverified\.mcap\.part$")),
    ("unverified log", re.compile(r"^(?P<stem>.+)\.unverified\.mcap$")),
    ("raw copy", re.compile(r"^(?!.*\.part)(?P<stem>.+)\.cwa$")),
    ("corrected log", re.compile(r"^(?!.*\.part)(?P<stem>.+)\.mcap$")),
    ("epoch table", re.compile(r"^(?!.*\.part)(?P<stem>.+)\.epochs\.csv\.gz$")),
    ("day table", re.compile(r"^(?!.*\.part)(?P<stem>.+)\.days\.csv$")),
    ("nights table", re.compile(r"^(?!.*\.part)(?P<stem>.+)\.nights\.csv$")),
    ("report", re.compile(r"^(?!.*\.part)(?P<stem>.+)\.report\.(png|html)$")),
)


def kind_of(name: str):
    """Which documented pattern ``name`` follows (``KINDS``), or None (a doubled ``.part.part``
    follows none)."""
    if ".part.part" in name:
        return None
    for kind, rx in KINDS:
        if rx.match(name):
            return kind
    return None
