"""Byte-level probes: the emulator answers every firmware command with the bytes the AX3/AX6
firmware source prints.

Each row is (device type, request bytes, expected reply bytes, source). The expected bytes are
written from the firmware source, not from the emulator: the ``printf`` formats of
``SettingsCommand`` and the parsing rules it calls (``my_atoi``, ``RtcFromString``,
``RtcToString``). Sources are in digitalinteraction/openmovement at commit 144ef13 (FW V50):
``S3`` = Firmware/AX3/Firmware/src/Settings.c, ``S6`` = Firmware/AX6/Firmware/src/Settings.c,
``U`` = Firmware/Flux.AX3/src/Utils/Util.c, ``R`` = Firmware/Flux.AX3/src/Peripherals/Rtc.c,
``M3`` = Firmware/AX3/Firmware/src/main.c, ``F`` = Firmware/Flux.AX3/src/Ftl/Ftl.c.

Every row runs on a freshly booted device (a copy of one simulated recording, AX3 id 12345 or
AX6 id 601234, session 1 in the header, restart counter 3, battery health 12) through its
pseudo-terminal, as a host program would talk to a real device: the request bytes are written to
the pty, the reply is read until it is complete and the port has been quiet for a moment.
"""

from __future__ import annotations

import os
import select
import time

import pytest

from stillpoint.drivers.ax.emulator import EmulatedDevice
from stillpoint.engine.sim.record import simulate_recording

IDS = {"AX3": 12345, "AX6": 601234}
QUIET_S = 0.15  # the reply is over when nothing more comes for this long
DELAYED_S = 3.0  # delayed activation completes within this (remount_s 0.05 per countdown tick)

