"""The 2-DoF finger: Dynamixel Protocol 2.0 servos through the ``dynamixel-sdk`` package.

The joints are the paper's FFJ3 (flexion) and FFJ4 (abduction) of the index finger. The driver
builds no packet itself: it calls the SDK's packet handler and group writers. What it adds:

- :class:`SdkPort` gives the SDK a port made from a :class:`~hardware.transport.Transport`
  (so this module opens no port and the same code runs against a pseudo-terminal emulator or an
  in-process simulator). Where the SDK's own ``PortHandler`` polls the port with a zero timeout
  in a busy loop, :meth:`SdkPort.readPort` blocks until bytes arrive or the packet times out.
- Late replies: the SDK flushes the input before each instruction, but a status packet arriving
  after the SDK gave up can still be taken for the next answer. After a timeout or a corrupt reply
  the driver waits for the line to stay quiet for one reply timeout, dropping what arrives, and
  flushes again before it retries.
- Every status packet's error byte is checked: the alert bit (0x80) makes the driver read the
  Hardware Error Status and raise :class:`~hardware.errors.ServoHardwareError` with the decoded
  :class:`~hardware.errors.ServoHardwareErrorFlags`; other errors raise
  :class:`~hardware.errors.ServoCommandError`.

Control-table addresses are those of the X series (XM430/XH430), Protocol 2.0.
"""

from __future__ import annotations

import functools
import math
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import dynamixel_sdk as dxl
import numpy as np
import numpy.typing as npt

from hardware.errors import (
    ConfigurationError,
    DeviceTimeout,
    HardwareError,
    NotConnectedError,
    ProtocolError,
    ServoCommandError,
    ServoHardwareError,
    ServoHardwareErrorFlags,
    UnsafeTrajectoryError,
)
from hardware.transport import Transport

FloatArray = npt.NDArray[np.float64]

DYNAMIXEL_BAUDRATE = 1_000_000
BROADCAST_ID = 0xFE

# X-series control table (Protocol 2.0).
ADDR_MODEL_NUMBER = 0
ADDR_OPERATING_MODE = 11
ADDR_VELOCITY_LIMIT = 44
ADDR_MAX_POSITION_LIMIT = 48
ADDR_MIN_POSITION_LIMIT = 52
ADDR_TORQUE_ENABLE = 64
ADDR_HARDWARE_ERROR_STATUS = 70
ADDR_PROFILE_VELOCITY = 112
ADDR_GOAL_POSITION = 116
ADDR_PRESENT_CURRENT = 126
ADDR_PRESENT_VELOCITY = 128
ADDR_PRESENT_POSITION = 132
PRESENT_BLOCK_LENGTH = 10  # current (2) + velocity (4) + position (4), from address 126

OPERATING_MODE_POSITION = 3
DEG_PER_TICK = 360.0 / 4096.0
CENTRE_TICK = 2048
MA_PER_CURRENT_UNIT = 2.69
DEG_S_PER_VELOCITY_UNIT = 0.229 * 6.0  # 0.229 rev/min

PACKET_ERRORS: dict[int, str] = {
    1: "result fail: the instruction could not be processed",
    2: "instruction error: undefined instruction, or action without reg write",
    3: "CRC error: the packet's CRC does not match",
    4: "data range error: the value is out of the range of the address",
    5: "data length error: the data is shorter than the address needs",
    6: "data limit error: the value exceeds a limit (e.g. a position limit)",
    7: "access error: read-only address, or EEPROM written with torque on",
}
"""Protocol 2.0 status-packet error numbers (bits 0..6 of the error byte)."""

ALERT_BIT = 0x80


#: Reply-timer resolution: time left below this counts as run out (a nanosecond, in ms).
TIMER_RESOLUTION_MS = 1e-6


# ---------------------------------------------------------------------------------------------
# The SDK's port, over a Transport
# ---------------------------------------------------------------------------------------------


