"""``activetouch rig``: check a rig before any run.

Each command opens the three ports (or a simulated rig with ``--sim``), does one thing and
closes them again::

    activetouch rig status --turntable-port /dev/ttyACM0 --finger-port /dev/ttyUSB0 \\
        --tactile-port /dev/ttyUSB1
    activetouch rig home --sim
    activetouch rig slot 3 --sim
    activetouch rig touch --slot 3 --action 0,0,0,1,0,0 --sim --json
    activetouch rig estop --turntable-port /dev/ttyACM0 --finger-port /dev/ttyUSB0

Ports can also come from ``ACTIVETOUCH_TURNTABLE_PORT``, ``ACTIVETOUCH_FINGER_PORT`` and
``ACTIVETOUCH_TACTILE_PORT``. Exit codes: 0 success, 1 a device error, 2 bad usage.

:class:`~app.cli.options.RigOptions` (the port/simulation options, declared once) and
:func:`connected_rig` (open, lease, connect, close) serve every command here and
``activetouch collect``. The drivers, numpy and the
DMPs are imported when a command runs, not when the CLI starts.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.markup import escape

from app.cli.options import AsJson, RigOptions, rig_options
from app.cli.output import fail
from app.cli.output import messages as console
from app.cli.output import results as stdout

if TYPE_CHECKING:  # the drivers, numpy and the DMPs are imported when a command runs
    import numpy as np

    from app.rig.actions import TouchActions
    from app.rig.build import RigHandle
    from hardware.records import TouchRecord
    from hardware.rig import RigLease, RigStatus

rig_app = typer.Typer(
    help="Check the rig: status, homing, turning a slot under the finger, a touch, e-stop.",
    no_args_is_help=True,
)


@contextmanager
def connected_rig(options: RigOptions, owner: str) -> Iterator[tuple[RigHandle, RigLease]]:
    """Open the rig, lease it to ``owner``, connect it; release and close it afterwards.

    A device error (while connecting or in the ``with`` body) prints its type and message and
    exits with code 1.
    """
    from hardware.errors import HardwareError

    try:
        handle = options.open()
    except HardwareError as exc:
        raise fail(f"{type(exc).__name__}: {exc}", 1) from None
    try:
        with handle.rig.acquire(owner) as lease:
            lease.connect()
            yield handle, lease
    except HardwareError as exc:
        raise fail(f"{type(exc).__name__}: {exc}", 1) from None
    finally:
        handle.close()


def _on_rig(
    options: RigOptions,
    command: str,
    operation: Callable[[RigLease, RigHandle], dict[str, Any]],
    as_json: bool,
) -> None:
    """Run one operation on the connected rig and print the document it returns."""
    with connected_rig(options, f"activetouch rig {command}") as (handle, lease):
        _print(operation(lease, handle), as_json)


def _status_document(lease: RigLease, handle: RigHandle) -> dict[str, Any]:
    """What the devices say, after the command's operation."""
    status: RigStatus = lease.status()
    rig = handle.rig
    document: dict[str, Any] = {
        "state": status.state.value,
        "slot": status.slot,
        "table_angle_deg": status.table_angle_deg,
        "finger_deg": None if status.finger_deg is None else list(status.finger_deg),
        "fault": status.fault,
        "devices": status.devices,
        "grbl_version": rig.turntable.version,
        "servo_models": rig.finger.models,
        "tactile_channels": list(rig.tactile.config.channel_names),
    }
    last = rig.tactile.last_frame
    if last is not None:
        document["tactile_sample"] = dict(
            zip(rig.tactile.config.channel_names, last.channels, strict=True)
        )
    if handle.object_names is not None:
        if handle.table is not None:
            document["simulated_table"] = handle.table.name
            document["simulated_table_action_std"] = handle.table.action_std
        document["simulated_objects"] = handle.object_names
        document["simulated_materials"] = {
            name: str(record["material"])
            for name, record in (handle.object_properties() or {}).items()
        }
    return document


def _print(document: dict[str, Any], as_json: bool) -> None:
    if as_json:
        sys.stdout.write(json.dumps(document) + "\n")
        return
    for key, value in document.items():
        if isinstance(value, float):
            value = f"{value:.3f}"
        elif isinstance(value, dict):
            value = ", ".join(
                f"{k}={v:.3f}" if isinstance(v, float) else f"{k}={v}" for k, v in value.items()
            )
        stdout.print(f"[bold]{escape(key)}[/bold]: {escape(str(value))}")


@rig_app.command()
@rig_options
def status(
    rig: RigOptions,
    as_json: AsJson = False,
) -> None:
    """Connect the three devices and report what they say (GRBL version, servo models,...)."""
    _on_rig(rig, "status", _status_document, as_json)


@rig_app.command()
@rig_options
def home(
    rig: RigOptions,
    as_json: AsJson = False,
) -> None:
    """Retract the finger and run the turntable's homing cycle ($H)."""

    def operation(lease: RigLease, handle: RigHandle) -> dict[str, Any]:
        lease.home()
        return _status_document(lease, handle)

    _on_rig(rig, "home", operation, as_json)


