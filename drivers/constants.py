"""Every device-specific constant, in one place, each with its source.

Sources (restated in ../shared/specs/):
* [CWA]  openmovement Docs/ax3/cwa.h, ax3-technical.md, firmware Logger.c/Settings.c (cwa-format.md)
* [GNA]  GENEActiv instruction manual "Understanding .bin files"; GENEAread/GGIRread (geneactiv-format.md)
"""

from __future__ import annotations

import numpy as np

# ----------------------------------------------------------------------------- Axivity .cwa
CWA_HEADER_BYTES = 1024  # [CWA] §2: header block is two 512-byte sectors
CWA_SECTOR_BYTES = 512  # [CWA] §2
CWA_TAG_HEADER = 0x444D  # "MD" [CWA] §2
CWA_TAG_DATA = 0x5841  # "AX" [CWA] §2
CWA_TAG_ERASED = 0xFFFF  # [CWA] §2
CWA_DATA_PACKET_LENGTH = 508  # [CWA] §5 packetLength of a data sector
CWA_SAMPLE_OFFSET = 30  # [CWA] §5: sample data starts at byte 30
CWA_SAMPLE_AREA = 480  # [CWA] §5: 480 bytes of samples per sector

# hardwareType byte [CWA] §4
CWA_HW_AX3 = (0x00, 0xFF, 0x17)
CWA_HW_AX6 = (0x64,)

# events bits [CWA] §5.4
CWA_EVENT_RESUME = 0x01
CWA_EVENT_FIFO_OVERFLOW = 0x10
CWA_EVENT_BUFFER_OVERFLOW = 0x20
CWA_EVENT_UNHANDLED_INT = 0x40

# AX6 firmware before V56 swaps accel and gyro triplets at the start of a recording [CWA] §10
CWA_AX6_AXIS_SWAP_FIXED_FIRMWARE = 56


def cwa_rate_hz(code: int) -> float:
    """Sampling frequency from the rate code: 3200 / 2^(15 - (code & 0x0F)) Hz. [CWA] §5.2"""
    return 3200.0 / (1 << (15 - (code & 0x0F)))


# rate codes 6..15 (low nibble) are the ones a data sector may carry: 6.25..3200 Hz [CWA] §5.2
CWA_RATE_RANGE_HZ = (6.25, 3200.0)


def cwa_range_g(code: int) -> int:
    """Accelerometer range from the rate code: 16 >> (code >> 6) g. [CWA] §5.2"""
    return 16 >> ((code >> 6) & 0x03)


def cwa_rate_code(rate_hz: float, range_g: int) -> int:
    """Inverse of cwa_rate_hz / cwa_range_g (used by the writer). [CWA] §5.2"""
    low = 15 - int(round(np.log2(3200.0 / rate_hz)))
    if not 6 <= low <= 15 or cwa_rate_hz(low) != rate_hz:
        raise ValueError(f"AX rate must be 3200/2^k Hz between 6.25 and 3200, got {rate_hz}")
    hi = {16: 0, 8: 1, 4: 2, 2: 3}.get(int(range_g))
    if hi is None:
        raise ValueError(f"AX range must be 2, 4, 8 or 16 g, got {range_g}")
    return (hi << 6) | low


def cwa_accel_counts_per_g(scale_code: int) -> float:
    """Accel counts per g = 2^(8 + A), A = lightScale >> 13 (0 -> 256, AX3). [CWA] §6.3"""
    return float(1 << (8 + scale_code))


def cwa_gyro_range_dps(code: int) -> float:
    """Gyro full-scale range = 8000 / 2^G dps; G = 0 on a gyro sector defaults to 2000. [CWA] §6.3"""
    return 2000.0 if code == 0 else 8000.0 / (1 << code)


def cwa_temperature_c(raw):
    """MCP9700 temperature sensor: degC = raw * 75 / 256 - 50 (10-bit ADC, 3 V reference).

    [CWA] §9 and §12.1: openmovement docs, OmApi, GGIRread, AX3 r1.7 schematic (MCP9700).
    Other readers differ: actipy 0.15*raw - 20.5 (MCP9701), skdh (raw - 171) / 3.142.
    """
    return np.asarray(raw, dtype=np.float64) * (75.0 / 256.0) - 50.0


