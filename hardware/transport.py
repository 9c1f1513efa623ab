"""Byte transports: the only module that opens serial ports.

A driver is handed a :class:`Transport` and speaks its protocol through it; it never opens a port
itself. Two implementations:

- :class:`SerialTransport` — a pyserial port (``/dev/ttyUSB0``, a pseudo-terminal of an emulator,
  or any pyserial URL such as ``socket://host:port``), with timeouts, clean close and reconnect.
- :class:`InProcessTransport` — a simulated device (a :class:`ByteDevice`) called directly in the
  same process: the same bytes as on a wire, without the operating system.

Reads never busy-wait: :meth:`Transport.read` blocks (``select`` on the port's file descriptor)
until at least one byte arrives or the timeout passes, and returns what is there.
"""

from __future__ import annotations

import contextlib
import select
import threading
import time
from abc import ABC, abstractmethod
from typing import Any, Protocol

import serial

from hardware.clock import Clock, SystemClock
from hardware.errors import (
    ConfigurationError,
    DeviceDisconnected,
    DeviceUnavailable,
    NotConnectedError,
)
from hardware.lifecycle import WithBlock

try:  # POSIX: pyserial lets termios errors through (e.g. tcflush on a hung-up tty)
    import termios

    _PORT_ERRORS: tuple[type[BaseException], ...] = (
        serial.SerialException,
        OSError,
        termios.error,
    )
except ImportError:  # pragma: no cover - Windows
    _PORT_ERRORS = (serial.SerialException, OSError)

_OPEN_ERRORS: tuple[type[BaseException], ...] = (*_PORT_ERRORS, ValueError)
_FILENO_ERRORS: tuple[type[BaseException], ...] = (
    AttributeError,
    NotImplementedError,
    *_PORT_ERRORS,
)


class Transport(WithBlock, ABC):
    """A bidirectional byte stream to one device.

    Writes are serialised by a lock, so an emergency stop may write from another thread while a
    driver reads and writes in its own.
    """

    def __init__(self, name: str) -> None:
        self.name = name
        self._write_lock = threading.Lock()

    # -- life cycle -------------------------------------------------------------------------

    @abstractmethod
    def open(self) -> None:
        """Open the connection.

        Raises:
            DeviceUnavailable: The port cannot be opened.
        """

    @abstractmethod
    def close(self) -> None:
        """Close the connection (idempotent)."""

    @property
    @abstractmethod
    def is_open(self) -> bool:
        """Whether the connection is open."""

    def reconnect(self, attempts: int = 3, delay_s: float = 0.5) -> None:
        """Close and open again, trying ``attempts`` times ``delay_s`` apart.

        Raises:
            DeviceUnavailable: Every attempt failed.
        """
        if attempts < 1:
            raise ConfigurationError(f"attempts: must be >= 1, received {attempts}.")
        self.close()
        last: DeviceUnavailable | None = None
        for attempt in range(attempts):
            try:
                self.open()
                return
            except DeviceUnavailable as exc:
                last = exc
                if attempt + 1 < attempts:
                    time.sleep(delay_s)
        assert last is not None
        raise DeviceUnavailable(f"{self.name}: reconnect failed after {attempts} attempts: {last}")

    def _begin(self) -> None:
        if not self.is_open:
            self.open()

    def _end(self) -> None:
        self.close()

    # -- bytes -------------------------------------------------------------------------------

    def write(self, data: bytes) -> None:
        """Write all of ``data``.

        Raises:
            NotConnectedError: The transport is closed.
            DeviceDisconnected: The device went away.
        """
        if not self.is_open:
            raise NotConnectedError(f"{self.name}: write on a closed transport.")
        with self._write_lock:
            self._write(bytes(data))

    @abstractmethod
    def _write(self, data: bytes) -> None: ...

    @abstractmethod
    def read(self, max_bytes: int, timeout_s: float) -> bytes:
        """Return 1..``max_bytes`` bytes as soon as any are there, or ``b""`` after ``timeout_s``.

        Raises:
            NotConnectedError: The transport is closed.
            DeviceDisconnected: The device went away.
        """

    @abstractmethod
    def reset_input_buffer(self) -> None:
        """Discard every byte received and not yet read."""

    def now(self) -> float:
        """The time base of this transport's timeouts, in seconds (real time by default)."""
        return time.monotonic()


# ---------------------------------------------------------------------------------------------
# Serial ports
# ---------------------------------------------------------------------------------------------


