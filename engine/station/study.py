"""Study records: the file names a study asks for and the short code of a whole device setting.

**File-name template** (``[station] file_name`` in the profile), e.g.
``"{study}_{subject}_{device}_{session}"``: the stem of a download's raw copy and corrected log
(``<stem>.cwa``, ``<stem>.mcap``) instead of ``<type>-<id>_<session>``. Fields: ``{device}``
(``AX3-10001``), ``{session}`` and any key of the metadata the device was configured with
(``{subject}``, entered or scanned at configure time; ``{study}``, ``{site}``, ... from the
profile's ``[metadata]``), as recorded in the ledger's configuration row of that device and
session; the profile's own metadata when the ledger has none. ``{device}`` and ``{session}`` are
required (two downloads never share a name). Every value goes through ``safe_name_part``
(letters, digits, ``.``, ``_``, ``-``; anything else replaced and tagged with a digest); a field
without a value is ``none``.

**Setting code**: one short line for a whole device setting, typed or scanned (a barcode scanner
types like a keyboard), in the spirit of AX-Deploy's scanned codes::

    SP1_<rate Hz>_<range g>_<gyro dps>_<start>_<stop>_<session>_<min battery %>[_F]

``start``: ``0`` (when unplugged), ``+<n>[mhd]`` or a local ISO time; ``stop``: ``-1`` (never),
``+<n>[mhd]`` after the start, or a local ISO time; ``session``: ``inc`` (previous + 1), ``keep``
or a number; ``F``: the LED flashes while recording. E.g. ``SP1_100_8_0_+1h_+8d_inc_80`` is 100 Hz,
±8 g, no gyro, start in an hour, record 8 days, the next session, at least 80 % battery. The code
is checked by the profile's own rules (``StudyProfile.check``) before any device is touched.
"""

from __future__ import annotations

import dataclasses
import re
from typing import Optional

from stillpoint.drivers.errors import StillpointError
from stillpoint.drivers.names import safe_name_part

from . import names

_FIELD = re.compile(r"\{([a-z][a-z0-9_]{0,30})\}")
_LITERAL = re.compile(r"^[A-Za-z0-9._-]*$")
CODE_PREFIX = "SP1"


class StudyRecordError(StillpointError):
    """A file-name template or a setting code that cannot be used."""


def check_template(template: str, where: str = "file_name") -> None:
    """Refuse a template whose literal text is not safe in a file name or that lacks
    ``{device}`` or ``{session}``."""
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
    return _FIELD.sub(lambda m: safe_name_part(values.get(m.group(1)), fallback="none"), template)


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


# ---------------------------------------------------------------------- setting codes
def setting_code(profile) -> str:
    """The setting code of a profile's device settings (module docstring)."""
    session = {"increment": "inc"}.get(profile.session, profile.session)
    parts = [CODE_PREFIX, f"{profile.rate_hz:g}", str(profile.range_g), str(profile.gyro_dps),
             profile.start, profile.stop, session, str(profile.min_battery_pct)]
    return "_".join(parts) + ("_F" if profile.led_flash else "")


def profile_from_code(code: str, base=None):
    """A ``StudyProfile``: ``base``'s (metadata, device type, station options) with the device
    settings of ``code``; checked by the profile's rules. ``StudyRecordError`` names what is
    wrong."""
    from .profile import ProfileError, StudyProfile
    text = code.strip()
    parts = text.split("_")
    if not parts or parts[0] != CODE_PREFIX or len(parts) not in (8, 9) or \
            (len(parts) == 9 and parts[8] != "F"):
        raise StudyRecordError(f"setting code {text[:60]!r}: expected {CODE_PREFIX}_<rate>_<range>_"
                               "<gyro>_<start>_<stop>_<session>_<min battery>[_F]")
    _, rate, rng, gyro, start, stop, session, batt = parts[:8]
    try:
        rate_hz, range_g, gyro_dps, min_batt = float(rate), int(rng), int(gyro), int(batt)
    except ValueError:
        raise StudyRecordError(f"setting code {text[:60]!r}: rate, range, gyro and battery must be "
                               "numbers") from None
    session = {"inc": "increment"}.get(session, session)
    prof = dataclasses.replace(base if base is not None else StudyProfile(), rate_hz=rate_hz,
                               range_g=range_g, gyro_dps=gyro_dps, start=start, stop=stop,
                               session=session, min_battery_pct=min_batt,
                               led_flash=len(parts) == 9, path=f"setting code {text[:60]}")
    try:
        prof.check()
    except ProfileError as e:
        raise StudyRecordError(str(e)) from None
    return prof