SPACES29 = b" " * 29
ROWS = [
    # ---- identity, status (one line per STATUS n)
    ("AX3", b"ID\r", b"ID=CWA,17,50,12345,1\r\n", "S3 458-461 (%x hardware, %u firmware, %lu id/session)"),
    ("AX6", b"ID\r", b"ID=AX6,64,56,601234,1\r\n", "S6 449-452 (HARDWARE_LABEL AX6, version 0x64, 56)"),
    ("AX3", b"id\r", b"ID=CWA,17,50,12345,1\r\n", "U 170-183 strnicmp: keywords are case-insensitive"),
    ("AX3", b" ID\r", b"ERROR: Unknown command:  ID\r\n", "S3 1387-1391: the line as received, no trimming"),
    ("AX3", b"STATUS 1\r", b"TEST=0000\r\n", "S3 548-552 TEST=%04x"),
    ("AX3", b"STATUS 2\r", b"BATTHEALTH=12\r\n", "S3 554-558 BATTHEALTH=%u"),
    ("AX3", b"STATUS 3\r", b"FTL=0,0,20,2,0,0\r\n", "S3 560-565; F 2136-2158: one bad-block count per plane"),
    ("AX3", b"STATUS 4\r", b"CHECKSUM=0000\r\n", "S3 567-573 CHECKSUM=%04x"),
    ("AX3", b"STATUS 5\r", b"RESTART=3\r\n", "S3 575-579 RESTART=%u"),
    ("AX3", b"STATUS 6\r", b"NAND=0000\r\n", "S3 581-586 NAND=%04x"),
    ("AX3", b"STATUS 7\r", b"NANDID=2c:68:04:4a:a9:00,1\r\n", "S3 588-595 NANDID=%02x:...:%02x,%d"),
    ("AX3", b"STATUS\r", b"TEST=0000\r\nBATTHEALTH=12\r\nFTL=0,0,20,2,0,0\r\nCHECKSUM=0000\r\nRESTART=3\r\n"
                         b"NAND=0000\r\nNANDID=2c:68:04:4a:a9:00,1\r\n", "S3 540-597: z = 0 prints all seven"),
    ("AX3", b"STATUS 9\r", b"", "S3 542-546: z = 9 matches no branch, nothing printed"),
    ("AX3", b"SAMPLE 9\r", b"", "S3 465-469: z = 9 matches no branch, nothing printed"),
    # ---- my_atoi: every digit concatenated, 32-bit wrap, '-' negates, none -> 0xFFFFFFFF
    ("AX3", b"SESSION 4294967296\r", b"SESSION=0\r\n", "S3 722-730; U 106-116 (unsigned long wraps)"),
    ("AX3", b"SESSION -1\r", b"SESSION=4294967295\r\n", "U 112-115: sign * value as unsigned long"),
    ("AX3", b"SESSION 12,34\r", b"SESSION=1234\r\n", "U 113: every digit of the rest of the line"),
    ("AX3", b"SESSION x\r", b"SESSION=4294967295\r\n", "U 115: no digit -> 0xFFFFFFFF"),
    ("AX3", b"SESSION\r", b"SESSION=1\r\n", "S3 724: line[7] == NUL: read only (session from the header)"),
    ("AX3", b"MAXSAMPLES 10\r", b"MAXSAMPLES=10\r\n", "S3 704-712 MAXSAMPLES=%lu"),
    ("AX3", b"DEBUG 300\r", b"DEBUG=44\r\n", "S3 713-721: unsigned char debuggingInfo (300 & 0xFF)"),
    ("AX3", b"LED 5\r", b"LED=5\r\n", "S3 1143-1152 LED=%d"),
    ("AX3", b"RATE 74,2000\r", b"RATE=112,0\r\n",
     "S3 731-739: my_atoi -> 742000 & 0xFF = 112; Accel.h 72: 3200/(1<<15) = 0 Hz"),
    ("AX3", b"RATE 74\r", b"RATE=74,100\r\n", "S3 738 RATE=%u,%u"),
    ("AX6", b"RATE 74,2000\r", b"RATE=74,100,2000\r\n", "S6 722-753: rate, then the gyro range after the comma"),
    ("AX6", b"RATE 74\r", b"RATE=74,100,0\r\n", "S6 731: a missing gyro range turns the gyro off"),
    ("AX6", b"RATE 71 250\r", b"RATE=71,12,250\r\n", "S6 735-745: any non-digit ends the rate; 3200/256 = 12"),
    # ---- dates: RtcFromString stores invalid dates as 0, 29-Feb of a non-leap year as 1-Mar
    ("AX3", b"HIBERNATE garbage\r", b"HIBERNATE=0\r\n", "S3 682-690; R 453-468: not six numbers -> 0 (start at once)"),
    ("AX3", b"HIBERNATE 2024-02-30 10:00:00\r", b"HIBERNATE=0\r\n", "R 456: day > maxDaysPerMonth -> 0"),
    ("AX3", b"STOP 2024/13/01,00:00:00\r", b"STOP=0\r\n", "S3 691-699; R 455: month 13 -> 0 (never record)"),
    ("AX3", b"STOP -1\r", b"STOP=-1\r\n", "R 422 a leading '-' -> 0xFFFFFFFF; R 479 prints -1"),
    ("AX3", b"HIBERNATE 0\r", b"HIBERNATE=0\r\n", "R 421: \"0\" -> 0; R 478 prints 0"),
    ("AX3", b"HIBERNATE 2023/02/29,01:02:03\r", b"HIBERNATE=2023/03/01,01:02:03\r\n", "R 462: 29-Feb non-leap -> 1-Mar"),
    ("AX3", b"HIBERNATE 2024/02/29,01:02:03\r", b"HIBERNATE=2024/02/29,01:02:03\r\n", "R 462: leap year kept"),
    ("AX3", b"STOP 24/7/4 5:6:7\r", b"STOP=2024/07/04,05:06:07\r\n", "R 437: any separators; a year < 2000 is 20yy"),
    ("AX3", b"TIME 2023/02/29,01:02:03\r", b"$TIME=2023/03/01,01:02:03\r\n", "S3 635-652; R 462"),
    ("AX3", b"TIME garbage\r", b"ERROR: Problem parsing time.\r\n", "S3 653-656: RtcFromString returned 0"),
    ("AX3", b"TIME \r", b"ERROR: Problem parsing time.\r\n", "S3 638-641; R 420: an empty argument is 0"),
    # ---- the other read-only and configuration commands
    ("AX3", b"LOCK\r", b"LOCK=0\r\n", "S3 1270-1277 LOCK=%d"),
    ("AX3", b"ILOCK\r", b"ILOCK=0\r\n", "S3 1297-1301"),
    ("AX3", b"ECC\r", b"ECC=1\r\n", "S3 1345-1348; Settings.h 89 CONFIG_ECC_DEFAULT 1"),
    ("AX3", b"TZONE\r", b"TZONE=\r\n", "S3 664-681: timeZone -1 prints TZONE="),
    ("AX3", b"TZONE 60\r", b"TZONE=60,+01:00\r\n", "S3 679 TZONE=%d,%c%02d:%02u"),
    ("AX3", b"TZONE -90\r", b"TZONE=-90,-01:30\r\n", "S3 670: (int)my_atoi -> -90; 679"),
    ("AX3", b"DATAMODE\r", b"DATAMODE=18,single-file,CWA/packed\r\n", "S3 1105-1122; S3 256 default"),
    ("AX6", b"DATAMODE\r", b"DATAMODE=20,single-file,CWA/unpacked\r\n", "S6 248 default FORMAT_CWA_UNPACKED"),
    ("AX3", b"STANDBY\r", b"STANDBY=0\r\n", "S3 1095"),
    ("AX3", b"HELP\r", b"HELP: help|echo|reset\r\n", "S3 443-447"),
    ("AX3", b"MOUNT\r", b"MOUNT=1\r\n", "S3 1123-1142 MOUNT=%d"),
    ("AX3", b"AT\r", b"OK\r\n", "S3 1379-1382"),
    ("AX3", b"EXIT\r", b"INFO: You'll have to close the terminal window yourself!\r\n", "S3 1375-1378"),
    ("AX3", b"ECHO\r", b"ECHO=0\r\n", "S3 448-457 ECHO=%d"),
    ("AX3", b"ECHO 1\rAT\r", b"ECHO=1\r\nAT\r\nOK\r\n", "S3 452-455; U 67-74, 88-94: typed characters, CR, LF echoed"),
    ("AX3", b"SESSION 1\rECHO\r", b"SESSION=1\r\nECHO=1\r\n",
     "S3 451: ECHO reads line[5] past its NUL: the static buffer still holds \"ON 1\" (U 48, 88-94)"),
    ("AX3", b"ANNOTATE03=abc\r", b"ANNOTATE03=abc" + SPACES29 + b"\r\n", "S3 805-830: 32 characters, padded with spaces"),
    ("AX3", b"ANNOTATE14=x\r", b"ERROR: Invalid annotation id 14\r\n", "S3 832-835"),
    ("AX3", b"ANNOTATE01 x\r", b"ERROR: Usage is ANNOTATE##=\r\n", "S3 807, 837-840: line[10] must be NUL or '='"),
    ("AX3", b"ECHO\x08\x08HO\r", b"ECHO=0\r\n", "U 75-83: BS removes a character"),
    ("AX3", b"I\nD\r", b"ID=CWA,17,50,12345,1\r\n", "U 84-87: LF ignored"),
    # ---- locked: the setter prints ERROR: Locked. and then its value
    ("AX3", b"LOCK 1234\rSESSION 5\rRATE 10\rUNLOCK 1234\rSESSION 5\r",
     b"LOCK=1\r\nERROR: Locked.\r\nSESSION=1\r\nERROR: Locked.\r\nRATE=74,100\r\nLOCK=0\r\nSESSION=5\r\n",
     "S3 1244-1268, 724-729, 733-738, 1303-1328"),
    ("AX3", b"LOCK 1234\rTIME 2024/01/01,00:00:00\r", b"LOCK=1\r\nERROR: Locked.\r\n", "S3 643-646: TIME prints only the error"),
    ("AX3", b"LOCK 1234\rCLEAR DATA\r", b"LOCK=1\r\nERROR: Locked.\r\nCLEAR: Use 'clear data' or 'clear all'.\r\n",
     "S3 742-774: flags stay 0 when locked"),
    # ---- delayed activation and the erase commands
    ("AX3", b"COMMIT\r", b"COMMIT: Delayed activation.\r\nCOMMIT\r\n", "S3 776-788; SettingsAction 402-412"),
    ("AX3", b"CLEAR DATA\r", b"CLEAR: Delayed activation.\r\nCOMMIT\r\n", "S3 745-763; SettingsAction 402-412"),
    ("AX3", b"MOUNT 0\rCLEAR DATA\r", b"MOUNT=0\r\nCOMMIT\r\nCLEAR\r\n", "S3 765-769: unmounted: SettingsAction, then CLEAR"),
    ("AX3", b"MOUNT 0\rCOMMIT\r", b"MOUNT=0\r\nCOMMIT\r\n", "S3 789-792: unmounted: SettingsAction at once"),
    ("AX3", b"CLEAR\r", b"CLEAR: Use 'clear data' or 'clear all'.\r\n", "S3 771-774"),
    ("AX3", b"FORMAT QC\r", b"FORMAT: Delayed activation.\r\nFORMAT: Complete.\r\nCOMMIT\r\n",
     "S3 1153-1181; SettingsAction 393-412: format prints before the create"),
    ("AX3", b"FORMAT WC\r", b"FORMAT: Delayed activation.\r\nFORMAT: Complete.\r\nCOMMIT\r\n", "S3 1168-1181"),
    ("AX3", b"FORMAT Q\r", b"FORMAT: Delayed activation.\r\nFORMAT: Complete.\r\n", "S3 1173: no C, no COMMIT"),
    ("AX3", b"FORMAT\r", b"ERROR: Must specify 'FORMAT Q' for quick or 'FORMAT W' for wipe, +'C' for COMMIT.\r\n",
     "S3 1189-1192"),
    ("AX3", b"FORMATQC\r", b"ERROR: Must specify 'FORMAT Q' for quick or 'FORMAT W' for wipe, +'C' for COMMIT.\r\n",
     "S3 1156: the letter must be at line[7]"),
    ("AX3", b"LOGFILE x\r", b"ERROR: Cannot while attached and mounted.\r\n", "S3 1194-1216"),
    # ---- the AX6 shares the command code apart from ID and RATE (S6 428-)
    ("AX6", b"STATUS 3\r", b"FTL=0,0,20,2,0,0\r\n", "S6 531-554: one line per STATUS n"),
    ("AX6", b"SESSION -1\r", b"SESSION=4294967295\r\n", "S6 713-720; U 106-116"),
    ("AX6", b"HIBERNATE 2024/02/30,00:00:00\r", b"HIBERNATE=0\r\n", "S6 673-681; R 456: invalid day -> 0"),
    ("AX6", b"FORMAT QC\r", b"FORMAT: Delayed activation.\r\nFORMAT: Complete.\r\nCOMMIT\r\n",
     "S6 1168-1196; SettingsAction 388, 398"),
]


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    root = tmp_path_factory.mktemp("probe-recordings")
    out = {}
    for kind, dev_id in IDS.items():
        p = root / f"{kind}.cwa"
        simulate_recording(p, device=kind.lower(), days=0.002, seed=3, truth_path=False, device_id=dev_id,
                           session_id=1, gyro_range_dps=2000.0 if kind == "AX6" else None)
        out[kind] = p
    return out


