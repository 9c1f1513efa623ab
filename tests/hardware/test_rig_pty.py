"""The whole rig through pseudo-terminals: three emulators, the real drivers, pyserial.

Simulated time runs 10x faster than real time; a 4 s touch takes ~0.4 s.
"""

from __future__ import annotations

import threading
from collections.abc import Iterator

import numpy as np
import pytest

from hardware.errors import (
    DeviceDisconnected,
    EmergencyStopped,
    GrblAlarm,
    ServoHardwareErrorFlags,
)
from hardware.records import FloatArray
from hardware.rig import RigConfig, RigState
from hardware.sim.rig import SimulatedRig, pty_rig
from tests.hardware.conftest import SHORT_TOUCH_S, at_step, servo_error_mid_touch


@pytest.fixture
def rig() -> Iterator[SimulatedRig]:
    # No rest before touches: these tests time faults into touches in real time (the rest has
    # its own tests, test_settle.py).
    config = RigConfig(control_period_s=0.04, settle_s=0.0)
    sim = pty_rig(seed=11, speed=10.0, rig_config=config)
    with sim.rig.acquire("setup") as lease:
        lease.connect()
    yield sim
    sim.close()


def test_touch_through_ptys(rig: SimulatedRig, short_touch: FloatArray) -> None:
    with rig.rig.acquire("test") as lease:
        lease.move_to_slot(rig.slot_of("stainless_cup"))
        steel = lease.touch(short_touch)
        lease.move_to_slot(rig.slot_of("paper_cup"))
        paper = lease.touch(short_touch)
    for record in (steel, paper):
        assert record.complete
        # Frames are kept by sensor time: the count does not depend on the host's speed.
        assert abs(record.n_frames - SHORT_TOUCH_S * 100) <= 5
        assert record.dropped_frames <= 4  # 1%: only an overloaded host loses any
        assert 0 <= record.late_steps <= record.commanded_deg.shape[0]
    assert steel.observation[3] > paper.observation[3]  # steel draws more heat
    assert [e.error for e in rig.emulators] == [None, None, None]


def test_garbage_and_bad_crc_on_the_line(rig: SimulatedRig, short_touch: FloatArray) -> None:
    sensor = rig.devices.sensor

    def spoil() -> None:
        sensor.inject_garbage(b"\x00\x01\xaa\x55\x1b" + b"\xff" * 40)
        sensor.corrupt_frames(5)

    with rig.rig.acquire("test") as lease:
        record = lease.touch(short_touch, on_progress=at_step(30, spoil))
    assert record.complete
    assert record.corrupt_frames >= 5
    assert record.dropped_frames == 5
    assert record.discarded_bytes >= 45


def test_finger_bus_disconnected_mid_touch(rig: SimulatedRig, short_touch: FloatArray) -> None:
    with rig.rig.acquire("test") as lease:
        with pytest.raises(DeviceDisconnected) as raised:
            lease.touch(short_touch, on_progress=at_step(40, rig.devices.bus.unplug))
        partial = raised.value.partial_record
        assert partial is not None
        assert partial.n_frames > 100  # recorded before the cable came out
        assert not partial.complete
    status = rig.rig.status()
    assert status.state is RigState.FAULT
    assert "DeviceDisconnected" in (status.fault or "")


def test_servo_hardware_error_mid_touch(rig: SimulatedRig, short_touch: FloatArray) -> None:
    error = servo_error_mid_touch(rig, short_touch, 1, 40, 2, ServoHardwareErrorFlags.OVERHEATING)
    assert error.joint == "FFJ4"


def test_grbl_alarm_through_the_port(rig: SimulatedRig) -> None:
    rig.devices.grbl.alarm_during_next_move(code=1, fraction=0.4)
    with rig.rig.acquire("test") as lease:
        with pytest.raises(GrblAlarm) as raised:
            lease.move_to_slot(6)
        assert raised.value.code == 1
        assert rig.rig.state is RigState.FAULT
        lease.recover()
        assert lease.move_to_slot(6) == pytest.approx(216.0)


def test_emergency_stop_from_another_thread(rig: SimulatedRig, short_touch: FloatArray) -> None:
    stopper = threading.Timer(0.15, rig.rig.estop, args=("test stop",))
    with rig.rig.acquire("test") as lease:
        lease.move_to_slot(2)
        stopper.start()
        with pytest.raises(EmergencyStopped) as raised:
            lease.touch(short_touch)
        stopper.join()
        partial = raised.value.partial_record
        assert partial is not None
        assert 0 < partial.n_frames < SHORT_TOUCH_S * 100
        assert b"\x18" in rig.devices.grbl.received
        assert rig.rig.state is RigState.ESTOPPED
        lease.recover()
        assert rig.rig.state is RigState.IDLE
        np.testing.assert_allclose(rig.rig.status().finger_deg or (), [0.0, 0.0], atol=0.5)
