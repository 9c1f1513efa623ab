"""Transports: pyserial ports (loop://, pseudo-terminals), the in-process transport."""

from __future__ import annotations

import time

import pytest

from hardware.clock import VirtualClock
from hardware.errors import DeviceDisconnected, DeviceUnavailable, NotConnectedError
from hardware.sim.pty import PtyEmulator
from hardware.transport import InProcessTransport, SerialTransport


class Echo:
    """A minimal ByteDevice that answers every byte with itself."""

    def __init__(self) -> None:
        self.out = bytearray()
        self.plugged = True
        self.attached = 0

    @property
    def connected(self) -> bool:
        return self.plugged

    def attach(self) -> None:
        self.attached += 1

    def receive(self, data: bytes) -> None:
        self.out.extend(data)

    def transmit(self, max_bytes: int) -> bytes:
        chunk = bytes(self.out[:max_bytes])
        del self.out[:max_bytes]
        return chunk


def test_loop_url_round_trip_and_timeout() -> None:
    port = SerialTransport("loop://", 115200)
    port.open()
    port.write(b"hello")
    assert port.read(100, 0.5) == b"hello"
    start = time.monotonic()
    assert port.read(100, 0.05) == b""
    assert time.monotonic() - start >= 0.04
    port.close()
    port.close()  # idempotent
    with pytest.raises(NotConnectedError):
        port.write(b"x")


def test_missing_port_is_unavailable() -> None:
    with pytest.raises(DeviceUnavailable, match="cannot open"):
        SerialTransport("/dev/does-not-exist-activetouch", 115200).open()


def test_reconnect_gives_up_with_device_unavailable() -> None:
    port = SerialTransport("/dev/does-not-exist-activetouch", 115200)
    with pytest.raises(DeviceUnavailable, match="after 2 attempts"):
        port.reconnect(attempts=2, delay_s=0.0)


def test_pty_round_trip_reconnect_and_unplug() -> None:
    device = Echo()
    with PtyEmulator(device, "echo") as emulator:
        port = SerialTransport(emulator.port, 1_000_000)
        port.open()
        port.write(b"ping")
        received = b""
        deadline = time.monotonic() + 2.0
        while len(received) < 4 and time.monotonic() < deadline:
            received += port.read(100, 0.5)
        assert received == b"ping"
        port.reconnect()
        port.write(b"again")
        received = b""
        while len(received) < 5 and time.monotonic() < deadline:
            received += port.read(100, 0.5)
        assert received == b"again"
        device.plugged = False  # the emulator hangs up the line

        def keep_talking() -> None:
            for _ in range(50):
                port.read(100, 0.1)
                port.write(b"x")

        with pytest.raises(DeviceDisconnected):
            keep_talking()
        port.close()


def test_in_process_read_waits_on_the_simulation_clock() -> None:
    clock = VirtualClock()
    device = Echo()
    port = InProcessTransport(device, clock, "echo")
    port.open()
    assert device.attached == 1
    start = time.monotonic()
    assert port.read(10, 30.0) == b""  # 30 simulated seconds, no real wait
    assert clock.now() == pytest.approx(30.0, abs=1e-3)
    assert time.monotonic() - start < 2.0
    port.write(b"abc")
    assert port.read(2, 1.0) == b"ab"
    port.reset_input_buffer()
    assert port.read(10, 0.0) == b""
    device.plugged = False
    with pytest.raises(DeviceDisconnected):
        port.read(10, 0.0)
    with pytest.raises(DeviceUnavailable):
        InProcessTransport(device, clock).open()