def cwa_battery_v(b):
    """Battery volts from the stored byte: (b + 512) * 6 / 1024; b = 0 means unknown (NaN).

    [CWA] §9 and §12.2: firmware Logger.c stores clamp(ADC - 512, 0, 255).
    """
    b = np.asarray(b, dtype=np.float64)
    return np.where(b == 0, np.nan, (b + 512.0) * 6.0 / 1024.0)


def cwa_light_lux(raw):
    """AX3 light (APDS-9007, 100 kOhm load): lux = 10^((raw + 512) * 6 / 1024). [CWA] §9"""
    return np.power(10.0, (np.asarray(raw, dtype=np.float64) + 512.0) * 6.0 / 1024.0)


# ----------------------------------------------------------------------------- GENEActiv .bin
GNA_SAMPLES_PER_PAGE = 300  # [GNA] §3: 300 samples per page
GNA_HEX_PER_SAMPLE = 12  # [GNA] §5: 12 hex chars (48 bits) per sample
GNA_PAGE_LINES = 10  # [GNA] §3
GNA_PAGE_MARKER = "Recorded Data"  # [GNA] §3
GNA_ACCEL_BITS = 12  # [GNA] §5: x, y, z are 12-bit two's complement
GNA_LIGHT_SHIFT = 2  # [GNA] §5: light = low 12 bits >> 2 (10 bits)
GNA_RATE_85_7 = 600.0 / 7.0  # [GNA] §6.2: "85.7 Hz" is 300 samples per 3.5 s = 600/7 Hz


def gna_rate_hz(text: str) -> float:
    """Rate from a "Measurement Frequency" value ("85.7 Hz", "100", "85,7"). [GNA] §1, §6.2"""
    value = float(text.replace(",", ".").split()[0])
    if abs(value - 85.7) < 1e-6:
        return GNA_RATE_85_7
    return value


def gna_accel_scale(gains, offsets) -> tuple[np.ndarray, np.ndarray]:
    """(counts per g, zero in counts) of a GENEActiv header's per-axis gain and offset: the vendor's
    g = (raw * 100 - offset) / gain, written as (raw - offset / 100) / (gain / 100). [GNA] §5 (vendor
    manual, all readers)"""
    return (np.asarray(gains, np.float64) / 100.0, np.asarray(offsets, np.float64) / 100.0)


def gna_light_lux(raw, lux, volts):
    """Light in lux: raw * Lux / Volts. [GNA] §5"""
    return np.asarray(raw, dtype=np.float64) * lux / volts


# ----------------------------------------------------------------------------- real-time clocks
# [ALN] /work/shared/specs/alignment.md "Clock model" (AX datasheet; tuning-fork RTC crystals)
RTC_TOLERANCE_PPM_AX = 50.0  # [ALN] AX3/AX6 RTC: +-50 ppm typical (about +-4.3 s a day)
RTC_CRYSTAL_TURNOVER_C = 25.0  # [ALN] crystal frequency error is parabolic around ~25 degC
RTC_CRYSTAL_PARABOLA_PPM_PER_C2 = -0.035  # [ALN] about -0.035 ppm/degC^2 around the turnover
# [ALN] spread of that coefficient between crystals: tuning-fork 32.768 kHz crystal datasheets
# give -0.034 +-0.006 ppm/degC^2 (e.g. Abracon ABS07, "Parabolic coefficient"); 0.01 is wider,
# for the thermistor sitting beside the crystal rather than on it (the alignment fit's prior SD)
RTC_CRYSTAL_PARABOLA_SD_PPM_PER_C2 = 0.01