def exchange(pty_path: str, request: bytes, expected_len: int) -> bytes:
    """Write ``request`` to the device's pty; read until ``expected_len`` bytes have come (or
    ``DELAYED_S`` passed) and then the port stays quiet for ``QUIET_S``."""
    fd = os.open(pty_path, os.O_RDWR | os.O_NOCTTY)
    try:
        os.write(fd, request)
        got = b""
        end = time.monotonic() + DELAYED_S
        while True:
            wait = QUIET_S if len(got) >= expected_len or time.monotonic() > end else 0.1
            r, _, _ = select.select([fd], [], [], wait)
            if r:
                got += os.read(fd, 4096)
            elif len(got) >= expected_len or time.monotonic() > end:
                return got
    finally:
        os.close(fd)


@pytest.mark.parametrize("kind, request_bytes, expected, source", ROWS,
                         ids=[f"{r[0]}:{r[1].decode('latin-1')!r}" for r in ROWS])
def test_reply_bytes_are_the_firmware_s(kind, request_bytes, expected, source, recordings, tmp_path,
                                        monkeypatch):
    monkeypatch.setenv("STILLPOINT_RUNTIME_DIR", str(tmp_path / "runtime"))
    d = EmulatedDevice(tmp_path / "dev", IDS[kind], kind, recording=recordings[kind], remount_s=0.05)
    try:
        d.plug(pty=True)
        got = exchange(d.pty_path, request_bytes, len(expected))
    finally:
        d.shutdown()
    assert got == expected, f"{kind} {request_bytes!r}: firmware ({source}) prints {expected!r}, emulator {got!r}"


def test_the_line_that_stops_a_stream_is_executed(recordings, tmp_path, monkeypatch):
    """AX3 main.c 291-297: any line stops the stream (status.stream = 0) and is then executed."""
    monkeypatch.setenv("STILLPOINT_RUNTIME_DIR", str(tmp_path / "runtime"))
    d = EmulatedDevice(tmp_path / "dev", IDS["AX3"], "AX3", recording=recordings["AX3"])
    try:
        d.plug(pty=True)
        fd = os.open(d.pty_path, os.O_RDWR | os.O_NOCTTY)
        try:
            os.write(fd, b"STREAM\r")
            time.sleep(0.3)
            os.write(fd, b"ID\r")
            got = b""
            while select.select([fd], [], [], 0.3)[0]:
                got += os.read(fd, 4096)
        finally:
            os.close(fd)
    finally:
        d.shutdown()
    lines = got.split(b"\r\n")
    assert sum(1 for x in lines if x.count(b",") == 2 and b"=" not in x) >= 5, got[:200]
    # the ID reply is the last line: the stream stopped, the stopping line was executed
    assert lines[-2:] == [b"ID=CWA,17,50,12345,1", b""], got[-200:]
