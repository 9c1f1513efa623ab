"""The turntable driver against the GRBL emulator on a pseudo-terminal (pyserial, 115200 baud)."""

from __future__ import annotations

import time
from collections.abc import Iterator

import pytest

from hardware.clock import ScaledClock
from hardware.errors import DeviceTimeout, GrblAlarm, GrblCommandError
from hardware.sim.grbl_device import GrblDevice
from hardware.sim.pty import PtyEmulator
from hardware.transport import SerialTransport
from hardware.turntable import GRBL_BAUDRATE, Turntable, TurntableConfig

CONFIG = TurntableConfig(banner_timeout_s=0.2, reply_timeout_s=0.5, move_timeout_s=5.0)


@pytest.fixture
def grbl() -> Iterator[tuple[GrblDevice, PtyEmulator]]:
    device = GrblDevice(ScaledClock(20.0))
    with PtyEmulator(device, "grbl") as emulator:
        yield device, emulator


def open_table(emulator: PtyEmulator) -> Turntable:
    table = Turntable(SerialTransport(emulator.port, GRBL_BAUDRATE), CONFIG)
    table.connect()
    return table


def test_connect_homes_sets_steps_and_moves_between_slots(
    grbl: tuple[GrblDevice, PtyEmulator],
) -> None:
    device, emulator = grbl
    table = open_table(emulator)
    assert table.version == "1.1h"
    assert device.settings[100] == 5.0
    assert "$H" in device.lines_received
    for slot in (3, 9, 0, 5):
        angle = table.move_to_slot(slot)
        assert angle == pytest.approx(36.0 * slot)
        assert device.position()[0] == pytest.approx(36.0 * slot)
    assert device.state == "Idle"
    assert all(not line.endswith("\r") for line in device.lines_received)
    table.close()


def test_crlf_would_give_two_answers(grbl: tuple[GrblDevice, PtyEmulator]) -> None:
    """Why the driver never sends \\r\\n: GRBL answers the empty line too."""
    _, emulator = grbl
    port = SerialTransport(emulator.port, GRBL_BAUDRATE)
    port.open()
    port.write(b"\x18")
    time.sleep(0.1)
    port.reset_input_buffer()
    port.write(b"$$\r\n")
    received = b""
    deadline = time.monotonic() + 2.0
    while received.count(b"ok") < 2 and time.monotonic() < deadline:
        received += port.read(4096, 0.2)
    assert received.count(b"ok\r\n") == 2
    port.close()


def test_alarm_in_the_middle_of_a_move(grbl: tuple[GrblDevice, PtyEmulator]) -> None:
    device, emulator = grbl
    table = open_table(emulator)
    device.alarm_during_next_move(code=1, fraction=0.5)
    with pytest.raises(GrblAlarm, match="Hard limit") as raised:
        table.move_to_slot(5)
    assert raised.value.code == 1
    assert 0.0 < device.position()[0] < 180.0  # stopped halfway
    assert device.state == "Alarm"
    with pytest.raises(Exception, match="not connected"):
        table.move_to_slot(1)
    table.connect()  # soft reset + homing clear the alarm
    assert table.move_to_slot(1) == pytest.approx(36.0)


def test_soft_reset_during_motion_is_alarm_3(grbl: tuple[GrblDevice, PtyEmulator]) -> None:
    device, emulator = grbl
    table = open_table(emulator)
    table.link.request("G90 G0 X300.000", 0.5)
    table.emergency_stop()

    def keep_listening() -> None:
        for _ in range(20):
            table.link.next_message(0.1)

    with pytest.raises(GrblAlarm, match="ALARM:3"):
        keep_listening()
    assert device.state == "Alarm"


def test_command_refused_in_alarm_state(grbl: tuple[GrblDevice, PtyEmulator]) -> None:
    _, emulator = grbl
    table = open_table(emulator)
    table.link.send_realtime(b"\x18")  # reset while idle: homing lock again
    time.sleep(0.05)
    with pytest.raises(GrblCommandError, match="error:9"):
        table.link.request("G90 G0 X36.000", 0.5)


def test_silent_controller_times_out(grbl: tuple[GrblDevice, PtyEmulator]) -> None:
    device, emulator = grbl
    table = open_table(emulator)
    device.mute()
    with pytest.raises(DeviceTimeout):
        table.move_to_slot(2)
