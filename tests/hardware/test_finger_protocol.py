"""Byte-exact Dynamixel Protocol 2.0 exchanges of the finger driver (through dynamixel-sdk).

The packets expected are checked first against the examples of the ROBOTIS e-manual, so the
conversation below does not depend on the emulator's own packet code being right.
"""

from __future__ import annotations

import numpy as np
import pytest

from hardware.errors import (
    DeviceTimeout,
    ServoCommandError,
    ServoHardwareError,
    ServoHardwareErrorFlags,
    UnsafeTrajectoryError,
)
from hardware.finger import Finger, FingerConfig, JointConfig
from hardware.sim.dynamixel_device import build_packet
from hardware.sim.protocol import ExpectedProtocol

# Protocol 2.0 examples from the ROBOTIS e-manual.
PING_1 = bytes.fromhex("ff ff fd 00 01 03 00 01 19 4e")
PING_1_STATUS_XM430_W210 = bytes.fromhex("ff ff fd 00 01 07 00 55 00 06 04 26 65 5d")
READ_1_PRESENT_POSITION = bytes.fromhex("ff ff fd 00 01 07 00 02 84 00 04 00 1d 15")
READ_1_STATUS_166 = bytes.fromhex("ff ff fd 00 01 08 00 55 00 a6 00 00 00 8c c0")
SYNC_WRITE_GOALS_150_170 = bytes.fromhex(
    "ff ff fd 00 fe 11 00 83 74 00 04 00 01 96 00 00 00 02 aa 00 00 00 82 87"
)


def instruction(servo_id: int, code: int, params: bytes = b"") -> bytes:
    return build_packet(servo_id, code, params)


def status(servo_id: int, error: int = 0, params: bytes = b"") -> bytes:
    return build_packet(servo_id, 0x55, bytes([error]) + params)


def write(servo_id: int, address: int, value: int, size: int) -> bytes:
    return instruction(
        servo_id, 0x03, address.to_bytes(2, "little") + value.to_bytes(size, "little")
    )


def read(servo_id: int, address: int, size: int) -> bytes:
    return instruction(servo_id, 0x02, address.to_bytes(2, "little") + size.to_bytes(2, "little"))


def test_packet_codec_matches_the_emanual() -> None:
    assert instruction(1, 0x01) == PING_1
    assert status(1, 0, bytes([0x06, 0x04, 0x26])) == PING_1_STATUS_XM430_W210
    assert read(1, 132, 4) == READ_1_PRESENT_POSITION
    assert status(1, 0, (166).to_bytes(4, "little")) == READ_1_STATUS_166
    params = bytes([0x74, 0, 4, 0, 1, 0x96, 0, 0, 0, 2, 0xAA, 0, 0, 0])
    assert instruction(0xFE, 0x83, params) == SYNC_WRITE_GOALS_150_170


def raw_joints() -> FingerConfig:
    """Joints whose tick 0 is 0° (so ticks and degrees match the manual's examples)."""
    return FingerConfig(
        joints=(
            JointConfig("FFJ3", 1, 0.0, 359.0, 90.0, zero_tick=0),
            JointConfig("FFJ4", 2, 0.0, 359.0, 90.0, zero_tick=0),
        ),
        min_packet_timeout_ms=5.0,
    )


def test_ping_reads_model_numbers() -> None:
    link = ExpectedProtocol(
        [
            (PING_1, PING_1_STATUS_XM430_W210),
            (instruction(2, 0x01), status(2, 0, bytes([0xFC, 0x03, 46]))),
        ]
    )
    assert Finger(link, raw_joints()).ping() == {"FFJ3": 1030, "FFJ4": 1020}
    link.assert_done()


