"""Axivity AX3/AX6 over USB: the serial protocol client, device discovery (serial port + drive),
the data-file reader, and a firmware-faithful emulator (pure Python) for use without hardware.

See /work/shared/specs/usb-protocols.md Part A for the protocol; constants live in
``drivers/constants.py``.
"""
