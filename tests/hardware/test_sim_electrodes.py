"""The simulated whole-touch channels: electrode ring, high-rate vibration, the twins table."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from scipy import signal

from hardware.clock import VirtualClock
from hardware.frames import FrameDecoder, crc16_ccitt, encode_frame, frame_size
from hardware.sim.electrodes import SurfaceDetail, WholeTouchChannels, WholeTouchSensor
from hardware.sim.materials import get_table
from hardware.sim.rig import simulated_devices

QUIET = WholeTouchSensor(electrode_noise=0.0, vibration_noise=0.0)


def _run(detail: SurfaceDetail, force_n: float, speed_mm_s: float, frames: int) -> np.ndarray:
    channels = WholeTouchChannels(QUIET, np.random.default_rng(0))
    return np.array([channels.sample(force_n, speed_mm_s, detail, 0.01) for _ in range(frames)])


def test_the_electrodes_share_the_force_and_the_patch_width_sets_their_spread() -> None:
    broad = _run(SurfaceDetail(0.1, 2.0), 3.0, 8.0, 400)[:, :8]
    edge = _run(SurfaceDetail(0.1, 0.6), 3.0, 8.0, 400)[:, :8]
    np.testing.assert_allclose(broad.sum(axis=1), 3.0, rtol=1e-12)
    np.testing.assert_allclose(edge.sum(axis=1), 3.0, rtol=1e-12)
    # Sliding 32 mm takes the patch twice round the ring: each electrode's mean is F / E on both.
    np.testing.assert_allclose(broad.mean(axis=0), 3.0 / 8, rtol=0.02)
    np.testing.assert_allclose(edge.mean(axis=0), 3.0 / 8, rtol=0.02)
    assert edge.std(axis=0).min() > 2 * broad.std(axis=0).max()


def test_the_vibration_is_a_tone_at_speed_over_period_with_one_rms() -> None:
    rate_hz = 100.0 * QUIET.vibration_samples_per_frame
    series = {
        period: _run(SurfaceDetail(period, 2.0), 4.0, 20.0, 300)[:, 8:].reshape(-1)
        for period in (0.05, 0.2)
    }
    for period, vibration in series.items():
        freqs, psd = signal.welch(vibration, fs=rate_hz, nperseg=512)
        assert freqs[np.argmax(psd)] == pytest.approx(20.0 / period, abs=rate_hz / 512)
        assert abs(vibration.mean()) < 0.01
    amplitude = 0.05 * np.sqrt(4.0) * 20.0 / 30.0
    for vibration in series.values():
        assert np.sqrt(np.mean(vibration**2)) == pytest.approx(amplitude / np.sqrt(2), rel=0.02)


def test_no_contact_gives_noise_only() -> None:
    channels = WholeTouchChannels(QUIET, np.random.default_rng(0))
    assert channels.sample(0.0, 10.0, SurfaceDetail(0.1, 1.0), 0.01) == (0.0,) * 24
    assert channels.sample(2.0, 10.0, None, 0.01) == (0.0,) * 24


def test_a_whole_touch_frame_is_byte_exact() -> None:
    values = tuple(float(v) for v in range(29))
    frame = encode_frame(1, 1000, values)
    assert len(frame) == frame_size(29) == 128
    expected = (
        b"\xaa\x55" + struct.pack("<BHIB", 7 + 4 * 29, 1, 1000, 29) + struct.pack("<29f", *values)
    )
    assert frame[:-2] == expected
    assert frame[-2:] == struct.pack("<H", crc16_ccitt(expected[2:]))
    (decoded,) = FrameDecoder(29).feed(frame)
    assert decoded.channels == values


def test_the_twins_table_streams_29_channels_through_the_plant() -> None:
    devices = simulated_devices(get_table("twins").objects, clock=VirtualClock(), seed=0)
    assert len(devices.channel_names) == 29
    assert devices.channel_names[5] == "electrode[0]"
    assert devices.channel_names[-1] == "vibration@15"
    devices.clock.sleep(0.05)
    data = devices.sensor.transmit(10_000)
    frames = FrameDecoder(29).feed(data)
    assert len(frames) >= 4
    assert all(len(f.channels) == 29 for f in frames)
    plain = simulated_devices(("paper_cup", "stainless_cup"), clock=VirtualClock(), seed=0)
    assert len(plain.channel_names) == 5