def test_connect_sequence() -> None:
    config = FingerConfig()  # FFJ3 on ID 1 (-10..60°), FFJ4 on ID 2 (-20..20°), 90°/s
    ok1, ok2 = status(1), status(2)
    link = ExpectedProtocol(
        [
            (instruction(1, 0x01), status(1, 0, bytes([0xFC, 0x03, 46]))),
            (instruction(2, 0x01), status(2, 0, bytes([0xFC, 0x03, 46]))),
            (read(1, 70, 1), status(1, 0, b"\x00")),
            (read(2, 70, 1), status(2, 0, b"\x00")),
            (write(1, 64, 0, 1), ok1),
            (write(2, 64, 0, 1), ok2),
            (write(1, 11, 3, 1), ok1),
            (write(1, 52, 1934, 4), ok1),  # -10° = 2048 - 113.8 ticks
            (write(1, 48, 2731, 4), ok1),  # 60° = 2048 + 682.7 ticks
            (write(1, 44, 66, 4), ok1),  # 90°/s in 0.229 rpm units
            (write(1, 112, 66, 4), ok1),
            (write(2, 11, 3, 1), ok2),
            (write(2, 52, 1820, 4), ok2),
            (write(2, 48, 2276, 4), ok2),
            (write(2, 44, 66, 4), ok2),
            (write(2, 112, 66, 4), ok2),
            (write(1, 64, 1, 1), ok1),
            (write(2, 64, 1, 1), ok2),
        ]
    )
    finger = Finger(link, config)
    assert finger.connect() == {"FFJ3": 1020, "FFJ4": 1020}
    link.assert_done()
    assert finger.connected
    assert finger.torque_enabled


def connected_raw(
    extra: list[tuple[bytes | None, bytes | None]],
) -> tuple[Finger, ExpectedProtocol]:
    link = ExpectedProtocol(extra)
    finger = Finger(link, raw_joints())
    finger._connected = True  # skip the connect conversation (tested above)
    return finger, link


def test_goals_are_one_sync_write() -> None:
    finger, link = connected_raw([(SYNC_WRITE_GOALS_150_170, None)])
    finger.write_goal([150 * 360 / 4096, 170 * 360 / 4096])
    link.assert_done()


def test_present_state_read_and_decoded() -> None:
    block = (
        (-10).to_bytes(2, "little", signed=True)
        + (5).to_bytes(4, "little")
        + (166).to_bytes(4, "little")
    )
    finger, link = connected_raw(
        [
            (read(1, 126, 10), status(1, 0, block)),
            (read(2, 126, 10), status(2, 0, block)),
        ]
    )
    state = finger.read_state()
    link.assert_done()
    np.testing.assert_allclose(state.currents_ma, [-26.9, -26.9])
    np.testing.assert_allclose(state.velocities_deg_s, [5 * 1.374, 5 * 1.374])
    np.testing.assert_allclose(state.positions_deg, [166 * 360 / 4096] * 2)


def test_alert_bit_reads_and_decodes_the_hardware_error() -> None:
    finger, link = connected_raw(
        [
            (read(1, 126, 10), status(1, 0x80, bytes(10))),
            (read(1, 70, 1), status(1, 0x80, bytes([0x24]))),
        ]
    )
    with pytest.raises(ServoHardwareError) as raised:
        finger.read_state()
    link.assert_done()
    error = raised.value
    assert error.joint == "FFJ3"
    assert error.servo_id == 1
    assert error.flags == ServoHardwareErrorFlags.OVERLOAD | ServoHardwareErrorFlags.OVERHEATING
    assert "OVERHEATING|OVERLOAD" in str(error)
    assert not finger.connected


def test_packet_error_is_a_command_error() -> None:
    finger, _link = connected_raw([(write(1, 64, 1, 1), status(1, 6))])
    with pytest.raises(ServoCommandError, match="data limit") as raised:
        finger.set_torque(True)
    assert raised.value.code == 6


def test_silent_servo_is_retried_then_times_out() -> None:
    finger, link = connected_raw([(PING_1, None), (PING_1, None), (PING_1, None)])
    with pytest.raises(DeviceTimeout, match="after 3 attempt"):
        finger.ping()
    link.assert_done()
    assert finger.retries_used == 2


def test_setpoint_outside_limits_is_refused_before_sending() -> None:
    finger, link = connected_raw([])
    finger.joints = FingerConfig().joints
    with pytest.raises(UnsafeTrajectoryError, match="FFJ4 breaks its upper position limit"):
        finger.write_goal([0.0, 25.0])
    assert link.written == b""
