"""The tactile stream reader against the sensor emulator on a pseudo-terminal (460800 baud)."""

from __future__ import annotations

import time
from collections.abc import Iterator

import numpy as np
import pytest

from hardware.clock import ScaledClock
from hardware.errors import DeviceTimeout
from hardware.frames import TactileFrame
from hardware.sim.materials import get_object
from hardware.sim.pty import PtyEmulator
from hardware.sim.tactile_device import TactileSource
from hardware.sim.world import Plant
from hardware.tactile import TACTILE_BAUDRATE, TactileConfig, TactileRecorder, TactileSensor
from hardware.transport import SerialTransport


@pytest.fixture
def source() -> Iterator[tuple[TactileSource, PtyEmulator]]:
    plant = Plant({0: get_object("paper_cup")}, ScaledClock(10.0), np.random.default_rng(0))
    device = TactileSource(plant, frame_rate_hz=200.0)
    with PtyEmulator(device, "tactile") as emulator:
        yield device, emulator


def open_sensor(emulator: PtyEmulator) -> TactileSensor:
    sensor = TactileSensor(
        SerialTransport(emulator.port, TACTILE_BAUDRATE), TactileConfig(frame_timeout_s=0.3)
    )
    sensor.connect()
    return sensor


def collect(sensor: TactileSensor, seconds: float) -> list[TactileFrame]:
    frames: list[TactileFrame] = []
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        frames.extend(sensor.poll(0.01))
    return frames


def test_stream_is_continuous(source: tuple[TactileSource, PtyEmulator]) -> None:
    _, emulator = source
    sensor = open_sensor(emulator)
    sensor.restart()
    frames = collect(sensor, 0.1)  # 1 simulated second at 200 frames/s
    assert 150 <= len(frames) <= 260
    sequence = np.array([f.sequence for f in frames])
    assert np.all(np.diff(sequence) == 1)
    stamps = np.array([f.timestamp_us for f in frames])
    np.testing.assert_allclose(np.diff(stamps), 5000, atol=1)  # 200 Hz
    assert sensor.stats.dropped == 0
    assert all(len(f.channels) == 5 for f in frames)
    recorder = TactileRecorder(5)
    recorder.add(frames)
    times, values, _ = recorder.arrays()
    assert values.shape == (len(frames), 5)
    assert times[0] == pytest.approx(stamps[0] * 1e-6)


def test_garbage_and_bad_frames_are_skipped_and_counted(
    source: tuple[TactileSource, PtyEmulator],
) -> None:
    device, emulator = source
    sensor = open_sensor(emulator)
    sensor.restart()
    collect(sensor, 0.02)
    device.inject_garbage(b"\xaa\x55\xff" + bytes(range(40)))
    device.corrupt_frames(4)
    device.drop_frames(2)
    frames = collect(sensor, 0.1)
    stats = sensor.stats
    assert stats.crc_errors == 4
    assert stats.dropped == 6  # 4 corrupt + 2 lost at the source
    assert stats.discarded_bytes >= 43
    assert len(frames) > 100  # the stream went on


def test_stalled_sensor_times_out(source: tuple[TactileSource, PtyEmulator]) -> None:
    device, emulator = source
    sensor = open_sensor(emulator)
    device.stall()
    sensor.restart()
    with pytest.raises(DeviceTimeout, match="no valid tactile frame"):
        sensor.wait_frames(0.2)
