"""Byte-exact GRBL 1.1 conversations of the turntable driver (against a scripted transport)."""

from __future__ import annotations

import pytest

from hardware.errors import (
    ConfigurationError,
    DeviceTimeout,
    GrblAlarm,
    GrblCommandError,
    NotConnectedError,
    ProtocolError,
)
from hardware.grbl import GRBL_ALARMS, GRBL_ERRORS, parse_setting, parse_status
from hardware.sim.protocol import ExpectedProtocol, ProtocolMismatchError
from hardware.turntable import Turntable, TurntableConfig

BANNER = b"\r\nGrbl 1.1h ['$' for help]\r\n"
LOCKED = b"[MSG:'$H'|'$X' to unlock]\r\n"
SETTINGS_FACTORY = b"$0=10\r\n$22=1\r\n$100=250.000\r\n$110=3600.000\r\nok\r\n"
SETTINGS_READY = b"$0=10\r\n$22=1\r\n$100=5.000\r\n$110=3600.000\r\nok\r\n"
IDLE_AT_0 = b"<Idle|MPos:0.000,0.000,0.000|FS:0,0>\r\n"
FAST = TurntableConfig(
    banner_timeout_s=0.05, reply_timeout_s=0.05, status_timeout_s=0.05, move_timeout_s=0.05
)


def connected(extra: list[tuple[bytes | None, bytes | None]]) -> tuple[Turntable, ExpectedProtocol]:
    link = ExpectedProtocol(
        [
            (None, BANNER + LOCKED),
            (b"$$\n", SETTINGS_READY),
            (b"?", b"<Alarm|MPos:0.000,0.000,0.000|FS:0,0>\r\n"),
            (b"$H\n", b"ok\r\n"),
            (b"?", IDLE_AT_0),
            *extra,
        ]
    )
    table = Turntable(link, FAST)
    table.connect()
    return table, link


def test_connect_reads_banner_sets_steps_and_homes() -> None:
    link = ExpectedProtocol(
        [
            (None, BANNER + LOCKED),
            (b"$$\n", SETTINGS_FACTORY),
            (b"$100=5.000\n", b"ok\r\n"),
            (b"?", b"<Alarm|MPos:0.000,0.000,0.000|FS:0,0>\r\n"),
            (b"$H\n", b"ok\r\n"),
            (b"?", IDLE_AT_0),
        ]
    )
    info = Turntable(link, FAST).connect()
    link.assert_done()
    assert info.version == "1.1h"
    assert info.homed is True
    assert info.settings[100] == 5.0
    assert b"\r" not in bytes(link.written)  # lines end with \n alone


def test_connect_without_banner_soft_resets_and_unlocks_without_homing() -> None:
    link = ExpectedProtocol(
        [
            (b"\x18", BANNER + LOCKED),
            (b"$$\n", b"$22=0\r\n$100=5.000\r\nok\r\n"),
            (b"?", b"<Alarm|MPos:12.000,0.000,0.000|FS:0,0>\r\n"),
            (b"$X\n", b"[MSG:Caution: Unlocked]\r\nok\r\n"),
            (b"?", b"<Idle|MPos:12.000,0.000,0.000|FS:0,0>\r\n"),
        ]
    )
    info = Turntable(link, FAST).connect()
    link.assert_done()
    assert info.homed is False
    assert info.position_deg == 12.0


def test_no_banner_even_after_reset_times_out() -> None:
    link = ExpectedProtocol([(b"\x18", None)])
    with pytest.raises(DeviceTimeout, match="no GRBL banner"):
        Turntable(link, FAST).connect()


def test_move_to_slot_is_g90_g0_then_dwell_then_status() -> None:
    table, link = connected(
        [
            (b"G90 G0 X108.000\n", b"ok\r\n"),
            (b"G4 P0\n", b"ok\r\n"),
            (b"?", b"<Idle|MPos:108.000,0.000,0.000|FS:0,0>\r\n"),
        ]
    )
    assert table.move_to_slot(3) == 108.0
    link.assert_done()
    assert table.slot == 3