# ---------------------------------------------------------------------------- plausibility limits
# Values outside these ranges are damage, not data. Each range is generous on purpose: it only has
# to separate a real device's output from garbage (a flipped bit, an unset field, a fuzzed file).
# Sample rates: the AX3/AX6 run 6.25-3200 Hz ([CWA] rate codes), the GENEActiv 10-100 Hz (GENEActiv
# instructions manual, "Measurement Frequency"); 1-5000 Hz leaves room for both.
PLAUSIBLE_RATE_HZ = (1.0, 5000.0)
# GENEActiv header calibration (gain counts per g *100, offset counts *100): real devices hold
# gains of ~25,000 and offsets within a few thousand ([GNA] §6.3 example header); a gain of 1e6 would
# be 1,000x off.
GNA_GAIN_MAX = 1_000_000
GNA_OFFSET_MAX = 1_000_000
# GENEActiv header light calibration (lux = light_raw * Lux / Volts, [GNA] §5): the headers we have
# hold Volts:300 and Lux:800 ([GNA] §2, header lines 54-55); 0.001..1e6 for each keeps
# the 10-bit raw times Lux / Volts a finite, normal number.
GNA_LIGHT_CAL_RANGE = (1e-3, 1e6)
# Device temperature (degC) and battery (V) a page can plausibly report: the MCP9700 sensor spans
# -40..125 degC (Microchip MCP9700 datasheet); a Li-ion cell is below 5 V.
PLAUSIBLE_TEMPERATURE_C = (-40.0, 125.0)
PLAUSIBLE_BATTERY_V = (0.0, 6.0)
# Recording times: int64 nanoseconds since 1970 cover 1677-09-21..2262-04-11 (numpy datetime64[ns]);
# a time outside that cannot be represented at all. Within it, a time before 2000 or after 2100 is
# kept but logged (no device we read existed or will run then: a clock that was never set).
NS_TIME_RANGE_MS = (-9_223_372_036_854, 9_223_372_036_854)
PLAUSIBLE_YEARS = (2000, 2100)
PLAUSIBLE_TIME_NS = (946_684_800_000_000_000, 4_102_444_800_000_000_000)  # 2000-01-01, 2100-01-01 UTC

# ----------------------------------------------------------------------------- AX3/AX6 over USB
# [USB] /work/shared/specs/usb-protocols.md Part A (openmovement firmware Settings.c FW 50/56,
#       usb_descriptors.c, OmApi omapi-internal.c / omapi-devicefinder-linux.c, axconfig ax3device.mjs)
AX_USB_VID = 0x04D8  # [USB] A1: Microchip VID, normal run mode (generic composite: never enough alone)
AX_USB_PID = 0x0057  # [USB] A1
AX_MANUFACTURER = "Newcastle University"  # [USB] A1: manufacturer string (space padded)
AX_SERIAL_PREFIXES = {"CWA": "AX3", "AX6": "AX6"}  # [USB] A1: serial prefix -> device type
AX_LABEL_PREFIXES = ("AX3", "AX6")  # [USB] A1: volume label AX317_<id> / AX664_<id>
AX_DATA_FILE = "CWA-DATA.CWA"  # [USB] A1: data file in the volume root
AX_ID_TYPES = {"CWA": "AX3", "AX6": "AX6"}  # [USB] A5: first field of the ID reply
AX_MAX_LINE = 127  # [USB] A3: characters kept per input line
AX_TIMEOUT_S = 2.0  # [USB] A3: OmApi default per-command timeout (2000 ms)
AX_TIMEOUT_COMMIT_S = 6.0  # [USB] A3: COMMIT / CLEAR DATA / FORMAT QC (6000 ms)
AX_TIMEOUT_FORMAT_WIPE_S = 15.0  # [USB] A3: FORMAT WC (15000 ms)
AX_COMMIT_REMOUNT_S = 20.0  # [USB] A5/A7: drive re-insertion after a delayed activation (axconfig
#                             waits up to 8-15 s for COMMIT; we allow 20 s for the volume to return)
AX_BOOTLOADER_S = 5.0  # [USB] A1: "enumerates briefly (a few seconds) as a bootloader device"
AX_TIME_TOLERANCE_S = 2.0  # [USB] A7 step 4: echoed time within 2 s
AX_CONFIGURE_RETRIES = 3  # [USB] A7 step 11: each step retried up to 3 times, 1 s apart
AX_STREAM_HZ = 100.0  # [USB] A6: at most one line per 1/100 s of RTC time
AX_STREAM_COUNTS_PER_G_AX3 = 256.0  # [USB] A6: AX3 g = value / 256
AX_STREAM_COUNTS_PER_G_AX6 = 4096.0  # [USB] A6: AX6 accel / 4096 at the default +-8 g (open question)
AX_DATETIME_NEVER = "-1"  # [USB] A4: "-1" = never / infinitely late
AX_DATETIME_ALWAYS = "0"  # [USB] A4: "0" = always / infinitely early
# [USB] A5 closing note: factory / destructive commands the host never sends
AX_FORBIDDEN_COMMANDS = ("WRITEL", "READRAW", "WRITERAW", "ERASERAW", "FILEBLOCK", "BADBLOCK",
                         "FORMAT D", "TEST_RESULTS", "LOGFILE", "EXIT", "DEVICE ", "RESET", "CLEAR ALL",
                         "LOCK", "ILOCK", "UNLOCK")
