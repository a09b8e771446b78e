"""The AX3/AX6 firmware's text rules, reproduced for the emulator: integer and date parsing, date
printing, the USB serial and the volume label.

Each rule cites the firmware source it reproduces, in repository digitalinteraction/openmovement
(mirrored as openmovementproject/openmovement), commit 144ef13 ("FW V50. 32-bit device IDs") for
``Firmware/AX3`` and ``Firmware/Flux.AX3``; ``Firmware/AX6`` at the same tree. The AX6 build
compiles ``Firmware/Flux/src/Utils/Util.c``, which is not published: its ``my_atoi`` is inferred
(see ``my_atoi_ax6``).

All values are the firmware's C types: ``unsigned long`` is 32 bits, ``int`` 16 bits (PIC24).
"""

from __future__ import annotations

import datetime as _dt

U32 = 0xFFFFFFFF

# Flux.AX3/include/Peripherals/Rtc.h 59-69: the packed DateTime and its limits
DATETIME_MIN = (1 << 22) | (1 << 17)  # DATETIME_FROM_YMDHMS(2000,1,1,0,0,0)
DATETIME_MAX = (63 << 26) | (12 << 22) | (31 << 17) | (23 << 12) | (59 << 6) | 59  # (2063,12,31,...)
# Flux.AX3/src/Peripherals/Rtc.c 51
MAX_DAYS_PER_MONTH = (0, 31, 29, 31, 30, 31, 30, 31, 31, 30, 31, 30, 31)


def my_atoi(text: str) -> int:
    """``my_atoi`` (Flux.AX3/src/Utils/Util.c 106-116): every digit of ``text`` concatenated
    (32-bit wrap), each ``-`` flips the sign; no digit and no ``-`` -> 0xFFFFFFFF; the result is
    ``unsigned long`` (``-1`` -> 4294967295)."""
    sign, value = 0, 0
    for ch in text:
        if ch == "-":
            sign = 1 if sign == 0 else sign
            sign = -sign
        elif "0" <= ch <= "9":
            sign = 1 if sign == 0 else sign
            value = (value * 10 + ord(ch) - 48) & U32
    return U32 if sign == 0 else (sign * value) & U32


def my_atoi_ax6(text: str) -> int:
    """The AX6's ``my_atoi``: as ``my_atoi`` but ending at the first non-digit after a digit.

    Inferred, not read: the AX6 parses ``RATE 74,2000`` with ``settings.sampleRate =
    my_atoi(line + 4)`` and the gyro range after the comma (AX6/Firmware/src/Settings.c 729-745),
    which only yields rate 74 if the number ends at the comma; OmApi sends ``RATE %u,%u`` to AX6
    devices and reads back ``RATE=74,100,2000``."""
    sign, value, seen = 0, 0, False
    for ch in text:
        if "0" <= ch <= "9":
            sign = 1 if sign == 0 else sign
            value = (value * 10 + ord(ch) - 48) & U32
            seen = True
        elif seen:
            break
        elif ch == "-":
            sign = 1 if sign == 0 else sign
            sign = -sign
    return U32 if sign == 0 else (sign * value) & U32


def as_int16(v: int) -> int:
    """``(int)`` of an ``unsigned long`` on the PIC24: the low 16 bits, signed."""
    v &= 0xFFFF
    return v - 0x10000 if v & 0x8000 else v


def as_char(v: int) -> int:
    """``(char)`` (signed on XC16): the low 8 bits, signed."""
    v &= 0xFF
    return v - 0x100 if v & 0x80 else v


def datetime_from_ymdhms(year: int, month: int, day: int, hours: int, minutes: int,
                         seconds: int) -> int:
    """``DATETIME_FROM_YMDHMS`` (Flux.AX3/include/Peripherals/Rtc.h 59)."""
    return ((((year % 100) & 0x3F) << 26) | ((month & 0x0F) << 22) | ((day & 0x1F) << 17)
            | ((hours & 0x1F) << 12) | ((minutes & 0x3F) << 6) | (seconds & 0x3F))


def rtc_from_string(value: str) -> int:
    """``RtcFromString`` (Flux.AX3/src/Peripherals/Rtc.c 413-469): ``""`` and ``"0"`` -> 0
    (always), a leading ``-`` -> 0xFFFFFFFF (never), six numbers with any separators -> a packed
    date/time; anything else, or an invalid date, -> 0. 29-Feb of a non-leap year -> 1-Mar.
    Numbers are 16-bit (``unsigned int v``), fields 8-bit (``unsigned char``)."""
    if value == "" or value == "0":
        return 0
    if value.startswith("-"):
        return U32
    fields = [0] * 6
    index, v = 0, 0xFFFF
    for ch in value + "\0":
        if "0" <= ch <= "9":
            if v == 0xFFFF:
                v = 0
            v = (v * 10 + ord(ch) - 48) & 0xFFFF
            continue
        if v != 0xFFFF:
            fields[index] = ((v - 2000) if (index == 0 and v >= 2000) else v) & 0xFF
            index += 1
            v = 0xFFFF
            if index >= 6:
                break
        if ch == "\0":
            break
    year, month, day, hours, minutes, seconds = fields
    if (index == 6 and 1 <= month <= 12 and 1 <= day <= MAX_DAYS_PER_MONTH[month]
            and hours <= 23 and minutes <= 59 and seconds <= 59):
        if month == 2 and day == 29 and (year & 3) != 0:
            month, day = 3, 1
        return datetime_from_ymdhms(year, month, day, hours, minutes, seconds)
    return 0


