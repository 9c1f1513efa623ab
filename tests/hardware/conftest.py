"""Fixtures of the hardware tests: real-device ports, simulated rigs and emulators."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator

import pytest

from hardware.errors import ServoHardwareError, ServoHardwareErrorFlags
from hardware.records import FloatArray
from hardware.rig import RigConfig, RigState, TouchProgress
from hardware.sim.rig import SimulatedRig, in_process_rig
from hardware.teaching import teaching_trajectory


def _port(request: pytest.FixtureRequest, option: str) -> str:
    value = request.config.getoption(option)
    if not value:
        pytest.skip(f"needs a real device: run pytest with {option}=/dev/tty...")
    return str(value)


@pytest.fixture
def turntable_port(request: pytest.FixtureRequest) -> str:
    """Port of a real GRBL turntable (skips the test without ``--turntable-port``)."""
    return _port(request, "--turntable-port")


@pytest.fixture
def finger_port(request: pytest.FixtureRequest) -> str:
    """Port of a real Dynamixel bus (skips the test without ``--finger-port``)."""
    return _port(request, "--finger-port")


@pytest.fixture
def tactile_port(request: pytest.FixtureRequest) -> str:
    """Port of a real tactile sensor (skips the test without ``--tactile-port``)."""
    return _port(request, "--tactile-port")


SHORT_TOUCH_S = 4.0
"""Touch duration used by the rig tests (the paper's is 14.4 s; shorter keeps tests fast)."""


@pytest.fixture
def short_touch() -> FloatArray:
    """A 4 s teaching trajectory at 25 Hz (101 setpoints)."""
    return teaching_trajectory(dt_s=0.04, duration_s=SHORT_TOUCH_S)


@pytest.fixture
def sim_rig() -> Iterator[SimulatedRig]:
    """A connected in-process simulated rig (virtual clock, seed 3) and its lease 'test'."""
    sim = in_process_rig(seed=3, rig_config=RigConfig(control_period_s=0.04))
    lease = sim.rig.acquire("test")
    lease.connect()
    lease.release()
    yield sim
    sim.close()


def at_step(step: int, action: Callable[[], object]) -> Callable[[TouchProgress], None]:
    """An on_progress callback that runs ``action()`` once, at setpoint ``step``."""
    done: list[bool] = []

    def callback(progress: TouchProgress) -> None:
        if progress.step >= step and not done:
            done.append(True)
            action()

    return callback


def servo_error_mid_touch(
    sim: SimulatedRig,
    touch: FloatArray,
    slot: int,
    step: int,
    servo_id: int,
    flags: ServoHardwareErrorFlags,
) -> ServoHardwareError:
    """A servo reports ``flags`` at setpoint ``step`` of a touch at ``slot``: the touch raises
    it with what was recorded, both joints' torque goes off (the rig is safe, in FAULT), and
    after :meth:`~hardware.rig.RigLease.recover` the rig touches again. Returns the error."""
    bus, plant = sim.devices.bus, sim.devices.plant
    with sim.rig.acquire("test") as lease:
        lease.move_to_slot(slot)
        with pytest.raises(ServoHardwareError) as raised:
            lease.touch(
                touch, on_progress=at_step(step, lambda: bus.inject_hardware_error(servo_id, flags))
            )
        assert raised.value.flags == flags
        assert raised.value.partial_record is not None
        deadline = time.monotonic() + 2.0  # over a pty the broadcast torque-off takes a while
        while plant.joint_state(0)[3] and time.monotonic() < deadline:
            time.sleep(0.01)
        assert not plant.joint_state(0)[3]
        assert not plant.joint_state(1)[3]
        assert sim.rig.state is RigState.FAULT
        lease.recover()  # reboots the servo
        assert not plant.hardware_error(bus.servos[servo_id].joint)
        assert lease.touch(touch).complete
    return raised.value