AX_EMPTY_DATA_BYTES = 1024  # [USB] A7 step 3: axconfig: a data file > 1024 bytes still holds data
AX_LOCKED_ECHO_S = 0.5  # [USB] A5 / conformance spec §1: after "ERROR: Locked." a setter prints
#                         "<KEY>=<old>" at once (Settings.c); wait this long for it
# Battery percentage from the raw ADC when the device reports 0 % (older firmware does not compute
# it): OmApi src/omapi-status.c 131-205 (libomapi @ 158e46b, AdcBattToPercentStatus, used by
# OmGetBatteryLevel when parts[4] is 0): 12 counts of charging current off, <= 614 -> 0 %, > 708 ->
# 100 %, a two-piece fit between (above 666: 150 * (adc - 538) >> 8; else 375 * (adc - 614) >> 8).
AX_BATT_ADC_CHARGE_COMPENSATION = 12
AX_BATT_ADC_ZERO = 614
AX_BATT_ADC_FULL = 708
AX_BATT_ADC_FIT = ((666, 150, 538, 8), (614, 375, 614, 8))  # (above, scale, offset, shift)


def ax_battery_pct_from_adc(adc: int) -> int:
    """The battery percentage OmApi models from the raw ADC reading (see the constants above)."""
    v = adc - AX_BATT_ADC_CHARGE_COMPENSATION if adc > AX_BATT_ADC_CHARGE_COMPENSATION else adc
    if v > AX_BATT_ADC_FULL:
        return 100
    if v < AX_BATT_ADC_ZERO:
        return 0
    for above, scale, offset, shift in AX_BATT_ADC_FIT:
        if v > above:
            return (scale * (v - offset)) >> shift
    return 0


AX_STREAM_STOP_S = 5.0  # [USB] A6: OmApi gives up flushing a running stream after 5 s

# ----------------------------------------------------------------------------- AX3/AX6 data file identity
# How each firmware writes the device id into the data file header ([FW] below):
# AX3 (V50, "FW V50. 32-bit device IDs", commit 144ef13) keeps only the low 16 bits and leaves the
# upper word (bytes 11-12) erased: Firmware/AX3/Firmware/src/Logger.c 447-448
# `SET_WORD(loggerBuffer + 5, settings.deviceId)`. AX6 writes both words:
# Firmware/AX6/Firmware/src/Logger.c 538-540. 0xFFFF in the upper word means "not written".
CWA_UPPER_ID_UNSET = 0xFFFF

