"""The tactile frame format: encoding, CRC, resynchronisation and loss accounting."""

from __future__ import annotations

import struct

import pytest

from hardware.errors import ConfigurationError
from hardware.frames import (
    CHANNELS,
    SYNC,
    FrameDecoder,
    crc16_ccitt,
    encode_frame,
    frame_size,
)

VALUES = (0.5, -1.25, 3.0, 120.0, 32.75)


def test_crc_is_ccitt_false() -> None:
    # The standard check value of CRC-16/CCITT-FALSE.
    assert crc16_ccitt(b"123456789") == 0x29B1


def test_frame_layout_is_the_documented_one() -> None:
    frame = encode_frame(0x1234, 0xDEADBEEF, VALUES)
    assert len(frame) == frame_size(5) == 32
    assert frame[:2] == SYNC == b"\xaa\x55"
    length, sequence, timestamp, count = struct.unpack_from("<BHIB", frame, 2)
    assert (length, sequence, timestamp, count) == (27, 0x1234, 0xDEADBEEF, 5)
    assert struct.unpack_from("<5f", frame, 10) == VALUES
    (crc,) = struct.unpack_from("<H", frame, 30)
    assert crc == crc16_ccitt(frame[2:30])


def test_round_trip_byte_by_byte() -> None:
    decoder = FrameDecoder()
    stream = encode_frame(7, 1000, VALUES) + encode_frame(8, 2000, VALUES)
    frames = []
    for byte in stream:
        frames.extend(decoder.feed(bytes([byte])))
    assert [(f.sequence, f.timestamp_us, f.channels) for f in frames] == [
        (7, 1000, VALUES),
        (8, 2000, VALUES),
    ]
    assert decoder.stats.dropped == 0
    assert decoder.stats.discarded_bytes == 0


def test_resynchronises_after_garbage_and_counts_it() -> None:
    decoder = FrameDecoder()
    garbage = b"\x00\xff\xaa\x13hello\xaa"
    frames = decoder.feed(encode_frame(1, 10, VALUES) + garbage + encode_frame(2, 20, VALUES))
    assert [f.sequence for f in frames] == [1, 2]
    stats = decoder.stats
    assert stats.discarded_bytes == len(garbage)
    assert stats.dropped == 0


def test_bad_crc_frame_is_rejected_and_shows_as_dropped() -> None:
    decoder = FrameDecoder()
    bad = bytearray(encode_frame(2, 20, VALUES))
    bad[15] ^= 0x01
    stream = encode_frame(1, 10, VALUES) + bytes(bad) + encode_frame(3, 30, VALUES)
    frames = decoder.feed(stream)
    assert [f.sequence for f in frames] == [1, 3]
    assert decoder.stats.crc_errors == 1
    assert decoder.stats.dropped == 1  # sequence 2 never arrived intact


def test_wrong_length_is_malformed() -> None:
    decoder = FrameDecoder()
    frames = decoder.feed(b"\xaa\x55\x09" + encode_frame(5, 50, VALUES))
    assert [f.sequence for f in frames] == [5]
    assert decoder.stats.malformed == 1


def test_sequence_gap_counted_across_wrap() -> None:
    decoder = FrameDecoder()
    frames = decoder.feed(
        encode_frame(65534, 1, VALUES) + encode_frame(65535, 2, VALUES) + encode_frame(2, 3, VALUES)
    )
    assert len(frames) == 3
    assert decoder.stats.dropped == 2  # 0 and 1 are missing


def test_reset_forgets_counters_and_sequence() -> None:
    decoder = FrameDecoder()
    decoder.feed(encode_frame(1, 1, VALUES) + b"junk")
    decoder.reset()
    decoder.feed(encode_frame(40, 2, VALUES))
    assert decoder.stats.dropped == 0
    assert decoder.stats.discarded_bytes == 0
    assert decoder.stats.frames == 1


def test_other_channel_count_is_rejected() -> None:
    decoder = FrameDecoder(channel_count=5)
    frames = decoder.feed(encode_frame(1, 1, (1.0, 2.0)) + encode_frame(2, 2, VALUES))
    assert [f.sequence for f in frames] == [2]
    assert decoder.stats.malformed == 1


def test_bad_channel_counts_raise() -> None:
    with pytest.raises(ConfigurationError, match=r"1\.\.32"):
        encode_frame(0, 0, ())
    with pytest.raises(ConfigurationError, match="channel_count"):
        FrameDecoder(channel_count=0)
    assert len(CHANNELS) == 5
