"""Study records: the file names a study asks for.

**File-name template** (``[station] file_name`` in the profile), e.g.
``"{study}_{subject}_{device}_{session}"``: the stem of a download's raw copy and corrected log
(``<stem>.cwa``, ``<stem>.mcap``) instead of ``<type>-<id>_<session>``. Fields: ``{device}``
(``AX3-10001``), ``{session}`` and any key of the metadata the device was configured with
(``{subject}``, entered or scanned at configure time; ``{study}``, ``{site}``, ... from the
profile's ``[metadata]``), as recorded in the ledger's configuration row of that device and
session; the profile's own metadata when the ledger has none. ``{device}`` and ``{session}`` are
required (two downloads never share a name). Every value goes through ``safe_name_part``
(letters, digits, ``.``, ``_``, ``-``; anything else replaced and tagged with a digest); a field
without a value (a device this station did not configure has no ``{subject}``) is named for
what is missing: ``no-subject``, ``no-study``.

The short code of a whole device setting is ``setting_code.py``.
"""

from __future__ import annotations

import re
from typing import Optional

from stillpoint.engine.core.errors import StillpointError
from stillpoint.drivers.names import safe_name_part

from . import names

_FIELD = re.compile(r"\{([a-z][a-z0-9_]{0,30})\}")
_LITERAL = re.compile(r"^[A-Za-z0-9._-]*$")


class StudyRecordError(StillpointError):
    """A file-name template or a setting code that cannot be used."""


# the longest file_name template: a file name holds 255 bytes, and each field's value adds to it
MAX_TEMPLATE_CHARS = 120


def check_template(template: str, where: str = "file_name") -> None:
    """Refuse a template whose literal text is not safe in a file name or that lacks
    ``{device}`` or ``{session}``."""
    if len(template) > MAX_TEMPLATE_CHARS:
        raise StudyRecordError(f"{where} {template[:40]!r}...: {len(template):,} characters, at most "
                               f"{MAX_TEMPLATE_CHARS} (a file name holds 255 bytes)")
    fields = _FIELD.findall(template)
    literal = _FIELD.sub("", template)
    if not _LITERAL.match(literal) or "{" in literal or "}" in literal:
        raise StudyRecordError(f"{where} {template[:80]!r}: only letters, digits, '.', '_', '-' "
                               "and {fields} (lower-case names) are allowed")
    for need in ("device", "session"):
        if need not in fields:
            raise StudyRecordError(f"{where} {template[:80]!r} must contain {{{need}}} (two "
                                   "downloads would otherwise share a name)")


def file_stem(template: Optional[str], *, device_type: str, device_id: int, session: int,
              metadata: Optional[dict] = None) -> str:
    """The stem of a download's files: the template filled in (module docstring), or the
    station's own ``<type>-<id>_<session>`` without one."""
    if not template:
        return names.stem(device_type, device_id, session)
    check_template(template)
    values = {str(k): v for k, v in (metadata or {}).items()}
    values.update(device=f"{device_type}-{device_id}", session=str(session))
    return _FIELD.sub(lambda m: safe_name_part(values.get(m.group(1)),
                                               fallback=missing_value(m.group(1))), template)


def missing_value(field: str) -> str:
    """The file-name part of a template field without a value, named for what is missing
    (``no-subject``)."""
    return f"no-{field}"


def download_stem(profile, ledger, device_type: str, device_id: int, session: int) -> str:
    """``file_stem`` for a download, with the metadata the ledger's configuration of this device
    and session recorded (the subject id given at configure), else the profile's."""
    template = getattr(profile, "file_name", None) if profile is not None else None
    if not template:
        return names.stem(device_type, device_id, session)
    meta = dict(getattr(profile, "metadata", {}) or {})
    settings = ledger.configuration_of(device_id, session, device_type)
    if settings:
        meta.update(settings.get("metadata") or {})
    return file_stem(template, device_type=device_type, device_id=device_id, session=session,
                     metadata=meta)