# ----------------------------------------------------------------------------- what an AX3/AX6 can record
# The settings each device type can record. A setting outside these is accepted and echoed by the
# firmware but records nothing, so the station refuses it when a study profile loads and again when a
# device is configured. Sources (one row each):
# [FW]    digitalinteraction/openmovement @ 5df5c9101ffc5b0bcd55853db5b281e7adefda21
# [OMGUI] openmovementproject/openmovement Software/OM/omgui (the vendor's desktop UI)
# [AXCFG] openmovementproject/openmovement-axconfig @ 5c85e6f5382a19a5e32e092a30f410dd2747b500
# (restated with the lines quoted in ../shared/specs/ax-firmware-conformance.md §2.3)
#
# The device rule table: one row per rule, a value per device type, and its source.
#   rule              AX3             AX6                              source
AX_DEVICE_RULES = (
    ("rate_hz", (12.5, 3200.0), (6.25, 1600.0),
     # AX3 records packed (DATAMODE 18, the firmware default; stillpoint never sets another) and
     # packed below 12.5 Hz is refused: [OMGUI] DateRangeForm.cs 818-830 "not supported by
     # firmware in packed mode"; [AXCFG] src/js/ax3device.mjs 711-718 "minimum rate of 12.5Hz in
     # packed mode.". AX6: the IMU set-up has no 3200 Hz case ([FW] Firmware/AX6/Firmware/src/
     # IMU-BMI160.c 193-266, "default: settingCheck = 0"); [OMGUI] DateRangeForm.cs 818-830 "not
     # supported by device" (> 1600 Hz); [AXCFG] ax3device.mjs 711-718 "maximum rate of 1600Hz."
     "DateRangeForm.cs 818-830; ax3device.mjs 711-718; IMU-BMI160.c 193-266"),
    ("gyro_dps", (), (125, 250, 500, 1000, 2000),
     # the AX3 has no gyroscope; the AX6 IMU accepts these full-scale ranges: [FW] IMU-BMI160.c
     # 193-266, `switch(imu_gyro_range)` cases 125..2000, any other: settingCheck = 0
     "IMU-BMI160.c 193-266"),
    ("gyro_min_rate_hz", None, 25.0,
     # [FW] IMU-BMI160.c 193-266, rate cases 1-13 (up to 12.5 Hz): `if(imu_gyro_range != 0)
     # settingCheck = 0;`; [OMGUI] DateRangeForm.cs 818-830 "not supported with gyro"; [AXCFG]
     # ax3device.mjs 711-718 "minimum rate of 25Hz with the gyroscope enabled."
     "IMU-BMI160.c 193-266; DateRangeForm.cs 818-830; ax3device.mjs 711-718"),
    ("session_max", 2**31 - 1, 2**31 - 1,
     # the header field is u32 (the firmware wraps at 2^32), the vendor's UI stops at 2^31 - 1:
     # [OMGUI] DateRangeForm.Designer.cs `numericUpDownSessionID.Maximum = 2147483647`
     "DateRangeForm.Designer.cs numericUpDownSessionID.Maximum"),
    ("annotation", (14, 32), (14, 32),
     # slots x characters: [FW] Firmware/AX3/Firmware/src/Settings.c ANNOTATEnn (`nn >= 14` ->
     # "ERROR: Invalid annotation id N"; each slot printed as 32 characters; conformance spec §1)
     "Settings.c ANNOTATEnn"),
    ("years", (2000, 2063), (2000, 2063),
     # start/stop a device can hold: the packed timestamp's year is 6 bits from 2000 ([CWA] §3);
     # [OMGUI] DateRangeForm.Designer.cs date pickers MinDate 2000-03-01, MaxDate 2063-12-31
     "cwa-format.md §3; DateRangeForm.Designer.cs MaxDate"),
)
AX_RULES = {kind: {row[0]: row[1 + k] for row in AX_DEVICE_RULES}
            for k, kind in enumerate(("AX3", "AX6"))}  # AX_RULES["AX6"]["rate_hz"] == (6.25, 1600.0)
