"""Device discovery: port filters, mount table parsing, pairing by device id, backends."""

from __future__ import annotations

from stillpoint.drivers.ax.discovery import (EmulatedBackend, PortInfo, discover, is_ax_port,
                                             label_device, parse_mountinfo)

from station_fixtures import emu, runtime  # noqa: F401

MANUF = "Newcastle University    "


def test_port_filter_needs_every_check():
    good = PortInfo("/dev/ttyACM0", "CWA17_12345", MANUF, 0x04D8, 0x0057)
    assert is_ax_port(good)
    assert is_ax_port(PortInfo("/dev/ttyACM1", "AX664_00042", MANUF, 0x04D8, 0x0057))
    # the Microchip composite VID:PID alone is not enough
    assert not is_ax_port(PortInfo("/dev/ttyACM2", "0001234", "Microchip", 0x04D8, 0x0057))
    assert not is_ax_port(PortInfo("/dev/ttyACM3", "CWA17_12345", "Someone Else", 0x04D8, 0x0057))
    assert not is_ax_port(PortInfo("/dev/ttyUSB0", "CWA17_12345", MANUF, 0x0403, 0x6001))


def test_labels():
    assert label_device("AX317_12345") == ("AX3", 12345)
    assert label_device("AX664_00042") == ("AX6", 42)
    assert label_device("AX3_1234567") == ("AX3", 1234567)
    assert label_device("USBSTICK") is None


def test_mountinfo_labels_and_escapes():
    text = ("36 25 8:17 / /media/ann/AX317_12345 rw,nosuid - vfat /dev/sdb1 rw\n"
            "37 25 8:33 / /run/media/bob/My\\040Disk rw - vfat /dev/sdc1 rw\n"
            "38 25 8:49 / /mnt/dock3 rw - vfat /dev/sdd1 rw\n")
    got = parse_mountinfo(text, {"/dev/sdd1": "AX664_00042"})
    assert ("/media/ann/AX317_12345", "AX317_12345") in got
    assert ("/run/media/bob/My Disk", "My Disk") in got
    # the label comes from the by-label table, not the mount folder's name
    assert ("/mnt/dock3", "AX664_00042") in got


class FakeBackend:
    def __init__(self, ports, volumes):
        self._p, self._v = ports, volumes

    def ports(self):
        return self._p

    def volumes(self):
        return self._v


def test_pairing_and_port_without_drive(tmp_path):
    vol = tmp_path / "AX317_12345"
    vol.mkdir()
    (vol / "CWA-DATA.CWA").write_bytes(b"MD" + b"\0" * 1022)
    other = tmp_path / "AX317_99999"  # a drive without the data file is not an AX drive
    other.mkdir()
    b = FakeBackend([PortInfo("/dev/ttyACM0", "CWA17_12345", MANUF, 0x04D8, 0x0057, "1-1.2"),
                     PortInfo("/dev/ttyACM1", "CWA17_99999", MANUF, 0x04D8, 0x0057, "1-1.3"),
                     PortInfo("/dev/ttyS0", None, None, None, None)],
                    [(str(vol), "AX317_12345"), (str(other), "AX317_99999")])
    found = {a.device_id: a for a in discover(b)}
    assert set(found) == {12345, 99999}
    assert found[12345].volume == str(vol) and found[12345].slot == "1-1.2" and not found[12345].problem
    assert found[99999].volume is None and "no mounted drive" in found[99999].problem
    # manual override: the drive is mounted somewhere discovery did not look
    found = {a.device_id: a for a in discover(b, volume=str(vol))}
    assert found[12345].volume == str(vol)


def test_emulated_devices_are_found_through_the_registry(emu):
    emu(10001)
    b = emu(20002, "AX6")
    found = discover(EmulatedBackend())
    assert [(x.device_id, x.device_type) for x in found] == [(10001, "AX3"), (20002, "AX6")]
    assert all(x.emulated and x.volume and x.port.startswith("axemu://") for x in found)
    b.unplug()
    assert [x.device_id for x in discover(EmulatedBackend())] == [10001]