def test_status_query_is_retried_after_a_timeout() -> None:
    table, link = connected(
        [
            (b"G90 G0 X36.000\n", b"ok\r\n"),
            (b"G4 P0\n", b"ok\r\n"),
            (b"?", None),  # lost
            (b"?", b"<Idle|MPos:36.000,0.000,0.000|FS:0,0>\r\n"),
        ]
    )
    assert table.move_to_slot(1) == 36.0
    link.assert_done()


def test_status_timeouts_after_every_retry_raise_and_need_reconnect() -> None:
    table, link = connected(
        [
            (b"G90 G0 X36.000\n", b"ok\r\n"),
            (b"G4 P0\n", b"ok\r\n"),
            (b"?", None),
            (b"?", None),
            (b"?", None),
        ]
    )
    with pytest.raises(DeviceTimeout, match="after 3 queries"):
        table.move_to_slot(1)
    link.assert_done()
    with pytest.raises(NotConnectedError):
        table.move_to_slot(2)


def test_error_reply_carries_grbl_meaning() -> None:
    table, _ = connected([(b"G90 G0 X36.000\n", b"error:9\r\n")])
    with pytest.raises(GrblCommandError) as raised:
        table.move_to_slot(1)
    assert raised.value.code == 9
    assert raised.value.meaning == GRBL_ERRORS[9][1]
    assert "locked out during alarm" in str(raised.value)


def test_alarm_during_move_raises_with_meaning() -> None:
    table, _ = connected([(b"G90 G0 X72.000\n", b"ok\r\n"), (b"G4 P0\n", b"ALARM:1\r\n")])
    with pytest.raises(GrblAlarm) as raised:
        table.move_to_slot(2)
    assert raised.value.code == 1
    assert raised.value.meaning == GRBL_ALARMS[1][1]
    assert "Re-homing is highly recommended" in str(raised.value)
    assert not table.connected


def test_move_that_stops_short_is_a_fault() -> None:
    table, _ = connected(
        [
            (b"G90 G0 X72.000\n", b"ok\r\n"),
            (b"G4 P0\n", b"ok\r\n"),
            (b"?", b"<Idle|MPos:70.000,0.000,0.000|FS:0,0>\r\n"),
        ]
    )
    with pytest.raises(Exception, match=r"stopped at 70\.000"):
        table.move_to_slot(2)


def test_feed_hold_resume_and_emergency_stop_are_single_bytes() -> None:
    table, link = connected([(b"!", None), (b"~", None), (b"\x18", None)])
    table.feed_hold()
    table.resume()
    table.emergency_stop()
    link.assert_done()
    assert not table.connected


def test_unexpected_bytes_fail_the_conversation() -> None:
    table, _ = connected([(b"G90 G0 X36.000\n", b"ok\r\n")])
    with pytest.raises(ProtocolMismatchError):
        table.move_to_slot(2)


def test_slot_angles_are_evenly_spaced_at_the_resolution() -> None:
    table = Turntable(ExpectedProtocol([]), TurntableConfig(slot_count=7))
    assert table.slot_angle(0) == 0.0
    assert table.slot_angle(1) == 51.4  # 51.43° rounded to 0.2°
    assert table.slot_angle(6) == 308.6
    ten = Turntable(ExpectedProtocol([]))
    assert [ten.slot_angle(k) for k in range(10)] == [36.0 * k for k in range(10)]
    with pytest.raises(ConfigurationError, match=r"0\.\.9"):
        ten.slot_angle(10)
    with pytest.raises(ConfigurationError, match="integer"):
        ten.slot_angle(1.5)  # type: ignore[arg-type]


def test_status_and_setting_parsers() -> None:
    status = parse_status("<Hold:1|MPos:1.500,2.000,-3.250|Bf:15,128|FS:600,0|WCO:0,0,0>")
    assert status.state == "Hold"
    assert status.substate == 1
    assert status.machine_position == (1.5, 2.0, -3.25)
    assert status.fields["Bf"] == "15,128"
    with pytest.raises(ProtocolError):
        parse_status("<Idle|FS:0,0>")
    with pytest.raises(ProtocolError):
        parse_status("ok")
    assert parse_setting("$100=5.000") == (100, 5.0)
    assert parse_setting("ok") is None
