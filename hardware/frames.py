"""The tactile sensor's binary frame format (documented in ``docs/tactile-frames.md``).

One frame, all multi-byte fields little-endian::

    offset  size  field
    0       2     sync            0xAA 0x55
    2       1     length          bytes from ``sequence`` to the last channel: 7 + 4·C
    3       2     sequence        uint16, +1 per frame, wraps at 65536
    5       4     timestamp_us    uint32, sensor clock in microseconds, wraps
    9       1     channel_count   C (1..32)
    10      4·C   channels        float32 each, physical units (see CHANNELS)
    10+4C   2     crc16           CRC-16/CCITT-FALSE of bytes [2, 10+4C) (length .. channels)

With the five channels of the paper a frame is 32 bytes. :class:`FrameDecoder` finds frames in an
arbitrary byte stream: it skips garbage, resynchronises after a bad length or CRC, and counts the
frames missing from the sequence numbers.
"""

from __future__ import annotations

import binascii
import struct
from dataclasses import dataclass

from hardware.errors import ConfigurationError

SYNC = b"\xaa\x55"
CHANNELS: tuple[str, ...] = (
    "vibration_1",
    "vibration_2",
    "pressure_kpa",
    "heat_flux_mw",
    "temperature_c",
)
"""The paper's five tactile features, in frame order."""

MAX_CHANNELS = 32
_FIXED_BODY = 7  # sequence (2) + timestamp (4) + channel count (1)
_HEADER = struct.Struct("<BHIB")  # length, sequence, timestamp, channel count


def crc16_ccitt(data: bytes, initial: int = 0xFFFF) -> int:
    """CRC-16/CCITT-FALSE (polynomial 0x1021, initial 0xFFFF, no reflection, no final XOR).

    ``crc16_ccitt(b"123456789") == 0x29B1``.
    """
    return binascii.crc_hqx(data, initial)


def frame_size(channel_count: int) -> int:
    """Bytes in a frame with ``channel_count`` channels."""
    return 2 + 1 + _FIXED_BODY + 4 * channel_count + 2


@dataclass(frozen=True, slots=True)
class TactileFrame:
    """One decoded frame.

    Attributes:
        sequence: Frame counter (uint16).
        timestamp_us: Sensor clock (uint32, microseconds).
        channels: Channel values in :data:`CHANNELS` order.
    """

    sequence: int
    timestamp_us: int
    channels: tuple[float, ...]


def encode_frame(sequence: int, timestamp_us: int, channels: tuple[float, ...]) -> bytes:
    """Encode one frame (used by the sensor simulator and by tests).

    Args:
        sequence: Frame counter; taken modulo 65536.
        timestamp_us: Sensor time; taken modulo 2³².
        channels: 1..32 channel values.
    """
    count = len(channels)
    if not 1 <= count <= MAX_CHANNELS:
        raise ConfigurationError(f"channels: expected 1..{MAX_CHANNELS} values, received {count}.")
    body = _HEADER.pack(
        _FIXED_BODY + 4 * count, sequence & 0xFFFF, timestamp_us & 0xFFFFFFFF, count
    ) + struct.pack(f"<{count}f", *channels)
    return SYNC + body + struct.pack("<H", crc16_ccitt(body))


@dataclass(frozen=True)
class DecoderStats:
    """Counters of a :class:`FrameDecoder`.

    Attributes:
        frames: Valid frames decoded.
        dropped: Frames missing according to the sequence numbers (lost or corrupt).
        crc_errors: Candidate frames whose CRC did not match.
        malformed: Candidate frames with an impossible length or channel count.
        discarded_bytes: Bytes skipped while looking for a frame.
    """

    frames: int = 0
    dropped: int = 0
    crc_errors: int = 0
    malformed: int = 0
    discarded_bytes: int = 0

    @property
    def corrupt(self) -> int:
        """Bad frames seen: CRC errors plus malformed ones."""
        return self.crc_errors + self.malformed


class FrameDecoder:
    """Incremental decoder: feed it bytes as they come, get frames out.

    Args:
        channel_count: Expected number of channels; frames with another count are malformed.
    """

    def __init__(self, channel_count: int = len(CHANNELS)) -> None:
        if not 1 <= channel_count <= MAX_CHANNELS:
            raise ConfigurationError(
                f"channel_count: expected 1..{MAX_CHANNELS}, received {channel_count}."
            )
        self.channel_count = channel_count
        self._length = _FIXED_BODY + 4 * channel_count
        self._size = frame_size(channel_count)
        self._values = struct.Struct(f"<{channel_count}f")
        self._buffer = bytearray()
        self._last_sequence: int | None = None
        self._frames = 0
        self._dropped = 0
        self._crc_errors = 0
        self._malformed = 0
        self._discarded = 0

    @property
    def stats(self) -> DecoderStats:
        """The counters since the last :meth:`reset`."""
        return DecoderStats(
            frames=self._frames,
            dropped=self._dropped,
            crc_errors=self._crc_errors,
            malformed=self._malformed,
            discarded_bytes=self._discarded,
        )

    def reset(self) -> None:
        """Forget buffered bytes, the last sequence number and the counters."""
        self._buffer.clear()
        self._last_sequence = None
        self._frames = self._dropped = self._crc_errors = self._malformed = self._discarded = 0

    def feed(self, data: bytes) -> list[TactileFrame]:
        """Add received bytes; return the frames completed by them, in order."""
        buffer = self._buffer
        buffer.extend(data)
        frames: list[TactileFrame] = []
        position = 0
        size = self._size
        while True:
            start = buffer.find(SYNC, position)
            if start < 0:
                # Keep a trailing 0xAA: it may be the first half of the next sync.
                keep_from = len(buffer) - 1 if buffer.endswith(SYNC[:1]) else len(buffer)
                self._discarded += max(0, keep_from - position)
                position = max(position, keep_from)
                break
            self._discarded += start - position
            position = start
            if len(buffer) - start < 3:
                break
            if buffer[start + 2] != self._length:
                self._malformed += 1
                position = start + 1
                self._discarded += 1
                continue
            if len(buffer) - start < size:
                break
            body = bytes(buffer[start + 2 : start + size - 2])
            (crc,) = struct.unpack_from("<H", buffer, start + size - 2)
            if crc16_ccitt(body) != crc:
                self._crc_errors += 1
                position = start + 1
                self._discarded += 1
                continue
            _, sequence, timestamp, count = _HEADER.unpack_from(body)
            if count != self.channel_count:
                self._malformed += 1
                position = start + 1
                self._discarded += 1
                continue
            channels = self._values.unpack_from(body, _HEADER.size)
            if self._last_sequence is not None:
                self._dropped += (sequence - self._last_sequence - 1) & 0xFFFF
            self._last_sequence = sequence
            self._frames += 1
            frames.append(TactileFrame(sequence, timestamp, channels))
            position = start + size
        del buffer[:position]
        return frames
