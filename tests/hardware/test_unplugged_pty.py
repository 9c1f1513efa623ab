"""Pulling the cable of any simulated device (:class:`hardware.sim.device.SimulatedDevice`)
hangs up its pseudo-terminal, and the driver on the other end reports a disconnect."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from hardware.clock import ScaledClock
from hardware.errors import DeviceDisconnected
from hardware.sim.device import SimulatedDevice
from hardware.sim.dynamixel_device import DynamixelBus
from hardware.sim.grbl_device import GrblDevice
from hardware.sim.materials import get_object
from hardware.sim.pty import PtyEmulator
from hardware.sim.tactile_device import TactileSource
from hardware.sim.world import Plant
from tests.hardware.test_finger_pty import open_finger
from tests.hardware.test_tactile_pty import open_sensor
from tests.hardware.test_turntable_pty import open_table

#: Device, how its driver opens it, and an operation that needs the device to answer.
CASES: dict[
    str, tuple[Callable[[], SimulatedDevice], Callable[[PtyEmulator], Any], Callable[[Any], Any]]
] = {
    "turntable": (
        lambda: GrblDevice(ScaledClock(20.0)),
        open_table,
        lambda table: table.move_to_slot(4),
    ),
    "finger": (
        lambda: DynamixelBus(Plant({}, ScaledClock(10.0), np.random.default_rng(0))),
        open_finger,
        lambda finger: finger.read_state(),
    ),
    "tactile": (
        lambda: TactileSource(
            Plant({0: get_object("paper_cup")}, ScaledClock(10.0), np.random.default_rng(0)),
            frame_rate_hz=200.0,
        ),
        open_sensor,
        lambda sensor: sensor.wait_frames(0.2),
    ),
}


@pytest.mark.parametrize("name", sorted(CASES))
def test_an_unplugged_device_is_a_disconnect(name: str) -> None:
    make, open_driver, operate = CASES[name]
    device = make()
    with PtyEmulator(device, name) as emulator:
        driver = open_driver(emulator)
        assert device.connected
        device.unplug()
        assert not device.connected
        assert emulator.wait_hung_up()
        with pytest.raises(DeviceDisconnected):
            operate(driver)
