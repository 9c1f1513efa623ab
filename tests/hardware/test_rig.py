"""The rig on in-process simulated devices: touches, lease, limits, e-stop and faults.

Every fault must give its specific exception, leave the rig safe (finger retracted or stopped,
table still), keep what was recorded (``partial_record``) and be recoverable.
"""

from __future__ import annotations

import threading

import numpy as np
import pytest

from hardware.errors import (
    CorruptStreamError,
    DeviceDisconnected,
    DeviceTimeout,
    EmergencyStopped,
    GrblAlarm,
    HardwareError,
    LeaseError,
    NotConnectedError,
    RigBusy,
    ServoHardwareErrorFlags,
    UnsafeTrajectoryError,
)
from hardware.records import FloatArray
from hardware.rig import RigConfig, RigState
from hardware.sim.materials import DEFAULT_TABLE, PAPER_CUPS
from hardware.sim.rig import SimulatedRig, in_process_rig
from tests.hardware.conftest import SHORT_TOUCH_S, at_step, servo_error_mid_touch

FRAME_RATE_HZ = 100.0


def finger_pose(sim: SimulatedRig) -> np.ndarray:
    plant = sim.devices.plant
    return np.array([plant.joint_state(0)[0], plant.joint_state(1)[0]])


def test_touch_records_the_stream_and_the_joints(
    sim_rig: SimulatedRig, short_touch: FloatArray
) -> None:
    with sim_rig.rig.acquire("test") as lease:
        assert lease.move_to_slot(sim_rig.slot_of("stainless_cup")) == pytest.approx(108.0)
        record = lease.touch(short_touch)
    assert record.complete
    assert record.failure is None
    assert record.slot == 3
    expected_frames = SHORT_TOUCH_S * FRAME_RATE_HZ
    assert abs(record.n_frames - expected_frames) <= 2
    assert record.tactile_times_s.min() >= 0.0
    assert record.tactile_times_s.max() <= SHORT_TOUCH_S
    assert np.all(np.diff(record.tactile_sequence) == 1)
    np.testing.assert_allclose(record.observation, record.tactile.mean(axis=0))
    assert record.observation.shape == (5,)
    assert record.dropped_frames == 0
    assert record.corrupt_frames == 0
    # Joint states every 5 setpoints; the finger followed the commanded path.
    assert record.joint_positions_deg.shape == (21, 2)  # setpoints 0, 5, ..., 100
    # The servo lags its goal by its time constant (30 ms) plus half a control period.
    lagged_times = record.joint_times_s - 0.03 - 0.02
    commanded = np.array(
        [
            np.interp(lagged_times, np.arange(101) * 0.04, record.commanded_deg[:, j])
            for j in range(2)
        ]
    ).T
    assert np.max(np.abs(record.joint_positions_deg - commanded)) < 1.5
    assert record.joint_currents_ma[:, 0].max() > 100.0  # pressing on steel loads FFJ3
    status = sim_rig.rig.status()
    assert status.state is RigState.IDLE
    assert status.touches == 1
    np.testing.assert_allclose(finger_pose(sim_rig), [0.0, 0.0], atol=0.3)  # back to safe


def test_the_four_cups_feel_different(sim_rig: SimulatedRig, short_touch: FloatArray) -> None:
    assert sim_rig.object_names[:4] == list(PAPER_CUPS)  # slots 0-3, the paper's O1..O4
    observations = {}
    with sim_rig.rig.acquire("test") as lease:
        for name in PAPER_CUPS:
            lease.move_to_slot(sim_rig.slot_of(name))
            observations[name] = lease.touch(short_touch).observation
    heat = {name: y[3] for name, y in observations.items()}
    assert max(heat, key=heat.__getitem__) == "stainless_cup"
    vibration = {name: y[0] for name, y in observations.items()}
    assert max(vibration, key=vibration.__getitem__) == "bumpy_glass"
    assert observations["paper_cup"][2] < observations["stainless_cup"][2]  # pressure


def test_the_default_table_holds_the_cups_and_three_more_objects(
    sim_rig: SimulatedRig, short_touch: FloatArray
) -> None:
    assert sim_rig.object_names == list(DEFAULT_TABLE)
    assert len(DEFAULT_TABLE) == len(set(DEFAULT_TABLE)) == 7
    table = sim_rig.objects_by_slot
    assert list(table) == list(range(7))
    assert table[6].name == "foam_sponge"
    props = table[4].properties()
    assert props["material"] == "glazed ceramic"
    assert props["thermal_effusivity_w_s05_per_m2_k"] == 1600.0
    assert props["temperature_c"] == 22.0
    observations = {}
    with sim_rig.rig.acquire("test") as lease:
        for name in ("stainless_cup", *DEFAULT_TABLE[4:]):
            lease.move_to_slot(sim_rig.slot_of(name))
            observations[name] = lease.touch(short_touch).observation
    # The soft sponge presses back least; the rigid mug draws more heat than wood or foam.
    pressure = {name: y[2] for name, y in observations.items()}
    assert min(pressure, key=pressure.__getitem__) == "foam_sponge"
    heat = observations["ceramic_mug"][3]
    assert heat > observations["wooden_block"][3] > observations["foam_sponge"][3]