class SdkPort:
    """The interface of ``dynamixel_sdk.PortHandler``, implemented over a transport.

    Times are in milliseconds, as in the SDK, on the transport's time base.

    Args:
        transport: An open transport.
        baudrate: Line rate, for the SDK's per-byte timing.
        min_packet_timeout_ms: Lower bound of a reply timeout (the SDK's own is ~34 ms at
            1 Mbaud: twice a 16 ms USB latency timer plus the bytes).
        latency_timer_ms: USB-serial latency timer assumed by the timeout.
        wait_slice_ms: Longest single blocking read while a reply is expected.
    """

    def __init__(
        self,
        transport: Transport,
        baudrate: int = DYNAMIXEL_BAUDRATE,
        min_packet_timeout_ms: float = 0.0,
        latency_timer_ms: float = 16.0,
        wait_slice_ms: float = 5.0,
    ) -> None:
        self.transport = transport
        self.baudrate = int(baudrate)
        self.port_name = transport.name
        self.is_open = transport.is_open
        self.is_using = False
        self.packet_start_time = 0.0
        self.packet_timeout = 0.0
        self.tx_time_per_byte = (1000.0 / self.baudrate) * 10.0
        self.min_packet_timeout_ms = float(min_packet_timeout_ms)
        self.latency_timer_ms = float(latency_timer_ms)
        self.wait_slice_ms = float(wait_slice_ms)

    # The SDK's method names follow its camelCase API.
    def openPort(self) -> bool:  # noqa: N802
        """The transport is opened by its owner; report whether it is open."""
        self.is_open = self.transport.is_open
        return self.is_open

    def closePort(self) -> None:  # noqa: N802
        """Close the transport."""
        self.transport.close()
        self.is_open = False

    def clearPort(self) -> None:  # noqa: N802
        """Discard pending input (the SDK calls this before each instruction)."""
        self.transport.reset_input_buffer()

    def setBaudRate(self, baudrate: int) -> bool:  # noqa: N802
        """Record the baud rate (the transport owns the line settings)."""
        self.baudrate = int(baudrate)
        self.tx_time_per_byte = (1000.0 / self.baudrate) * 10.0
        return True

    def getBaudRate(self) -> int:  # noqa: N802
        """The baud rate."""
        return self.baudrate

    def getPortName(self) -> str:  # noqa: N802
        """The transport's name."""
        return self.port_name

    def getBytesAvailable(self) -> int:  # noqa: N802
        """Not tracked: a read returns what is there."""
        return 0

    def _now_ms(self) -> float:
        return self.transport.now() * 1000.0

    def _remaining_ms(self) -> float:
        """Time left on the reply timer."""
        return self.packet_timeout - (self._now_ms() - self.packet_start_time)

    def readPort(self, length: int) -> bytes:  # noqa: N802
        """Up to ``length`` bytes; blocks (without spinning) while the reply is still due."""
        wait_ms = min(max(self._remaining_ms(), 0.0), self.wait_slice_ms)
        return self.transport.read(max(1, int(length)), wait_ms / 1000.0)

    def writePort(self, packet: Sequence[int]) -> int:  # noqa: N802
        """Write an instruction packet; returns the number of bytes written."""
        data = bytes(packet)
        self.transport.write(data)
        return len(data)

    def setPacketTimeout(self, packet_length: int) -> None:  # noqa: N802
        """Start the reply timer for a reply of ``packet_length`` bytes."""
        timeout = self.tx_time_per_byte * packet_length + self.latency_timer_ms * 2.0 + 2.0
        self.packet_start_time = self._now_ms()
        self.packet_timeout = max(timeout, self.min_packet_timeout_ms)

    def setPacketTimeoutMillis(self, msec: float) -> None:  # noqa: N802
        """Start the reply timer for ``msec`` milliseconds."""
        self.packet_start_time = self._now_ms()
        self.packet_timeout = max(float(msec), self.min_packet_timeout_ms)

    def isPacketTimeout(self) -> bool:  # noqa: N802
        """Whether the reply timer has run out (to within :data:`TIMER_RESOLUTION_MS`: a wait
        shorter than that cannot advance a simulation clock that has run for seconds, so the
        timer would never run out)."""
        if self._remaining_ms() < TIMER_RESOLUTION_MS:
            self.packet_timeout = 0.0
            return True
        return False

    def drain_late_replies(self, quiet_ms: float | None = None, limit_ms: float = 250.0) -> int:
        """Read and drop bytes until the line has been quiet for ``quiet_ms``.

        The default quiet time is one reply timeout: a reply up to twice the timeout late is
        caught here instead of being read as the answer to the next instruction (Protocol 2.0
        has no sequence numbers; a reply later than that cannot be told from an answer).

        Returns:
            The number of bytes dropped.
        """
        if quiet_ms is None:
            quiet_ms = max(self.min_packet_timeout_ms, self.latency_timer_ms * 2.0 + 2.0)
        dropped = 0
        deadline = self._now_ms() + limit_ms
        while self._now_ms() < deadline:
            chunk = self.transport.read(4096, quiet_ms / 1000.0)
            if not chunk:
                break
            dropped += len(chunk)
        self.transport.reset_input_buffer()
        return dropped


