"""Serial-level emulators: a simulated device behind a pseudo-terminal.

:class:`PtyEmulator` opens a pseudo-terminal pair (``os.openpty``) and runs a thread that moves
bytes between the master side and a :class:`~hardware.transport.ByteDevice`. The slave side is a
real tty path (``/dev/pts/N``) that a driver opens with pyserial — or that the Dynamixel SDK's own
``PortHandler`` could open — so the drivers are exercised byte for byte, through the kernel.

Unplugging the device closes the master side: the driver sees the port hang up, as when a USB
adapter is pulled.
"""

from __future__ import annotations

import contextlib
import os
import select
import threading
import time
import tty

from hardware.errors import HardwareError
from hardware.lifecycle import WithBlock
from hardware.transport import ByteDevice


class PtyEmulator(WithBlock):
    """A device served on a pseudo-terminal.

    Args:
        device: The simulated device.
        name: Thread and message name.
        poll_interval_s: Longest real time between two polls of the device for output.
        buffer_limit_bytes: Output waiting for a host that does not read, beyond what the
            pseudo-terminal holds (~20 KB). It stands for the kernel and adapter buffers of a
            real port, and absorbs the burst a simulated device produces when this process was
            not scheduled for a while (simulated time kept running). Beyond it the oldest bytes
            are dropped (an overrun).
    """

    def __init__(
        self,
        device: ByteDevice,
        name: str = "emulator",
        poll_interval_s: float = 0.002,
        buffer_limit_bytes: int = 1 << 18,
    ) -> None:
        self.device = device
        self.name = name
        self.poll_interval_s = poll_interval_s
        self.buffer_limit_bytes = buffer_limit_bytes
        self._master = -1
        self._slave = -1
        self._port = ""
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self.error: BaseException | None = None
        self.bytes_in = 0
        self.bytes_out = 0
        self.bytes_overrun = 0

    @property
    def port(self) -> str:
        """The tty path to open (``/dev/pts/N``)."""
        if not self._port:
            raise HardwareError(f"{self.name}: the emulator is not started.")
        return self._port

    @property
    def serving(self) -> bool:
        """Whether the emulator thread is running (False once the device is unplugged)."""
        return self._thread is not None and self._thread.is_alive()

    def wait_hung_up(self, timeout_s: float = 2.0) -> bool:
        """Wait until an unplugged device's line is hung up; returns whether it is."""
        deadline = time.monotonic() + timeout_s
        while self.serving and time.monotonic() < deadline:
            time.sleep(0.005)
        return not self.serving

    def start(self) -> str:
        """Open the pseudo-terminal and start serving; returns the port path."""
        if self._thread is not None:
            return self._port
        master, slave = os.openpty()
        tty.setraw(slave)
        os.set_blocking(master, False)
        self._master, self._slave = master, slave
        self._port = os.ttyname(slave)
        self._stop.clear()
        self._thread = threading.Thread(target=self._serve, name=f"pty-{self.name}", daemon=True)
        self._thread.start()
        return self._port

    def stop(self) -> None:
        """Stop serving and close the pseudo-terminal."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        self._close_fds()

    def _close_fds(self) -> None:
        for fd in (self._master, self._slave):
            if fd >= 0:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self._master = self._slave = -1

    def _begin(self) -> None:
        self.start()

    def _end(self) -> None:
        self.stop()

    def _serve(self) -> None:
        pending = bytearray()
        master = self._master
        try:
            while not self._stop.is_set():
                if not self.device.connected:
                    break
                ready, _, _ = select.select([master], [], [], self.poll_interval_s)
                if ready:
                    try:
                        data = os.read(master, 4096)
                    except BlockingIOError:
                        data = b""
                    except OSError:
                        data = b""  # no reader on the slave side at the moment
                    if data:
                        self.bytes_in += len(data)
                        self.device.receive(data)
                pending.extend(self.device.transmit(1 << 16))
                if len(pending) > self.buffer_limit_bytes:
                    overrun = len(pending) - self.buffer_limit_bytes
                    del pending[:overrun]
                    self.bytes_overrun += overrun
                if pending:
                    try:
                        written = os.write(master, pending)
                    except (BlockingIOError, InterruptedError):
                        written = 0
                    except OSError:
                        written = 0
                    del pending[:written]
                    self.bytes_out += written
        except Exception as exc:  # reported through .error
            self.error = exc
        finally:
            if not self.device.connected:
                # The cable is pulled: hang up the line for whoever has the port open.
                self._close_fds()