def test_a_seed_gives_the_same_observations() -> None:
    def observe(seed: int) -> FloatArray:
        sim = in_process_rig(seed=seed, rig_config=RigConfig(control_period_s=0.04))
        from hardware.teaching import teaching_trajectory

        with sim.rig.acquire("seeded") as lease:
            lease.connect()
            lease.move_to_slot(1)
            return lease.touch(teaching_trajectory(dt_s=0.04, duration_s=4.0)).observation

    np.testing.assert_array_equal(observe(5), observe(5))
    assert not np.array_equal(observe(5), observe(6))


def test_only_one_lease_at_a_time(sim_rig: SimulatedRig) -> None:
    rig = sim_rig.rig
    first = rig.acquire("run 1")
    with pytest.raises(RigBusy, match="run 1") as raised:
        rig.acquire("run 2")
    assert raised.value.owner == "run 1"
    assert rig.status().lease_owner == "run 1"
    releaser = threading.Timer(0.05, first.release)
    releaser.start()
    second = rig.acquire("run 2", timeout_s=5.0)  # waits for the release
    with pytest.raises(LeaseError):
        first.move_to_slot(1)
    assert rig.revoke_lease() == "run 2"
    with pytest.raises(LeaseError):
        second.go_safe()


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda t: t + np.array([40.0, 0.0]), "FFJ3 breaks its upper position limit"),
        (lambda t: t - np.array([0.0, 25.0]), "FFJ4 breaks its lower position limit"),
        (lambda t: t[::8], "FFJ3 breaks its velocity limit"),
        (lambda t: t[:, :1], "shape"),
        (lambda t: np.where(np.arange(len(t))[:, None] == 7, np.nan, t), "finite value"),
    ],
)
def test_unsafe_trajectories_are_refused_before_anything_moves(
    sim_rig: SimulatedRig, short_touch: FloatArray, change: object, message: str
) -> None:
    bus = sim_rig.devices.bus
    with sim_rig.rig.acquire("test") as lease:
        before = bus.packets_received
        with pytest.raises(UnsafeTrajectoryError, match=message):
            lease.touch(change(short_touch))  # type: ignore[operator]
        assert bus.packets_received == before
    assert sim_rig.rig.state is RigState.IDLE


def test_emergency_stop_from_another_thread(sim_rig: SimulatedRig, short_touch: FloatArray) -> None:
    rig = sim_rig.rig

    def stop_from_operator_thread() -> None:
        operator = threading.Thread(target=rig.estop, args=("operator pressed stop",))
        operator.start()
        operator.join()

    with rig.acquire("test") as lease:
        lease.move_to_slot(2)
        with pytest.raises(EmergencyStopped) as raised:
            lease.touch(short_touch, on_progress=at_step(40, stop_from_operator_thread))
        partial = raised.value.partial_record
        assert partial is not None
        assert not partial.complete
        assert 100 < partial.n_frames < 200  # ~40 setpoints of 40 ms at 100 frames/s
        assert b"\x18" in sim_rig.devices.grbl.received  # GRBL soft reset
        status = rig.status()
        assert status.state is RigState.ESTOPPED
        assert status.fault == "operator pressed stop"
        held = finger_pose(sim_rig)
        sim_rig.devices.clock.sleep(1.0)
        np.testing.assert_allclose(finger_pose(sim_rig), held, atol=0.2)  # held in place
        with pytest.raises(EmergencyStopped):
            lease.move_to_slot(1)
        lease.recover()
        assert rig.state is RigState.IDLE
        lease.move_to_slot(2)
        assert lease.touch(short_touch).complete


