"""Fixtures of the hardware tests: real-device ports, simulated rigs and emulators."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from hardware.records import FloatArray
from hardware.rig import RigConfig
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
