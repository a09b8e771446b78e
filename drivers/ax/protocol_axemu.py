"""pyserial protocol handler for ``axemu://<serial>`` (see ``emulator_url``)."""

from __future__ import annotations


from serial.serialutil import PortNotOpenError, SerialBase, SerialException


class Serial(SerialBase):
    """A pyserial port whose other end is an ``EmulatedDevice`` in this process."""

    def open(self):
        from .emulator import EMULATORS
        if self._port is None:
            raise SerialException("port must be configured before it can be used")
        if self.is_open:
            raise SerialException("port already open")
        name = str(self._port)
        if name.lower().startswith("axemu://"):
            name = name[len("axemu://"):]
        dev = EMULATORS.get(name)
        if dev is None or not dev.plugged:
            raise SerialException(f"could not open port {self._port}: no emulated device {name} attached")
        self._dev = dev
        self.is_open = True

    def _reconfigure_port(self):
        pass

    def close(self):
        self.is_open = False
        self._dev = None

    @property
    def in_waiting(self):
        if not self.is_open:
            raise PortNotOpenError()
        return self._dev.pending()

    def read(self, size=1):
        if not self.is_open:
            raise PortNotOpenError()
        try:
            return self._dev.host_read(size, self._timeout)
        except OSError as e:
            raise SerialException(f"read failed: {e}") from None

    def write(self, data):
        if not self.is_open:
            raise PortNotOpenError()
        try:
            self._dev.host_write(bytes(data))
        except OSError as e:
            raise SerialException(f"write failed: {e}") from None
        return len(data)

    def reset_input_buffer(self):
        if self.is_open:
            while self._dev.pending():
                self._dev.host_read(65536, 0)

    def reset_output_buffer(self):
        pass

    def flush(self):
        pass

    @property
    def cts(self):
        return True

    @property
    def dsr(self):
        return True

    @property
    def ri(self):
        return False

    @property
    def cd(self):
        return True

    def _update_rts_state(self):
        pass

    def _update_dtr_state(self):
        pass

    def _update_break_state(self):
        pass
