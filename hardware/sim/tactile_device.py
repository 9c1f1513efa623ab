"""A simulated tactile sensor: it streams frames (:mod:`hardware.frames`) of the plant's samples.

Like a real sensor on a UART it sends continuously whether or not anyone reads, and drops frames
when its output buffer is full. Faults: frames lost at the source (sequence gaps), corrupt frames
(bad CRC), garbage bytes, a stall (silence), unplugging.
"""

from __future__ import annotations

from hardware.frames import encode_frame
from hardware.sim.device import SimulatedDevice
from hardware.sim.world import Plant


class TactileSource(SimulatedDevice):
    """The sensor, as bytes.

    Args:
        plant: The world it samples.
        frame_rate_hz: Frames per second (of simulated time).
        buffer_limit_bytes: Output kept for a host that does not read; beyond it frames drop.
    """

    def __init__(
        self, plant: Plant, frame_rate_hz: float = 100.0, buffer_limit_bytes: int = 65536
    ) -> None:
        super().__init__()
        self.plant = plant
        self.frame_rate_hz = float(frame_rate_hz)
        self.buffer_limit_bytes = buffer_limit_bytes
        self._sequence = 0
        self._stalled = False
        self._drop_next = 0
        self._corrupt_next = 0
        self.frames_sent = 0
        self.frames_overflowed = 0
        plant.attach_sampler(self._on_sample, 1.0 / self.frame_rate_hz)

    def _on_sample(self, moment: float, channels: tuple[float, ...]) -> None:
        with self.lock:
            if self._stalled:
                return
            sequence = self._sequence
            self._sequence = (self._sequence + 1) & 0xFFFF
            if self._drop_next > 0:
                self._drop_next -= 1
                return
            frame = bytearray(encode_frame(sequence, round(moment * 1e6), channels))
            if self._corrupt_next > 0:
                self._corrupt_next -= 1
                frame[12] ^= 0x5A  # a flipped channel byte: the CRC no longer matches
            if len(self._out) + len(frame) > self.buffer_limit_bytes:
                self.frames_overflowed += 1
                return
            self._out.extend(frame)
            self.frames_sent += 1

    # -- ByteDevice ---------------------------------------------------------------------------

    def attach(self) -> None:
        """Opening the port changes nothing: the sensor streams regardless."""

    def receive(self, data: bytes) -> None:
        """The sensor takes no commands; input is ignored."""

    def transmit(self, max_bytes: int) -> bytes:
        """The frames produced by now."""
        self.plant.advance()
        return self._take(max_bytes)

    # -- fault injection ----------------------------------------------------------------------

    def stall(self, stalled: bool = True) -> None:
        """Stop (or resume) sending frames."""
        with self.lock:
            self._stalled = stalled

    def drop_frames(self, count: int) -> None:
        """Lose the next ``count`` frames at the source (their sequence numbers are skipped)."""
        with self.lock:
            self._drop_next += count

    def corrupt_frames(self, count: int) -> None:
        """Corrupt one byte in each of the next ``count`` frames."""
        with self.lock:
            self._corrupt_next += count

    def inject_garbage(self, data: bytes) -> None:
        """Bytes that are not frames, at the current point of the stream."""
        with self.lock:
            self.plant.advance()
            self._out.extend(data)
