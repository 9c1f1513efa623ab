"""The tactile sensor: a stream of binary frames on its own serial port.

The sensor sends frames continuously (format in :mod:`hardware.frames` and
``docs/tactile-frames.md``). :class:`TactileSensor` reads what has arrived, decodes it, and keeps
the decoder's counters (dropped frames by sequence number, CRC errors, garbage skipped).
:class:`TactileRecorder` collects the frames of one touch, unwrapping the sensor's 32-bit
microsecond clock.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hardware.errors import ConfigurationError, DeviceTimeout, NotConnectedError
from hardware.frames import CHANNELS, DecoderStats, FrameDecoder, TactileFrame
from hardware.records import FloatArray, IntArray
from hardware.transport import Transport

TACTILE_BAUDRATE = 460800
"""32-byte frames at 1 kHz need 320 kbit/s: 460800 baud leaves margin."""


@dataclass(frozen=True)
class TactileConfig:
    """Tactile stream settings.

    Attributes:
        channel_names: Channel names, in frame order (the paper's five by default).
        frame_timeout_s: Longest silence accepted from a streaming sensor.
    """

    channel_names: tuple[str, ...] = CHANNELS
    frame_timeout_s: float = 0.5

    def __post_init__(self) -> None:
        if not self.channel_names:
            raise ConfigurationError("channel_names: at least one channel is needed.")
        if not self.frame_timeout_s > 0:
            raise ConfigurationError(
                f"frame_timeout_s: must be positive, received {self.frame_timeout_s}."
            )


class TactileSensor:
    """Reader of the tactile frame stream.

    Args:
        transport: The sensor's port.
        config: Stream settings.
    """

    def __init__(self, transport: Transport, config: TactileConfig | None = None) -> None:
        self.transport = transport
        self.config = config or TactileConfig()
        self.decoder = FrameDecoder(len(self.config.channel_names))
        self.last_frame: TactileFrame | None = None
        self._connected = False

    @property
    def connected(self) -> bool:
        """Whether the stream was seen since the last connect."""
        return self._connected

    @property
    def stats(self) -> DecoderStats:
        """Decoder counters since the last :meth:`restart`."""
        return self.decoder.stats

    def connect(self) -> TactileFrame:
        """Open the port and wait for a valid frame.

        Raises:
            DeviceTimeout: No valid frame within ``frame_timeout_s``.
        """
        self._connected = False
        if not self.transport.is_open:
            self.transport.open()
        self.restart()
        frames = self.wait_frames(self.config.frame_timeout_s)
        self._connected = True
        return frames[-1]

    def close(self) -> None:
        """Close the port."""
        self._connected = False
        self.transport.close()

    def restart(self) -> None:
        """Discard buffered bytes and reset the decoder and its counters."""
        if not self.transport.is_open:
            raise NotConnectedError(f"{self.transport.name}: the tactile port is not open.")
        self.transport.reset_input_buffer()
        self.decoder.reset()

    def poll(self, timeout_s: float = 0.0) -> list[TactileFrame]:
        """Decode the bytes that have arrived (waiting up to ``timeout_s`` for the first)."""
        frames: list[TactileFrame] = []
        data = self.transport.read(1 << 16, timeout_s)
        while data:
            frames.extend(self.decoder.feed(data))
            data = self.transport.read(1 << 16, 0.0)
        if frames:
            self.last_frame = frames[-1]
        return frames

    def wait_frames(self, timeout_s: float) -> list[TactileFrame]:
        """Frames, waiting until at least one has arrived.

        Raises:
            DeviceTimeout: No valid frame within ``timeout_s`` (a stalled or silent sensor; the
                decoder's counters say whether bytes arrived that were not frames).
        """
        deadline = self.transport.now() + timeout_s
        while True:
            remaining = deadline - self.transport.now()
            frames = self.poll(max(0.0, remaining))
            if frames:
                return frames
            if remaining <= 0:
                stats = self.decoder.stats
                raise DeviceTimeout(
                    f"{self.transport.name}: no valid tactile frame for {timeout_s:g} s "
                    f"({stats.discarded_bytes} bytes skipped, {stats.crc_errors} CRC errors)."
                )


class TactileRecorder:
    """Frames of one recording, with the sensor clock unwrapped to seconds.

    Args:
        channel_count: Channels per frame.
    """

    def __init__(self, channel_count: int) -> None:
        self.channel_count = channel_count
        self._times: list[float] = []
        self._values: list[tuple[float, ...]] = []
        self._sequence: list[int] = []
        self._last_raw: int | None = None
        self._wraps = 0

    def __len__(self) -> int:
        return len(self._values)

    def add(self, frames: list[TactileFrame]) -> None:
        """Append frames in arrival order."""
        for frame in frames:
            raw = frame.timestamp_us
            if self._last_raw is not None and raw < self._last_raw - (1 << 31):
                self._wraps += 1
            self._last_raw = raw
            self._times.append((raw + (self._wraps << 32)) * 1e-6)
            self._values.append(frame.channels)
            self._sequence.append(frame.sequence)

    @property
    def last_time_s(self) -> float | None:
        """Sensor time of the last frame (unwrapped), or None."""
        return self._times[-1] if self._times else None

    def arrays(self) -> tuple[FloatArray, FloatArray, IntArray]:
        """``(times_s (n,), values (n, C), sequence (n,))``."""
        times = np.asarray(self._times, dtype=np.float64)
        values = np.asarray(self._values, dtype=np.float64).reshape(-1, self.channel_count)
        sequence = np.asarray(self._sequence, dtype=np.int64)
        return times, values, sequence