# ---------------------------------------------------------------------------------------------
# Configuration and state
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class JointConfig:
    """One finger joint on one servo.

    Attributes:
        name: Joint name (``"FFJ3"``).
        servo_id: Dynamixel ID (1..252).
        lower_deg: Lower position limit (also written to the servo's Min Position Limit).
        upper_deg: Upper position limit (Max Position Limit).
        max_velocity_deg_s: Velocity limit checked before moving (also the servo's profile
            velocity, a second line of defence).
        zero_tick: Servo position that is 0° of the joint.
        direction: +1, or -1 if the servo turns the other way.
    """

    name: str
    servo_id: int
    lower_deg: float
    upper_deg: float
    max_velocity_deg_s: float
    zero_tick: int = CENTRE_TICK
    direction: int = 1

    def __post_init__(self) -> None:
        if not 0 <= self.servo_id <= 252:
            raise ConfigurationError(
                f"{self.name}: servo_id must be in 0..252, received {self.servo_id}."
            )
        if not self.lower_deg < self.upper_deg:
            raise ConfigurationError(
                f"{self.name}: lower_deg ({self.lower_deg}) must be below upper_deg "
                f"({self.upper_deg})."
            )
        if not self.max_velocity_deg_s > 0:
            raise ConfigurationError(
                f"{self.name}: max_velocity_deg_s must be positive, received "
                f"{self.max_velocity_deg_s}."
            )
        if self.direction not in (1, -1):
            raise ConfigurationError(
                f"{self.name}: direction must be +1 or -1, received {self.direction}."
            )
        for bound in (self.lower_deg, self.upper_deg):
            tick = self.to_tick(bound)
            if not 0 <= tick <= 4095:
                raise ConfigurationError(
                    f"{self.name}: {bound}° maps to servo position {tick}, outside 0..4095."
                )

    def to_tick(self, angle_deg: float) -> int:
        """Joint angle → servo position value."""
        return round(self.zero_tick + self.direction * angle_deg / DEG_PER_TICK)

    def to_deg(self, tick: int) -> float:
        """Servo position value → joint angle."""
        return (tick - self.zero_tick) * DEG_PER_TICK * self.direction


def default_joints() -> tuple[JointConfig, JointConfig]:
    """FFJ3 (flexion, ID 1) and FFJ4 (abduction, ID 2) with the rig's limits."""
    return (
        JointConfig("FFJ3", 1, lower_deg=-10.0, upper_deg=60.0, max_velocity_deg_s=90.0),
        JointConfig("FFJ4", 2, lower_deg=-20.0, upper_deg=20.0, max_velocity_deg_s=90.0),
    )


@dataclass(frozen=True)
class FingerConfig:
    """Finger driver settings.

    Attributes:
        joints: The joints, in trajectory column order.
        baudrate: Bus baud rate.
        min_packet_timeout_ms: Lower bound of a reply timeout.
        retries: Extra attempts after a timeout or a corrupt reply.
        expected_models: Model numbers accepted at ping (empty: any).
        set_profile_velocity: Write each joint's velocity limit as its profile velocity.
    """

    joints: tuple[JointConfig, ...] = field(default_factory=default_joints)
    baudrate: int = DYNAMIXEL_BAUDRATE
    min_packet_timeout_ms: float = 20.0
    retries: int = 2
    expected_models: tuple[int, ...] = ()
    set_profile_velocity: bool = True

    def __post_init__(self) -> None:
        if not self.joints:
            raise ConfigurationError("joints: at least one joint is needed.")
        ids = [joint.servo_id for joint in self.joints]
        if len(set(ids)) != len(ids):
            raise ConfigurationError(f"joints: servo IDs must be distinct, received {ids}.")
        if self.retries < 0:
            raise ConfigurationError(f"retries: must be >= 0, received {self.retries}.")


