"""The setting code: one short line for a whole device setting, typed or scanned (a barcode scanner
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

from .profile import ProfileError, StudyProfile
from .study import StudyRecordError

CODE_PREFIX = "SP1"


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
