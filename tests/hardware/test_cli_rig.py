"""``activetouch rig``: status, home, slot, touch, estop on simulated rigs."""

from __future__ import annotations

import json
import time

from typer.testing import CliRunner

from app.cli.rig import rig_app
from hardware.clock import ScaledClock
from hardware.sim.rig import simulated_devices, start_emulators

runner = CliRunner()


def test_status_of_a_simulated_rig() -> None:
    result = runner.invoke(rig_app, ["status", "--sim", "--json"])
    assert result.exit_code == 0, result.output
    document = json.loads(result.stdout)
    assert document["state"] == "idle"
    assert document["grbl_version"] == "1.1h"
    assert document["servo_models"] == {"FFJ3": 1020, "FFJ4": 1020}
    assert document["simulated_objects"][3] == "stainless_cup"
    assert set(document["tactile_sample"]) == set(document["tactile_channels"])


def test_slot_and_home() -> None:
    result = runner.invoke(rig_app, ["slot", "7", "--sim", "--json"])
    assert result.exit_code == 0, result.output
    assert json.loads(result.stdout)["table_angle_deg"] == 252.0
    result = runner.invoke(rig_app, ["home", "--sim", "--json"])
    assert result.exit_code == 0, result.output
    assert json.loads(result.stdout)["table_angle_deg"] == 0.0


def test_touch_prints_the_observation() -> None:
    result = runner.invoke(
        rig_app,
        ["touch", "--sim", "--slot", "3", "--duration", "5", "--action", "0,0,0,1,0,0", "--json"],
    )
    assert result.exit_code == 0, result.output
    document = json.loads(result.stdout)
    assert document["slot"] == 3
    assert document["frames"] == 500
    assert document["dropped_frames"] == 0
    assert document["observation"]["heat_flux_mw"] > 50.0  # the steel cup
    assert document["action"] == [0.0, 0.0, 0.0, 1.0, 0.0, 0.0]


def test_bad_usage_exits_2() -> None:
    result = runner.invoke(rig_app, ["status"])
    assert result.exit_code == 2
    assert "missing --turntable-port, --finger-port, --tactile-port" in result.output
    result = runner.invoke(rig_app, ["touch", "--sim", "--action", "1,2"])
    assert result.exit_code == 2
    assert "expected 6 numbers" in result.output


def test_device_error_exits_1() -> None:
    result = runner.invoke(
        rig_app,
        [
            "status",
            "--turntable-port",
            "/dev/does-not-exist-1",
            "--finger-port",
            "/dev/does-not-exist-2",
            "--tactile-port",
            "/dev/does-not-exist-3",
        ],
    )
    assert result.exit_code == 1
    assert "DeviceUnavailable" in result.output
    result = runner.invoke(rig_app, ["slot", "12", "--sim"])
    assert result.exit_code == 1
    assert "slot: expected 0..9" in result.output


def test_estop_on_real_ports_resets_grbl_and_frees_the_servos() -> None:
    devices = simulated_devices(clock=ScaledClock(10.0))
    devices.plant.set_torque(0, True)
    devices.plant.set_torque(1, True)
    emulators = start_emulators(devices)
    try:
        result = runner.invoke(
            rig_app,
            [
                "estop",
                "--turntable-port",
                emulators["turntable"].port,
                "--finger-port",
                emulators["finger"].port,
            ],
        )
        assert result.exit_code == 0, result.output
        # Each emulator serves its port on its own thread: wait for both to have acted.
        deadline = time.monotonic() + 5.0
        while time.monotonic() < deadline and (
            devices.plant.joint_state(0)[3]
            or devices.plant.joint_state(1)[3]
            or b"\x18" not in devices.grbl.received
        ):
            time.sleep(0.01)
        assert b"\x18" in devices.grbl.received
        assert not devices.plant.joint_state(0)[3]
        assert not devices.plant.joint_state(1)[3]
    finally:
        for emulator in emulators.values():
            emulator.stop()