AX_GYRO_DEVICE_TYPES = tuple(k for k, r in AX_RULES.items() if r["gyro_dps"])
AX_SESSION_MAX = AX_RULES["AX3"]["session_max"]
# "Never record": the firmware logs only while start < stop ([FW] Firmware/AX3/Firmware/src/main.c
# 516-529, RunLogging: start >= stop -> no logging). The vendor's clear sets HIBERNATE -1, STOP -1
# and SESSION 0 before erasing ([OMGUI] Software/OM/omapinet/OmDevice.cs 610-625, "Never log").
AX_NEVER_LOG = (("HIBERNATE", "-1"), ("STOP", "-1"), ("SESSION", "0"))
# Erase levels: FORMAT QC (quick: filesystem, label and every file rebuilt, then the data file
# re-created from the settings) or FORMAT WC (the NAND wiped first). [OMGUI] OmDevice.cs 610-625;
# OmApi include/omapi.h 741 (`OmClearDataAndCommit` is QUICKFORMAT); [AXCFG] default `FORMAT WC`.
AX_ERASE_COMMANDS = {"quick": "FORMAT QC", "wipe": "FORMAT WC"}
# FORMAT's reply: "FORMAT: Delayed activation.", then "FORMAT: Complete." (or "ERROR: Problem during
# ... format"), then "COMMIT" ([FW] Settings.c SettingsAction, FORMAT with C).
AX_FORMAT_COMPLETE = "FORMAT: Complete."

# ----------------------------------------------------------------------------- ActiGraph .gt3x
# [GT3X]   actigraph/GT3X-File-Format @ d4aa795 (MIT): README.md, info.txt.md, LogRecords/*.md
# [NHANES] actigraph/NHANES-GT3X-File-Format @ 2fcafc6 (MIT): README.md, technical.md, fileformats/*.md
# [ALF]    ActiLife's own raw CSV exports checked against public files (data/real/PROVENANCE.md,
#          "Facts a reader needs beyond the format description"; pygt3x tests/test_ism.py for the
#          idle-sleep fill; rows of actigraph_pygt3x_neo_30hz_legacy.actilife.csv)
GT3X_LOG_MEMBER = "log.bin"  # [GT3X] README.md 31: log records
GT3X_INFO_MEMBER = "info.txt"  # [GT3X] README.md 35; [NHANES] README.md 74
GT3X_ACTIVITY_MEMBER = "activity.bin"  # [NHANES] README.md 44: legacy 12-bit sample stream
GT3X_LUX_MEMBER = "lux.bin"  # [NHANES] README.md 86: legacy light, one u16 per second
GT3X_SEPARATOR = 0x1E  # [GT3X] README.md 65: every record starts with 0x1E
GT3X_HEADER_BYTES = 8  # [GT3X] README.md 62-88: separator, type, u32 time (LE), u16 size (LE)
GT3X_CHECKSUM_OK = 0xFF  # [GT3X] README.md 100, 302-313: checksum = ~XOR(header+payload), so the
#                          XOR over a whole record including its checksum byte is 0xFF
# record types [GT3X] README.md 158-265
GT3X_REC_ACTIVITY = 0x00  # 158-163: one second, 12-bit, YXZ
GT3X_REC_BATTERY = 0x02  # 164-169: u16 millivolts
GT3X_REC_EVENT = 0x03  # 170-175: idle sleep enter 0x08 / exit 0x09
GT3X_REC_LUX = 0x05  # 182-187: u16 lux
GT3X_REC_METADATA = 0x06  # 188-193: JSON
GT3X_REC_PARAMETERS = 0x15  # 242-247
GT3X_REC_SENSOR_SCHEMA = 0x18  # 248-253 (IMU; read for its size only, data skipped)
GT3X_REC_SENSOR_DATA = 0x19  # 254-259
GT3X_REC_ACTIVITY2 = 0x1A  # 260-265: one second, int16 LE, XYZ
GT3X_EVENT_IDLE_ENTER = 0x08  # [GT3X] README.md 174
GT3X_EVENT_IDLE_EXIT = 0x09  # [GT3X] README.md 174
GT3X_USB_PAYLOAD_BYTES = 1  # [GT3X] LogRecords/Activity.md 23-24, Activity2.md 14-15: a 1-byte
#                             ACTIVITY/ACTIVITY2 payload is a USB-connect record, not samples
GT3X_BITS_PER_SAMPLE = 36  # [GT3X] LogRecords/Activity.md 6; [NHANES] README.md 117
# PARAMETERS record: 8-byte (u16 address space, u16 id, u32 value) pairs, LE [GT3X]
# LogRecords/Parameters.md 9; floats in the 24-bit fraction / 8-bit exponent code, 11 and 36-62
GT3X_PARAM_ACCEL_SCALE = (0, 55)  # Parameters.md 517-523 (example 237-238: 256 LSB/g)
GT3X_PARAM_BATTERY_VOLTAGE = (0, 7)  # Parameters.md 399-405
GT3X_PARAM_FIRMWARE_VERSION = (0, 13)  # Parameters.md 426-432: (major<<24)|(minor<<16)|build
GT3X_PARAM_FEATURE_ENABLE = (1, 2)  # Parameters.md 564-579
GT3X_FEATURE_SLEEP_MODE_BIT = 2  # Parameters.md 572: "Bit 2 = Sleep Mode"
GT3X_PARAM_UTC_OFFSET = (1, 40)  # Parameters.md 798-805: seconds (often 0; info.txt TimeZone wins)
# Accelerometer scale (LSB/g) when neither info.txt "Acceleration Scale" nor the PARAMETERS
# ACCEL_SCALE gives one: [GT3X] LogRecords/Activity.md 20, Activity2.md 11 ("NEO and CLE use 341
# LSB/g (+-6g). MOS devices use 256 LSB/g (+-8g)"); [NHANES] fileformats/activity.bin.md 24 (341).
# device model by serial prefix (info.txt "Device Type" names), when info.txt has no Device Type:
# [GT3X] README.md 9-16; [NHANES] README.md 16
GT3X_MODEL_BY_SERIAL_PREFIX = (("MOS0", "wGT3XBT"), ("MOS2", "wGT3XBT"), ("MOS3", "wActiSleepPlus"),
                               ("MOS4", "wActiSleepBT"), ("NEO", "GT3XPlus"), ("MRA", "ActiSleepPlus"),
                               ("CLE", "wGT3XPlus"), ("TAS", "Link"))
