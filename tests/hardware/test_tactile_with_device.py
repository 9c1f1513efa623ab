"""A real tactile sensor (run with ``--tactile-port /dev/ttyUSB1``; skipped otherwise)."""

from __future__ import annotations

import time

from hardware.tactile import TACTILE_BAUDRATE, TactileSensor
from hardware.transport import SerialTransport


def test_stream_for_one_second(tactile_port: str) -> None:
    sensor = TactileSensor(SerialTransport(tactile_port, TACTILE_BAUDRATE))
    try:
        sensor.connect()
        sensor.restart()
        frames = []
        deadline = time.monotonic() + 1.0
        while time.monotonic() < deadline:
            frames.extend(sensor.poll(0.05))
        assert len(frames) > 10
        stats = sensor.stats
        assert stats.dropped <= 0.01 * (stats.frames + stats.dropped)
        assert all(len(frame.channels) == 5 for frame in frames)
    finally:
        sensor.close()
