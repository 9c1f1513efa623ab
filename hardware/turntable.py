"""The object turntable: a stepper motor behind a GRBL 1.1 controller.

The table's axis is GRBL's X axis, in degrees (``$100`` is steps per degree, ``$110`` the maximum
rate in degrees per minute, ``$120`` the acceleration in degrees per second²). Objects stand in
``slot_count`` evenly spaced slots; slot k is at ``offset_deg + k · 360 / slot_count``, rounded to
the table's resolution (0.2° by default: 1 full step with ``$100 = 5``).

A move is ``G90 G0 X<deg>`` then ``G4 P0`` (GRBL answers the dwell only once the motion has
finished), then ``?`` status reports until ``Idle`` at the target, each with a timeout and a retry.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field

from hardware.errors import (
    ConfigurationError,
    DeviceFault,
    DeviceTimeout,
    GrblAlarm,
    HardwareError,
    NotConnectedError,
)
from hardware.grbl import (
    CYCLE_START,
    FEED_HOLD,
    SOFT_RESET,
    GrblLink,
    GrblStatus,
    move_command,
    parse_setting,
)
from hardware.transport import Transport

GRBL_BAUDRATE = 115200


@dataclass(frozen=True)
class TurntableConfig:
    """Settings of the turntable driver.

    Attributes:
        slot_count: Number of evenly spaced slots (the paper's table holds 10).
        steps_per_degree: Value ``$100`` must have; written at connect when it differs.
        resolution_deg: Angular resolution; slot angles are rounded to it.
        offset_deg: Angle of slot 0.
        home_on_connect: Run ``$H`` at connect when GRBL has homing enabled (``$22=1``);
            otherwise an alarm lock is cleared with ``$X``.
        banner_timeout_s: How long to wait for the start-up banner before a soft reset.
        reply_timeout_s: Timeout for the answer to an ordinary command.
        homing_timeout_s: Timeout for ``$H``.
        move_timeout_s: Timeout for a move to finish (the ``ok`` to ``G4 P0``).
        status_timeout_s: Timeout for one ``?`` status report.
        status_retries: Extra ``?`` queries after a status timeout.
        position_tolerance_deg: Accepted distance between the reported and the target angle.
    """

    slot_count: int = 10
    steps_per_degree: float = 5.0
    resolution_deg: float = 0.2
    offset_deg: float = 0.0
    home_on_connect: bool = True
    banner_timeout_s: float = 2.5
    reply_timeout_s: float = 1.0
    homing_timeout_s: float = 60.0
    move_timeout_s: float = 30.0
    status_timeout_s: float = 0.5
    status_retries: int = 2
    position_tolerance_deg: float = 0.1

    def __post_init__(self) -> None:
        if self.slot_count < 1:
            raise ConfigurationError(f"slot_count: must be >= 1, received {self.slot_count}.")
        for name in (
            "steps_per_degree",
            "resolution_deg",
            "banner_timeout_s",
            "reply_timeout_s",
            "homing_timeout_s",
            "move_timeout_s",
            "status_timeout_s",
            "position_tolerance_deg",
        ):
            if not float(getattr(self, name)) > 0:
                raise ConfigurationError(
                    f"{name}: must be positive, received {getattr(self, name)}."
                )
        if self.status_retries < 0:
            raise ConfigurationError(
                f"status_retries: must be >= 0, received {self.status_retries}."
            )


@dataclass(frozen=True)
class TurntableInfo:
    """What :meth:`Turntable.connect` found.

    Attributes:
        version: GRBL version from the banner (``"1.1h"``).
        settings: GRBL's ``$$`` settings after connect.
        homed: Whether a homing cycle ran.
        position_deg: Table angle after connect.
    """

    version: str
    settings: dict[int, float] = field(default_factory=dict)
    homed: bool = False
    position_deg: float = 0.0


class Turntable:
    """GRBL 1.1 turntable driver.

    Args:
        transport: The controller's port (115200 baud for a stock GRBL).
        config: Driver settings.
    """

    def __init__(self, transport: Transport, config: TurntableConfig | None = None) -> None:
        self.transport = transport
        self.config = config or TurntableConfig()
        self.link = GrblLink(transport)
        self._lock = threading.RLock()
        self._connected = False
        self._settings: dict[int, float] = {}
        self.version: str | None = None
        self.position_deg: float | None = None
        self.slot: int | None = None

    # -- geometry -----------------------------------------------------------------------------

    def slot_angle(self, slot: int) -> float:
        """Table angle of ``slot`` in degrees, rounded to the resolution.

        Raises:
            ConfigurationError: ``slot`` is not in ``0..slot_count-1``.
        """
        if isinstance(slot, bool) or not isinstance(slot, int):
            raise ConfigurationError(f"slot: expected an integer, received {slot!r}.")
        if not 0 <= slot < self.config.slot_count:
            raise ConfigurationError(
                f"slot: expected 0..{self.config.slot_count - 1}, received {slot}."
            )
        resolution = self.config.resolution_deg
        raw = self.config.offset_deg + slot * 360.0 / self.config.slot_count
        return round(round(raw / resolution) * resolution, 6)

    @property
    def connected(self) -> bool:
        """Whether the controller is connected, unlocked and in step with the driver."""
        return self._connected

    @property
    def settings(self) -> dict[int, float]:
        """GRBL's settings read at connect (``$$``)."""
        return dict(self._settings)

    # -- connection ---------------------------------------------------------------------------

    def connect(self) -> TurntableInfo:
        """Open the port, reach a known state and check the settings.

        The banner is awaited (an Arduino resets when its port opens); without one a soft reset
        makes GRBL print it again. Then ``$$`` is read, ``$100`` written if it differs, and an
        alarm lock is cleared: ``$H`` when homing is enabled and ``home_on_connect``, else ``$X``.

        Raises:
            DeviceTimeout: No banner even after a soft reset, or no answer to a command.
            GrblCommandError, GrblAlarm: GRBL refused a command or raised an alarm.
        """
        with self._lock:
            self._connected = False
            if not self.transport.is_open:
                self.transport.open()
            self.link.banner_version = None
            self._await_banner()
            self._settings = self._read_settings()
            wanted = self.config.steps_per_degree
            if (
                abs(self._settings.get(100, float("nan")) - wanted) > 1e-3
                or 100 not in self._settings
            ):
                self.link.request(f"$100={wanted:.3f}", self.config.reply_timeout_s)
                self._settings[100] = wanted
            status = self._status()
            homed = False
            if status.state == "Alarm":
                if self._settings.get(22, 0.0) == 1.0 and self.config.home_on_connect:
                    self.link.request("$H", self.config.homing_timeout_s)
                    homed = True
                else:
                    self.link.request("$X", self.config.reply_timeout_s)
                status = self._status()
            if status.state != "Idle":
                raise DeviceFault(
                    f"{self.transport.name}: GRBL is {status.state!r} after connect, expected Idle."
                )
            self.position_deg = status.machine_position[0]
            self.slot = self._slot_at(self.position_deg)
            self._connected = True
            assert self.link.banner_version is not None
            self.version = self.link.banner_version
            return TurntableInfo(self.version, dict(self._settings), homed, self.position_deg)

    def close(self) -> None:
        """Close the port."""
        with self._lock:
            self._connected = False
            self.transport.close()

    def _await_banner(self) -> None:
        link = self.link
        if self._banner_within(self.config.banner_timeout_s):
            return
        link.send_realtime(SOFT_RESET)
        if self._banner_within(max(self.config.reply_timeout_s, 1.0)):
            return
        raise DeviceTimeout(
            f"{self.transport.name}: no GRBL banner, even after a soft reset: is this a GRBL 1.1 "
            f"controller at {GRBL_BAUDRATE} baud?"
        )

    def _banner_within(self, timeout_s: float) -> bool:
        link = self.link
        deadline = self.transport.now() + timeout_s
        while link.banner_version is None:
            remaining = deadline - self.transport.now()
            if remaining <= 0:
                return False
            line = link.read_line(remaining)
            if line is None:
                return False
            link.handle_push(line)  # anything else before the banner is noise from before the reset
        # Let the rest of the start-up output ([MSG:...]) arrive.
        while link.next_message(0.05) is not None:
            pass
        return True

    def _read_settings(self) -> dict[int, float]:
        reply = self.link.request("$$", self.config.reply_timeout_s)
        settings: dict[int, float] = {}
        for line in reply.lines:
            parsed = parse_setting(line)
            if parsed is not None:
                settings[parsed[0]] = parsed[1]
        return settings

    def _require_connected(self) -> None:
        if not self._connected:
            raise NotConnectedError(
                f"{self.transport.name}: the turntable is not connected (or lost step after a "
                f"fault); call connect() first."
            )

    # -- status and motion --------------------------------------------------------------------

    def _status(self) -> GrblStatus:
        """``?`` with a timeout and ``status_retries`` retries."""
        attempts = self.config.status_retries + 1
        for _ in range(attempts):
            status = self.link.query_status(self.config.status_timeout_s)
            if status is not None:
                return status
        raise DeviceTimeout(
            f"{self.transport.name}: no status report from GRBL after {attempts} queries of "
            f"{self.config.status_timeout_s:g} s."
        )

    def status(self) -> GrblStatus:
        """A fresh status report.

        Raises:
            DeviceTimeout: No report after the retries.
        """
        with self._lock:
            try:
                status = self._status()
            except HardwareError:
                self._connected = False
                raise
            self.position_deg = status.machine_position[0]
            return status

    def move_to_slot(self, slot: int) -> float:
        """Turn slot ``slot`` under the finger and wait until the table stands still there.

        Returns:
            The table angle reported by GRBL.

        Raises:
            ConfigurationError: Bad slot.
            DeviceTimeout: The move did not finish in ``move_timeout_s`` or status queries failed.
            GrblAlarm, GrblCommandError: GRBL raised an alarm or refused the move.
        """
        angle = self.slot_angle(slot)
        position = self.move_to_angle(angle)
        self.slot = slot
        return position

    def move_to_angle(self, angle_deg: float) -> float:
        """Move to an absolute table angle and wait until Idle there. See :meth:`move_to_slot`."""
        with self._lock:
            self._require_connected()
            self.slot = None
            try:
                self.link.request(move_command(angle_deg), self.config.reply_timeout_s)
                # G4 P0 is answered once the planner is empty: the move has finished.
                self.link.request("G4 P0", self.config.move_timeout_s)
                status = self._status()
            except (DeviceTimeout, GrblAlarm):
                self._connected = False
                raise
            self.position_deg = status.machine_position[0]
            if status.state != "Idle":
                self._connected = False
                raise DeviceFault(
                    f"{self.transport.name}: GRBL is {status.state!r} after the move, expected "
                    f"Idle."
                )
            if abs(self.position_deg - angle_deg) > self.config.position_tolerance_deg:
                self._connected = False
                raise DeviceFault(
                    f"{self.transport.name}: the table stopped at {self.position_deg:.3f}°, "
                    f"expected {angle_deg:.3f}°."
                )
            self.slot = self._slot_at(self.position_deg)
            return self.position_deg

    def _slot_at(self, angle_deg: float) -> int | None:
        for slot in range(self.config.slot_count):
            if abs(self.slot_angle(slot) - angle_deg) <= self.config.position_tolerance_deg:
                return slot
        return None

    def home(self) -> None:
        """Run the homing cycle ``$H`` (GRBL must have ``$22=1``)."""
        with self._lock:
            self._require_connected()
            self.link.request("$H", self.config.homing_timeout_s)
            status = self._status()
            self.position_deg = status.machine_position[0]
            self.slot = self._slot_at(self.position_deg)

    def feed_hold(self) -> None:
        """``!``: decelerate to a stop, keeping position (resume with :meth:`resume`)."""
        self.link.send_realtime(FEED_HOLD)

    def resume(self) -> None:
        """``~``: resume after a feed hold."""
        self.link.send_realtime(CYCLE_START)

    def emergency_stop(self) -> None:
        """Soft reset ``0x18`` now, from any thread; the table must be reconnected afterwards.

        A reset during a motion makes GRBL raise ALARM:3 and lose its position; the next
        :meth:`connect` homes or unlocks it again.
        """
        self._connected = False
        self.transport.write(SOFT_RESET)
