"""What every simulated device shares: a lock, a cable that can be pulled, bytes for the host.

The simulated GRBL controller, Dynamixel bus and tactile sensor each speak their own protocol
(:class:`~hardware.transport.ByteDevice`); the state a pulled cable changes and the queue of
bytes waiting for the host are kept the same way in all of them, here.
"""

from __future__ import annotations

import threading


class SimulatedDevice:
    """A device at the far end of a cable.

    Attributes:
        lock: Held while the device's state changes (the host's thread, the emulator's thread
            and fault injection from a test may call at once).
    """

    def __init__(self) -> None:
        self.lock = threading.RLock()
        self._connected = True
        self._out = bytearray()  # sent by the device, not yet read by the host

    @property
    def connected(self) -> bool:
        """False after :meth:`unplug`."""
        return self._connected

    def unplug(self) -> None:
        """The cable is pulled: the host's port hangs up."""
        with self.lock:
            self._connected = False

    def _take(self, max_bytes: int) -> bytes:
        """Remove and return up to ``max_bytes`` of the bytes waiting for the host."""
        with self.lock:
            chunk = bytes(self._out[:max_bytes])
            del self._out[:max_bytes]
            return chunk