@dataclass(frozen=True)
class FingerState:
    """Present state of every joint (arrays in joint order, shape (J,)).

    Attributes:
        positions_deg: Present positions.
        velocities_deg_s: Present velocities.
        currents_ma: Present currents (signed).
    """

    positions_deg: FloatArray
    velocities_deg_s: FloatArray
    currents_ma: FloatArray


def _signed(value: int, bits: int) -> int:
    return value - (1 << bits) if value >= 1 << (bits - 1) else value


# ---------------------------------------------------------------------------------------------
# The driver
# ---------------------------------------------------------------------------------------------


class Finger:
    """Two (or more) position-controlled Dynamixel joints.

    Every bus transaction holds :attr:`bus_lock`, so an emergency stop from another thread waits
    for the packet in flight instead of interleaving bytes with it.

    Args:
        transport: The bus's port (1 Mbaud by default).
        config: Joints and bus settings.
    """

    def __init__(self, transport: Transport, config: FingerConfig | None = None) -> None:
        self.transport = transport
        self.config = config or FingerConfig()
        self.joints = self.config.joints
        self.bus_lock = threading.RLock()
        self.port = SdkPort(
            transport,
            baudrate=self.config.baudrate,
            min_packet_timeout_ms=self.config.min_packet_timeout_ms,
        )
        self.packets: Any = dxl.PacketHandler(2.0)
        self._sync_write: Any = dxl.GroupSyncWrite(self.port, self.packets, ADDR_GOAL_POSITION, 4)
        self._connected = False
        self.models: dict[str, int] = {}
        self.torque_enabled = False
        self.retries_used = 0
        self.late_bytes_dropped = 0

    @property
    def connected(self) -> bool:
        """Whether :meth:`connect` succeeded and no fault has occurred since."""
        return self._connected

    # -- transactions -------------------------------------------------------------------------

    def _transact(
        self,
        joint: JointConfig,
        what: str,
        call: Callable[[], tuple[Any, int, int]],
        check_alert: bool = True,
    ) -> Any:
        """Run one SDK request/reply with retries; check the status packet's error byte."""
        attempts = self.config.retries + 1
        last_result = 0
        for attempt in range(attempts):
            with self.bus_lock:
                try:
                    value, result, error = call()
                except HardwareError:
                    self.port.is_using = False
                    raise
                finally:
                    self.port.is_using = False
                if result == dxl.COMM_SUCCESS:
                    break
                last_result = int(result)
                if result not in (dxl.COMM_RX_TIMEOUT, dxl.COMM_RX_CORRUPT):
                    raise ProtocolError(
                        f"{joint.name} (ID {joint.servo_id}) {what}: "
                        f"{self.packets.getTxRxResult(result)}"
                    )
                if attempt + 1 < attempts:
                    self.retries_used += 1
                    self.late_bytes_dropped += self.port.drain_late_replies()
        else:
            message = (
                f"{joint.name} (ID {joint.servo_id}) {what}: "
                f"{self.packets.getTxRxResult(last_result)} after {attempts} attempt(s)"
            )
            if last_result == dxl.COMM_RX_TIMEOUT:
                raise DeviceTimeout(f"{self.transport.name}: {message}")
            raise ProtocolError(f"{self.transport.name}: {message}")
        if error & ALERT_BIT and check_alert:
            raise self._hardware_error(joint)
        code = int(error) & 0x7F
        if code:
            raise ServoCommandError(
                joint.name, joint.servo_id, code, PACKET_ERRORS.get(code, "unknown error"), what
            )
        return value

    def _hardware_error(self, joint: JointConfig) -> ServoHardwareError:
        flags = self.read_hardware_error(joint)
        self._connected = False
        self.torque_enabled = False
        return ServoHardwareError(joint.name, joint.servo_id, flags)

    def read_hardware_error(self, joint: JointConfig) -> ServoHardwareErrorFlags:
        """Read and decode a joint's Hardware Error Status (address 70)."""
        value = self._transact(
            joint,
            "read of the hardware error status",
            lambda: self.packets.read1ByteTxRx(
                self.port, joint.servo_id, ADDR_HARDWARE_ERROR_STATUS
            ),
            check_alert=False,
        )
        return ServoHardwareErrorFlags(int(value))

    def _write1(self, joint: JointConfig, address: int, value: int, what: str) -> None:
        self._transact(
            joint,
            what,
            lambda: (
                None,
                *self.packets.write1ByteTxRx(self.port, joint.servo_id, address, value),
            ),
        )

    def _write4(self, joint: JointConfig, address: int, value: int, what: str) -> None:
        self._transact(
            joint,
            what,
            lambda: (
                None,
                *self.packets.write4ByteTxRx(self.port, joint.servo_id, address, value),
            ),
        )

    # -- life cycle ---------------------------------------------------------------------------

    def ping(self) -> dict[str, int]:
        """Ping every joint's servo; returns the model numbers by joint name."""
        models: dict[str, int] = {}
        for joint in self.joints:
            model = self._transact(
                joint, "ping", functools.partial(self.packets.ping, self.port, joint.servo_id)
            )
            models[joint.name] = int(model)
        return models

    def connect(self) -> dict[str, int]:
        """Ping, check for hardware errors, write mode and limits (torque off), enable torque.

        Returns:
            Model numbers by joint name.

        Raises:
            DeviceTimeout: A servo does not answer.
            ServoHardwareError: A servo has a hardware error (reboot it with :meth:`reboot`).
            ConfigurationError: A servo has a model that is not in ``expected_models``.
        """
        if not self.transport.is_open:
            self.transport.open()
        self.port.is_open = True
        self._connected = False
        self.models = self.ping()
        for joint in self.joints:
            model = self.models[joint.name]
            if self.config.expected_models and model not in self.config.expected_models:
                raise ConfigurationError(
                    f"{joint.name} (ID {joint.servo_id}): model {model} is not one of "
                    f"{self.config.expected_models}."
                )
            flags = self.read_hardware_error(joint)
            if flags:
                raise ServoHardwareError(joint.name, joint.servo_id, flags)
        self.set_torque(False)
        for joint in self.joints:
            self._write1(joint, ADDR_OPERATING_MODE, OPERATING_MODE_POSITION, "operating mode")
            low, high = sorted((joint.to_tick(joint.lower_deg), joint.to_tick(joint.upper_deg)))
            self._write4(joint, ADDR_MIN_POSITION_LIMIT, low, "min position limit")
            self._write4(joint, ADDR_MAX_POSITION_LIMIT, high, "max position limit")
            if self.config.set_profile_velocity:
                units = math.ceil(joint.max_velocity_deg_s / DEG_S_PER_VELOCITY_UNIT)
                self._write4(joint, ADDR_VELOCITY_LIMIT, units, "velocity limit")
                self._write4(joint, ADDR_PROFILE_VELOCITY, units, "profile velocity")
        self.set_torque(True)
        self._connected = True
        return dict(self.models)

    def close(self) -> None:
        """Close the bus port (torque is left as it is)."""
        self._connected = False
        self.transport.close()

    def reboot(self) -> None:
        """Reboot every servo (clears hardware errors; torque comes back off)."""
        for joint in self.joints:
            self._transact(
                joint,
                "reboot",
                functools.partial(self._reboot_call, joint.servo_id),
                check_alert=False,
            )
        self.torque_enabled = False
        self._connected = False

    def _reboot_call(self, servo_id: int) -> tuple[None, int, int]:
        result, error = self.packets.reboot(self.port, servo_id)
        return None, int(result), int(error)

    def set_torque(self, enabled: bool) -> None:
        """Torque on or off on every joint."""
        for joint in self.joints:
            self._write1(joint, ADDR_TORQUE_ENABLE, 1 if enabled else 0, "torque enable")
        self.torque_enabled = enabled

    # -- motion -------------------------------------------------------------------------------

    def _require_connected(self) -> None:
        if not self._connected:
            raise NotConnectedError(
                f"{self.transport.name}: the finger is not connected (or faulted); call "
                f"connect() first."
            )

    def check_setpoint(self, positions_deg: npt.ArrayLike) -> FloatArray:
        """Validate one setpoint against the joint limits; returns it as an array (J,).

        Raises:
            UnsafeTrajectoryError: A joint is outside its position limits.
        """
        goal = np.asarray(positions_deg, dtype=np.float64)
        if goal.shape != (len(self.joints),) or not np.all(np.isfinite(goal)):
            raise UnsafeTrajectoryError(
                ",".join(j.name for j in self.joints),
                "shape",
                float("nan"),
                float(len(self.joints)),
                0,
                f"(expected {len(self.joints)} finite values, received shape {goal.shape})",
            )
        for joint, value in zip(self.joints, goal, strict=True):
            if value < joint.lower_deg:
                raise UnsafeTrajectoryError(
                    joint.name, "lower position", float(value), joint.lower_deg, 0, "deg"
                )
            if value > joint.upper_deg:
                raise UnsafeTrajectoryError(
                    joint.name, "upper position", float(value), joint.upper_deg, 0, "deg"
                )
        return goal

    def write_goal(self, positions_deg: npt.ArrayLike) -> None:
        """Sync-write goal positions to every joint (one broadcast packet, no reply).

        Args:
            positions_deg: One goal per joint. Shape (J,).
        """
        self._require_connected()
        goal = self.check_setpoint(positions_deg)
        writer = self._sync_write
        with self.bus_lock:
            for joint, value in zip(self.joints, goal, strict=True):
                tick = joint.to_tick(float(value))
                data = list(tick.to_bytes(4, "little", signed=False))
                if not writer.changeParam(joint.servo_id, data):
                    writer.addParam(joint.servo_id, data)
            try:
                result = writer.txPacket()
            finally:
                self.port.is_using = False
        if result != dxl.COMM_SUCCESS:
            raise ProtocolError(
                f"{self.transport.name}: sync write failed: {self.packets.getTxRxResult(result)}"
            )

    def read_state(self) -> FingerState:
        """Present current, velocity and position of every joint (one read per servo).

        Raises:
            ServoHardwareError: A servo reports a hardware error.
            DeviceTimeout: A servo does not answer.
        """
        positions, velocities, currents = [], [], []
        for joint in self.joints:
            data = self._transact(
                joint,
                "read of present state",
                functools.partial(
                    self.packets.readTxRx,
                    self.port,
                    joint.servo_id,
                    ADDR_PRESENT_CURRENT,
                    PRESENT_BLOCK_LENGTH,
                ),
            )
            raw = bytes(data)
            if len(raw) != PRESENT_BLOCK_LENGTH:
                raise ProtocolError(
                    f"{joint.name} (ID {joint.servo_id}): read returned {len(raw)} bytes, "
                    f"expected {PRESENT_BLOCK_LENGTH}."
                )
            current = int.from_bytes(raw[0:2], "little", signed=True)
            velocity = int.from_bytes(raw[2:6], "little", signed=True)
            position = int.from_bytes(raw[6:10], "little", signed=True)
            currents.append(current * MA_PER_CURRENT_UNIT)
            velocities.append(velocity * DEG_S_PER_VELOCITY_UNIT * joint.direction)
            positions.append(joint.to_deg(position))
        return FingerState(
            positions_deg=np.array(positions),
            velocities_deg_s=np.array(velocities),
            currents_ma=np.array(currents),
        )

    def hold(self) -> FingerState:
        """Hold the present position (goal := present position) and return the state."""
        self._require_connected()
        state = self.read_state()
        goal = np.clip(
            state.positions_deg,
            [j.lower_deg for j in self.joints],
            [j.upper_deg for j in self.joints],
        )
        self.write_goal(goal)
        return state

    def emergency_stop(self, torque_off: bool, lock_timeout_s: float = 0.5) -> None:
        """Stop the finger from any thread: hold position, or switch torque off.

        Waits up to ``lock_timeout_s`` for the packet in flight; the stop itself is sent even if
        the bus stays busy (a broadcast torque-off, which needs no reply). Errors are swallowed:
        a stop must not raise.
        """
        acquired = self.bus_lock.acquire(timeout=lock_timeout_s)
        try:
            self.port.is_using = False
            if torque_off or not self._connected:
                self.packets.write1ByteTxOnly(self.port, BROADCAST_ID, ADDR_TORQUE_ENABLE, 0)
                self.port.is_using = False
                self.torque_enabled = False
            else:
                self.hold()
        except HardwareError:
            try:
                self.port.is_using = False
                self.packets.write1ByteTxOnly(self.port, BROADCAST_ID, ADDR_TORQUE_ENABLE, 0)
                self.torque_enabled = False
            except HardwareError:
                pass
        finally:
            self.port.is_using = False
            if acquired:
                self.bus_lock.release()