class SerialTransport(Transport):
    """A serial port through pyserial.

    Args:
        port: Device path (``/dev/ttyACM0``, ``/dev/pts/5``) or pyserial URL (``socket://...``).
        baudrate: Bits per second.
        write_timeout_s: A write that cannot complete in this time means the device is gone.
        exclusive: Take an exclusive lock on the port (POSIX), so two programs cannot share it.
    """

    def __init__(
        self,
        port: str,
        baudrate: int,
        *,
        write_timeout_s: float = 1.0,
        exclusive: bool = True,
    ) -> None:
        if not port:
            raise ConfigurationError("port: a device path or pyserial URL is required.")
        if baudrate <= 0:
            raise ConfigurationError(f"baudrate: must be positive, received {baudrate}.")
        super().__init__(port)
        self.port = port
        self.baudrate = int(baudrate)
        self.write_timeout_s = float(write_timeout_s)
        self.exclusive = exclusive
        self._serial: Any = None

    @property
    def is_open(self) -> bool:
        """Whether the port is open."""
        return self._serial is not None and bool(self._serial.is_open)

    def open(self) -> None:
        """Open the port (8N1, no flow control)."""
        if self.is_open:
            return
        kwargs: dict[str, Any] = {
            "baudrate": self.baudrate,
            "bytesize": serial.EIGHTBITS,
            "parity": serial.PARITY_NONE,
            "stopbits": serial.STOPBITS_ONE,
            "timeout": 0,
            "write_timeout": self.write_timeout_s,
            "do_not_open": True,
        }
        if self.exclusive and "://" not in self.port:
            kwargs["exclusive"] = True
        try:
            port = serial.serial_for_url(self.port, **kwargs)
            port.open()
        except _OPEN_ERRORS as exc:
            raise DeviceUnavailable(f"{self.name}: cannot open the port: {exc}") from exc
        self._serial = port

    def close(self) -> None:
        """Close the port; errors while closing a dead port are ignored."""
        port, self._serial = self._serial, None
        if port is not None:
            with contextlib.suppress(*_PORT_ERRORS):
                port.close()

    def _port(self) -> Any:
        if self._serial is None or not self._serial.is_open:
            raise NotConnectedError(f"{self.name}: the port is not open.")
        return self._serial

    def _write(self, data: bytes) -> None:
        port = self._port()
        try:
            written = port.write(data)
            port.flush()
        except serial.SerialTimeoutException as exc:
            raise DeviceDisconnected(f"{self.name}: write timed out: {exc}") from exc
        except _PORT_ERRORS as exc:
            raise DeviceDisconnected(f"{self.name}: write failed: {exc}") from exc
        if written is not None and written != len(data):
            raise DeviceDisconnected(f"{self.name}: wrote {written} of {len(data)} bytes.")

    def read(self, max_bytes: int, timeout_s: float) -> bytes:
        """See :meth:`Transport.read`."""
        port = self._port()
        deadline = time.monotonic() + max(0.0, timeout_s)
        try:
            fileno: int | None = port.fileno()
        except _FILENO_ERRORS:
            fileno = None
        while True:
            try:
                waiting = int(port.in_waiting)
                if waiting:
                    return bytes(port.read(min(waiting, max_bytes)))
            except _PORT_ERRORS as exc:
                raise DeviceDisconnected(f"{self.name}: read failed: {exc}") from exc
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return b""
            if fileno is None:
                time.sleep(min(remaining, 0.001))
                continue
            try:
                ready, _, _ = select.select([fileno], [], [], remaining)
            except (OSError, ValueError) as exc:
                raise DeviceDisconnected(f"{self.name}: port closed while waiting: {exc}") from exc
            if ready:
                # Readable: data, or a hang-up, which read() reports as an error.
                try:
                    data = bytes(port.read(max_bytes))
                except _PORT_ERRORS as exc:
                    raise DeviceDisconnected(f"{self.name}: read failed: {exc}") from exc
                if data:
                    return data

    def reset_input_buffer(self) -> None:
        """Discard buffered input (``tcflush``)."""
        try:
            self._port().reset_input_buffer()
        except _PORT_ERRORS as exc:
            raise DeviceDisconnected(f"{self.name}: flush failed: {exc}") from exc


# ---------------------------------------------------------------------------------------------
# Simulated devices in the same process
# ---------------------------------------------------------------------------------------------


class ByteDevice(Protocol):
    """A simulated device seen as bytes: what a serial cable would carry."""

    @property
    def connected(self) -> bool:
        """False once the device has been unplugged (fault injection)."""
        ...

    def attach(self) -> None:
        """The host opened the port (an Arduino resets here and prints its banner)."""
        ...

    def receive(self, data: bytes) -> None:
        """Bytes written by the host."""
        ...

    def transmit(self, max_bytes: int) -> bytes:
        """Up to ``max_bytes`` bytes the device has sent by now (may be empty)."""
        ...


class InProcessTransport(Transport):
    """A transport handed a simulated device instead of a port.

    Waiting happens on the simulation's clock, so with a :class:`~hardware.clock.VirtualClock`
    a read timeout costs no real time.

    Args:
        device: The simulated device.
        clock: The simulation clock the device runs on.
        name: Name used in messages.
        poll_s: Clock time between two polls of the device while waiting.
    """

    def __init__(
        self,
        device: ByteDevice,
        clock: Clock | None = None,
        name: str = "in-process device",
        poll_s: float = 0.001,
    ) -> None:
        super().__init__(name)
        self.device = device
        self.clock: Clock = clock or SystemClock()
        self.poll_s = float(poll_s)
        self._open = False

    @property
    def is_open(self) -> bool:
        """Whether the transport is open."""
        return self._open

    def open(self) -> None:
        """Connect to the device (it must be plugged in)."""
        if self._open:
            return
        if not self.device.connected:
            raise DeviceUnavailable(f"{self.name}: the simulated device is unplugged.")
        self._open = True
        self.device.attach()

    def close(self) -> None:
        """Disconnect."""
        self._open = False

    def _check(self) -> None:
        if not self._open:
            raise NotConnectedError(f"{self.name}: the transport is not open.")
        if not self.device.connected:
            raise DeviceDisconnected(f"{self.name}: the simulated device was unplugged.")

    def _write(self, data: bytes) -> None:
        self._check()
        self.device.receive(data)

    def read(self, max_bytes: int, timeout_s: float) -> bytes:
        """See :meth:`Transport.read`; waits on the simulation clock."""
        self._check()
        deadline = self.clock.now() + max(0.0, timeout_s)
        while True:
            data = self.device.transmit(max_bytes)
            if data:
                return data
            remaining = deadline - self.clock.now()
            if remaining <= 0:
                return b""
            self.clock.sleep(min(remaining, self.poll_s))
            self._check()

    def now(self) -> float:
        """The simulation clock: read timeouts are simulated seconds."""
        return self.clock.now()

    def reset_input_buffer(self) -> None:
        """Discard everything the device has sent so far."""
        self._check()
        while self.device.transmit(1 << 16):
            pass
