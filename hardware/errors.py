"""Errors raised by :mod:`hardware`.

Every error raised on purpose derives from :class:`HardwareError`. The specific classes say what
went wrong in a way a caller can act on (the web app maps them to HTTP codes: a timeout to 504, an
unavailable device to 503, a busy rig to 409, a rejected argument to 422):

- :class:`DeviceTimeout` — a device did not answer in time.
- :class:`DeviceDisconnected` — the port went away (cable, power, emulator stopped).
- :class:`DeviceUnavailable` — the port could not be opened at all.
- :class:`ProtocolError` — bytes arrived that do not follow the protocol;
  :class:`CorruptStreamError` when too many tactile frames are lost or corrupt.
- :class:`DeviceFault` — the device reports a fault of its own: :class:`GrblAlarm`,
  :class:`ServoHardwareError` (with a decoded :class:`ServoHardwareErrorFlags`).
- :class:`CommandRejected` — the device refused a command: :class:`GrblCommandError`,
  :class:`ServoCommandError`.
- :class:`UnsafeTrajectoryError` — a trajectory breaks a joint limit; nothing was sent.
- :class:`RigBusy`, :class:`LeaseError`, :class:`EmergencyStopped`, :class:`NotConnectedError`,
  :class:`ConfigurationError`.

An error raised in the middle of a touch carries what was recorded up to that moment in
``partial_record``, so that nothing recorded is lost.
"""

from __future__ import annotations

import enum
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from hardware.records import TouchRecord


class HardwareError(Exception):
    """Base class of every error raised by :mod:`hardware`.

    Attributes:
        partial_record: The touch recorded up to the failure, when the error interrupted a touch.
    """

    partial_record: TouchRecord | None = None


class ConfigurationError(HardwareError, ValueError):
    """A setting or argument is unusable (a slot out of range, a bad port name, ...)."""


class NotConnectedError(HardwareError):
    """A device was used before :meth:`connect` or after :meth:`close`."""


class DeviceUnavailable(HardwareError):  # noqa: N818
    """The port could not be opened (missing, busy, no permission)."""


class DeviceTimeout(HardwareError, TimeoutError):  # noqa: N818
    """A device did not answer within its timeout (after the configured retries)."""


class DeviceDisconnected(HardwareError, ConnectionError):  # noqa: N818
    """The connection to a device was lost."""


class ProtocolError(HardwareError):
    """Bytes arrived that do not follow the device's protocol."""


class CorruptStreamError(ProtocolError):
    """Too many tactile frames were corrupt or missing for the recording to be trusted."""


class DeviceFault(HardwareError):  # noqa: N818
    """The device reports a fault of its own (alarm, hardware error)."""


class GrblAlarm(DeviceFault):
    """GRBL entered its alarm state (``ALARM:N``).

    Attributes:
        code: The GRBL 1.1 alarm code.
        name: GRBL's short name for it.
        meaning: GRBL's description (what happened, what to do).
    """

    def __init__(self, code: int, name: str, meaning: str) -> None:
        super().__init__(f"GRBL ALARM:{code} ({name}): {meaning}")
        self.code = code
        self.name = name
        self.meaning = meaning


class ServoHardwareErrorFlags(enum.IntFlag):
    """Dynamixel X-series Hardware Error Status (control table address 70)."""

    NONE = 0x00
    INPUT_VOLTAGE = 0x01
    OVERHEATING = 0x04
    MOTOR_ENCODER = 0x08
    ELECTRICAL_SHOCK = 0x10
    OVERLOAD = 0x20

    def describe(self) -> str:
        """Readable names of the set bits, e.g. ``"OVERLOAD|OVERHEATING"``."""
        names = [flag.name for flag in type(self) if flag in self and flag.name]
        unknown = int(self) & ~sum(int(flag) for flag in type(self))
        if unknown:
            names.append(f"unknown bits 0x{unknown:02X}")
        return "|".join(names) or "none"


class ServoHardwareError(DeviceFault):
    """A servo reports a hardware error; it has switched its torque off.

    Attributes:
        joint: Name of the joint (e.g. ``"FFJ3"``).
        servo_id: Dynamixel ID.
        flags: The decoded Hardware Error Status.
    """

    def __init__(self, joint: str, servo_id: int, flags: ServoHardwareErrorFlags) -> None:
        super().__init__(
            f"servo {joint} (ID {servo_id}) reports a hardware error: {flags.describe()} "
            f"(status 0x{int(flags):02X}); its torque is off until it is rebooted."
        )
        self.joint = joint
        self.servo_id = servo_id
        self.flags = flags


class CommandRejected(HardwareError):  # noqa: N818
    """The device understood the command and refused it."""


class GrblCommandError(CommandRejected):
    """GRBL answered ``error:N``.

    Attributes:
        code: The GRBL 1.1 error code.
        name: GRBL's short name for it.
        meaning: GRBL's description.
        command: The line that was refused.
    """

    def __init__(self, code: int, name: str, meaning: str, command: str) -> None:
        super().__init__(f"GRBL refused {command!r}: error:{code} ({name}): {meaning}")
        self.code = code
        self.name = name
        self.meaning = meaning
        self.command = command


class ServoCommandError(CommandRejected):
    """A servo answered with a packet error (data range, access, ...).

    Attributes:
        joint: Name of the joint.
        servo_id: Dynamixel ID.
        code: The Protocol 2.0 error number (1..7).
        meaning: What it means.
    """

    def __init__(self, joint: str, servo_id: int, code: int, meaning: str, what: str) -> None:
        super().__init__(f"servo {joint} (ID {servo_id}) refused {what}: {meaning} (error {code})")
        self.joint = joint
        self.servo_id = servo_id
        self.code = code
        self.meaning = meaning


class UnsafeTrajectoryError(HardwareError, ValueError):
    """A trajectory breaks a joint limit; it was refused before anything moved.

    Attributes:
        joint: The joint whose limit is broken.
        limit: ``"lower position"``, ``"upper position"`` or ``"velocity"`` (or ``"shape"``).
        value: The offending value (degrees or degrees per second).
        bound: The limit it breaks.
        sample: Index of the first offending sample.
    """

    def __init__(
        self, joint: str, limit: str, value: float, bound: float, sample: int, unit: str
    ) -> None:
        super().__init__(
            f"trajectory refused: joint {joint} breaks its {limit} limit at sample {sample}: "
            f"{value:.3f} {unit} (limit {bound:.3f} {unit})."
        )
        self.joint = joint
        self.limit = limit
        self.value = value
        self.bound = bound
        self.sample = sample


class RigBusy(HardwareError):  # noqa: N818
    """Another run holds the rig's lease.

    Attributes:
        owner: Who holds it.
    """

    def __init__(self, owner: str) -> None:
        super().__init__(f"the rig is in use by {owner!r}; wait for it to finish or stop it.")
        self.owner = owner


class LeaseError(HardwareError):
    """A lease was used after it was released (or taken over)."""


class EmergencyStopped(HardwareError):  # noqa: N818
    """The rig was emergency-stopped; it must be recovered before it moves again."""