def rtc_to_string(value: int) -> str:
    """``RtcToString`` (Flux.AX3/src/Peripherals/Rtc.c 473-492): below 2000-01-01 -> ``0``,
    above 2063-12-31 23:59:59 -> ``-1``, else ``YYYY/MM/DD,hh:mm:ss`` (fields printed unchecked)."""
    if value < DATETIME_MIN:
        return "0"
    if value > DATETIME_MAX:
        return "-1"
    return (f"{2000 + ((value >> 26) & 0x3F):04d}/{(value >> 22) & 0x0F:02d}/{(value >> 17) & 0x1F:02d},"
            f"{(value >> 12) & 0x1F:02d}:{(value >> 6) & 0x3F:02d}:{value & 0x3F:02d}")


def packed_to_datetime(value: int) -> _dt.datetime:
    """A packed date/time made by ``rtc_from_string`` (always a real date) as a naive datetime."""
    return _dt.datetime(2000 + ((value >> 26) & 0x3F), (value >> 22) & 0x0F, (value >> 17) & 0x1F,
                        (value >> 12) & 0x1F, (value >> 6) & 0x3F, value & 0x3F)


def datetime_to_packed(t: _dt.datetime) -> int:
    """``RtcNow`` of a clock reading ``t`` (2000..2063; outside: clamped to the limits)."""
    if t.year < 2000:
        return DATETIME_MIN
    if t.year > 2063:
        return DATETIME_MAX
    return datetime_from_ymdhms(t.year - 2000, t.month, t.day, t.hour, t.minute, t.second)


def accel_frequency_for_rate(rate: int) -> int:
    """``ACCEL_FREQUENCY_FOR_RATE`` (Flux.AX3/include/Peripherals/Accel.h 72), integer Hz:
    3200 // 2^(15 - (rate & 0x0F)), truncated: 6.25 Hz prints 6, low nibble 0 prints 0 (``RATE=112,0``)."""
    return 3200 // (1 << (15 - (rate & 0x0F)))


# ----------------------------------------------------------------------------- identity strings
# HARDWARE_SELECT: AX3/Firmware/src/HardwareProfile.h 36 (0x17), AX6/Firmware/src/HardwareProfile.h
# 69 (0x64); printed by ID in hex, part of the USB serial and the volume label.
HARDWARE_VERSION = {"AX3": 0x17, "AX6": 0x64}
# serial prefix (AX3/Firmware/src/usb_descriptors.c 425; AX6 usb_descriptors.c 363) and label
# prefix (AX3 Settings.c 354-356; AX6 Settings.c 345-347)
_PREFIX = {"AX3": ("CWA", "AX3", HARDWARE_VERSION["AX3"]), "AX6": ("AX6", "AX6", HARDWARE_VERSION["AX6"])}
DEVICEID_UNSET = 0xFFFF  # AX3/Firmware/src/Settings.h 164


def serial_number(kind: str, device_id: int) -> str:
    """USB serial (AX3/Firmware/src/usb_descriptors.c 527-557): ``CWA17_`` + 5 digits, 7 digits
    above 99999, 10 digits above 9999999."""
    t, _, hw = _PREFIX[kind]
    head = f"{t}{hw >> 4}{hw & 0x0F}_"
    if device_id == DEVICEID_UNSET:
        return head + ",,,,,,,,,,"  # the descriptor's placeholder (line 425)
    digits = 10 if device_id > 9999999 else 7 if device_id > 99999 else 5
    return head + f"{device_id % 10 ** digits:0{digits}d}"


def volume_label(kind: str, device_id: int) -> str:
    """Volume label written by FORMAT (AX3/Firmware/src/Settings.c 352-382): ``AX317_`` + 5
    digits; above 99999 ``AX3_`` + the low 7 digits; an unset id -> ``AX317______``."""
    _, t, hw = _PREFIX[kind]
    if device_id == DEVICEID_UNSET:
        return f"{t}{hw >> 4}{hw & 0x0F}______"
    if device_id > 99999:
        return f"{t}_{device_id % 10 ** 7:07d}"
    return f"{t}{hw >> 4}{hw & 0x0F}_{device_id % 100000:05d}"