@rig_app.command()
@rig_options
def slot(
    k: Annotated[int, typer.Argument(help="Slot to turn under the finger (0-based).")],
    rig: RigOptions,
    as_json: AsJson = False,
) -> None:
    """Turn slot K under the finger (the finger is retracted first)."""

    def operation(lease: RigLease, handle: RigHandle) -> dict[str, Any]:
        lease.move_to_slot(k)
        return _status_document(lease, handle)

    _on_rig(rig, "slot", operation, as_json)


def _parse_action(text: str, dimension: int) -> np.ndarray:
    import numpy as np

    try:
        values = [float(part) for part in text.split(",")] if text.strip() else []
    except ValueError:
        raise fail(
            f"--action: expected {dimension} comma-separated numbers, got {text!r}."
        ) from None
    if len(values) != dimension:
        raise fail(f"--action: expected {dimension} numbers, got {len(values)}.")
    return np.asarray(values, dtype=np.float64)


def _touch_document(record: TouchRecord, action: np.ndarray) -> dict[str, Any]:
    import numpy as np

    return {
        "slot": record.slot,
        "action": action.tolist(),
        "observation": dict(zip(record.channel_names, record.observation.tolist(), strict=True)),
        "frames": record.n_frames,
        "dropped_frames": record.dropped_frames,
        "corrupt_frames": record.corrupt_frames,
        "late_setpoints": record.late_steps,
        "duration_s": record.duration_s,
        "peak_current_ma": dict(
            zip(
                record.joint_names,
                np.abs(record.joint_currents_ma).max(axis=0).tolist(),
                strict=True,
            )
        )
        if record.joint_currents_ma.size
        else {},
    }


def touch_actions(duration_s: float, press_depth: bool = False) -> TouchActions:
    """The rig's action → trajectory map for touches of ``duration_s``, with the press-depth
    component as the action's last dimension if ``press_depth`` (bad values exit 2)."""
    from app.rig.actions import TouchActions
    from core.errors import CoreError
    from hardware.rig import RigConfig

    try:
        return TouchActions.from_teaching(
            dt_s=RigConfig().control_period_s, duration_s=duration_s, press_depth=press_depth
        )
    except CoreError as exc:
        raise fail(str(exc), 2) from None


@rig_app.command()
@rig_options
def touch(
    rig: RigOptions,
    slot_k: Annotated[
        int | None, typer.Option("--slot", help="Turn this slot under the finger first.")
    ] = None,
    action: Annotated[
        str,
        typer.Option(
            help="Action x: 6 comma-separated numbers (0 = the teaching touch), or 7 with the "
            "press depth last."
        ),
    ] = "0,0,0,0,0,0",
    duration_s: Annotated[
        float, typer.Option("--duration", min=1.0, help="Touch duration in seconds.")
    ] = 14.4,
    as_json: AsJson = False,
) -> None:
    """Execute one touch (action → DMP → trajectory) and print its observation y."""
    from app.rig.action_layout import has_press_depth

    press_depth = has_press_depth(len(action.split(","))) is True
    actions = touch_actions(duration_s, press_depth)
    x = _parse_action(action, actions.action_dim)

    def operation(lease: RigLease, handle: RigHandle) -> dict[str, Any]:
        return _touch_document(actions.touch(lease, x, slot=slot_k), x)

    _on_rig(rig, "touch", operation, as_json)


@rig_app.command()
@rig_options
def estop(rig: RigOptions) -> None:
    """Emergency stop: GRBL soft reset and servo torque off, without waiting for anything.

    Only the turntable and finger ports are used (``--tactile-port`` is accepted and ignored).
    A port held by another program (a running server) cannot be opened: stop the rig through
    that program (``POST /api/v1/rig/estop``).
    """
    from hardware.errors import HardwareError
    from hardware.finger import DYNAMIXEL_BAUDRATE, Finger
    from hardware.transport import SerialTransport
    from hardware.turntable import GRBL_BAUDRATE, Turntable

    handle: RigHandle | None = None
    if rig.sim:
        handle = rig.open()
        turntable: Turntable | None = handle.rig.turntable
        finger: Finger | None = handle.rig.finger
    else:
        if not rig.turntable_port and not rig.finger_port:
            raise fail("give --turntable-port and/or --finger-port (or use --sim).")
        turntable = (
            Turntable(SerialTransport(rig.turntable_port, GRBL_BAUDRATE))
            if rig.turntable_port
            else None
        )
        finger = (
            Finger(SerialTransport(rig.finger_port, DYNAMIXEL_BAUDRATE))
            if rig.finger_port
            else None
        )
    stopped = []
    try:
        if turntable is not None:
            try:
                turntable.transport.open()
                turntable.emergency_stop()
                stopped.append("turntable (soft reset)")
            except HardwareError as exc:
                console.print(f"[yellow]warning:[/yellow] turntable: {escape(str(exc))}")
        if finger is not None:
            try:
                finger.transport.open()
                finger.emergency_stop(torque_off=True)
                stopped.append("finger (torque off)")
            except HardwareError as exc:
                console.print(f"[yellow]warning:[/yellow] finger: {escape(str(exc))}")
    finally:
        for device in (turntable, finger):
            if device is not None:
                device.transport.close()
        if handle is not None:
            handle.close()
    if not stopped:
        raise fail("no device could be reached.", 1)
    stdout.print(f"emergency stop sent to: {escape(', '.join(stopped))}")