GT3X_SCALE_BY_SERIAL_PREFIX = {"NEO": 341.0, "CLE": 341.0, "MRA": 341.0, "MOS": 256.0}
GT3X_RANGE_BY_SCALE = {341.0: 6.0, 256.0: 8.0}  # [GT3X] Activity.md 20: 341 -> +-6 g, 256 -> +-8 g
# wGT3X-BT firmware 1.6.0 turns the axes 90 degrees about Z: fixed x = y, fixed y = -x
# [GT3X] LogRecords/Activity.md 26-37
GT3X_AXIS_SWAP_SERIAL_PREFIX = "MOS"
GT3X_AXIS_SWAP_FIRMWARE = "1.6.0"
# info.txt times are .NET ticks (100 ns since 0001-01-01) of the device's local clock
# [GT3X] info.txt.md 39-55; [NHANES] technical.md 9-13, 21
GT3X_TICKS_PER_S = 10_000_000
GT3X_TICKS_AT_UNIX_EPOCH = 621_355_968_000_000_000  # 1970-01-01T00:00:00 in .NET ticks
# legacy lux.bin [NHANES] fileformats/lux.bin.md 7-30: < 20 -> 0, 0xFFFF -> 0, scale and maximum
# by device (GT3X+ 1.25 / 2500 lux, ActiSleep+ 3.25 / 6000 lux)
GT3X_LUX_MIN_RAW = 20
GT3X_LUX_INVALID = 0xFFFF
GT3X_LUX_SCALE_BY_SERIAL_PREFIX = {"NEO": (1.25, 2500.0), "MRA": (3.25, 6000.0)}
# ActiLife's raw CSV [ALF]: every value is stored integer / scale rounded half away from zero to
# 3 decimals; idle-sleep seconds repeat the last sample; other missing seconds (after a USB-connect
# record, and from the last record to the download time) are zeros.
GT3X_ACTILIFE_DECIMALS = 3
# A scale (LSB/g) outside this range is damage: real devices store 341 (GT3X+), 256 (wGT3X-BT,
# GT9X) and 2048 (GT9X IMU) ([GT3X] Activity.md 20, Parameters.md 225-238)
GT3X_PLAUSIBLE_SCALE = (1.0, 100_000.0)