def test_tactile_stall_mid_touch(sim_rig: SimulatedRig, short_touch: FloatArray) -> None:
    sensor = sim_rig.devices.sensor
    with sim_rig.rig.acquire("test") as lease:
        with pytest.raises(DeviceTimeout, match="stalled") as raised:
            lease.touch(short_touch, on_progress=at_step(40, sensor.stall))
        partial = raised.value.partial_record
        assert partial is not None
        assert 140 <= partial.n_frames <= 170  # everything before the stall is kept
        assert "DeviceTimeout" in (partial.failure or "")
        assert sim_rig.rig.state is RigState.FAULT
        np.testing.assert_allclose(finger_pose(sim_rig), [0.0, 0.0], atol=0.3)  # retracted
        with pytest.raises(NotConnectedError, match="FAULT"):
            lease.touch(short_touch)
        sensor.stall(False)
        lease.recover()
        assert lease.touch(short_touch).complete


def test_tactile_disconnect_mid_touch(sim_rig: SimulatedRig, short_touch: FloatArray) -> None:
    sensor = sim_rig.devices.sensor
    with sim_rig.rig.acquire("test") as lease:
        with pytest.raises(DeviceDisconnected) as raised:
            lease.touch(short_touch, on_progress=at_step(30, sensor.unplug))
        partial = raised.value.partial_record
        assert partial is not None
        assert partial.n_frames > 100
        assert partial.joint_positions_deg.shape[0] >= 6
        assert sim_rig.rig.state is RigState.FAULT
        np.testing.assert_allclose(finger_pose(sim_rig), [0.0, 0.0], atol=0.3)
        with pytest.raises(DeviceDisconnected):
            lease.recover()  # the sensor is still unplugged
    assert sim_rig.rig.state is RigState.FAULT
    assert "DeviceDisconnected" in (sim_rig.rig.status().fault or "")


def test_a_few_bad_frames_are_counted_too_many_refused(
    sim_rig: SimulatedRig, short_touch: FloatArray
) -> None:
    sensor = sim_rig.devices.sensor
    with sim_rig.rig.acquire("test") as lease:
        lease.move_to_slot(0)

        def spoil_the_stream() -> None:
            sensor.corrupt_frames(3)
            sensor.inject_garbage(b"\x00garbage\xaa\x55\x01")

        record = lease.touch(short_touch, on_progress=at_step(20, spoil_the_stream))
        assert record.complete
        assert record.corrupt_frames >= 3
        assert record.dropped_frames == 3
        assert record.discarded_bytes > 0
        assert abs(record.n_frames - (SHORT_TOUCH_S * FRAME_RATE_HZ - 3)) <= 2
        with pytest.raises(CorruptStreamError, match="tactile frames lost") as raised:
            lease.touch(short_touch, on_progress=at_step(20, lambda: sensor.drop_frames(50)))
        partial = raised.value.partial_record
        assert partial is not None
        assert partial.n_frames > 0
        assert not partial.complete
    assert sim_rig.rig.state is RigState.FAULT


def test_servo_hardware_error_mid_touch(sim_rig: SimulatedRig, short_touch: FloatArray) -> None:
    error = servo_error_mid_touch(sim_rig, short_touch, 3, 35, 1, ServoHardwareErrorFlags.OVERLOAD)
    assert error.partial_record is not None
    assert error.partial_record.n_frames > 100


def test_silent_servo_mid_touch(sim_rig: SimulatedRig, short_touch: FloatArray) -> None:
    bus = sim_rig.devices.bus
    with sim_rig.rig.acquire("test") as lease, pytest.raises(DeviceTimeout, match="FFJ4"):
        lease.touch(short_touch, on_progress=at_step(20, lambda: bus.mute(2)))
    assert sim_rig.rig.state is RigState.FAULT


def test_grbl_alarm_during_a_slot_move(sim_rig: SimulatedRig, short_touch: FloatArray) -> None:
    grbl = sim_rig.devices.grbl
    with sim_rig.rig.acquire("test") as lease:
        grbl.alarm_during_next_move(code=1, fraction=0.5)
        with pytest.raises(GrblAlarm, match="Hard limit"):
            lease.move_to_slot(5)
        status = sim_rig.rig.status()
        assert status.state is RigState.FAULT
        assert "GrblAlarm" in (status.fault or "")
        lease.recover()  # soft reset + homing
        assert lease.move_to_slot(5) == pytest.approx(180.0)


def test_the_table_turns_only_with_the_finger_clear(sim_rig: SimulatedRig) -> None:
    plant = sim_rig.devices.plant
    with sim_rig.rig.acquire("test") as lease:
        sim_rig.rig.finger.write_goal([26.0, 0.0])  # pressing into the paper cup
        sim_rig.devices.clock.sleep(1.0)
        lease.move_to_slot(4)
    assert plant.events.collisions == 0
    assert plant.events.overloads == 0


def test_errors_are_hardware_errors() -> None:
    for error in (DeviceTimeout, DeviceDisconnected, CorruptStreamError, GrblAlarm):
        assert issubclass(error, HardwareError)
