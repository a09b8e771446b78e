"""Typed errors of a device conversation; each names the device and what went wrong."""

from __future__ import annotations

from stillpoint.engine.core.errors import StillpointError


class DeviceError(StillpointError):
    """A device could not be used. ``device`` names it (id, serial or port), ``reason`` says why."""

    def __init__(self, device, reason: str):
        self.device = str(device)
        self.reason = reason
        super().__init__(f"device {self.device}: {reason}")


class DeviceTimeout(DeviceError):
    """No expected reply within the command's timeout."""


class DeviceCommandError(DeviceError):
    """The device answered ``ERROR: ...``."""

    def __init__(self, device, command: str, reply: str):
        self.command, self.reply = command, reply
        super().__init__(device, f"{command!r} refused: {reply}")


class DeviceLocked(DeviceCommandError):
    """``ERROR: Locked.``: the device's settings are locked with a code."""


class DeviceGone(DeviceError):
    """The port or the drive went away (unplugged, re-enumerating)."""


class IdentityMismatch(DeviceError):
    """Two sources that must name the same device (serial, ID, header, label) or session disagree."""


class ForbiddenCommand(DeviceError):
    """A factory/destructive command the host must never send."""
