"""The ``axemu://<serial>`` pyserial URL: a serial port to an emulated device in this process.

Importing this module registers the scheme (``serial.protocol_handler_packages``), so
``serial.serial_for_url("axemu://CWA17_12345")`` opens the device's port; pyserial looks for
``protocol_axemu`` in the registered package.
"""

from __future__ import annotations

import serial

_PACKAGE = "stillpoint.drivers.ax"
if _PACKAGE not in serial.protocol_handler_packages:
    serial.protocol_handler_packages.append(_PACKAGE)
