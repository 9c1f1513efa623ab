"""The rig: turntable, finger and tactile sensor together.

- One run at a time drives the rig: motion and connection go through a :class:`RigLease` from
  :meth:`Rig.acquire`; a second :meth:`Rig.acquire` gets :class:`~hardware.errors.RigBusy`. The
  rig's operations take the lease as their first argument and refuse any but the current one
  (:class:`~hardware.errors.LeaseError`); the lease's methods call them with itself.
- :meth:`Rig.estop` works at any moment, from any thread, without the lease: GRBL soft reset, the
  finger held (or its torque switched off), every operation in progress stopped with
  :class:`~hardware.errors.EmergencyStopped`; :meth:`RigLease.recover` brings the rig back.
- A touch (:meth:`RigLease.touch`) checks the trajectory against the joint limits before anything
  moves, rests until :attr:`RigConfig.settle_s` has passed since the last touch (the sensor's
  skin recovers its temperature, so every touch starts from the same state), approaches its
  first pose, streams the setpoints at the control rate while it records the
  tactile stream and the joint states, then returns the finger to its safe pose. On any fault the
  rig is left safe (finger retracted or held, table stopped) and the error carries what was
  recorded (``partial_record``).

The rig receives trajectories as arrays: turning an action into a trajectory (DMPs) is done by the
caller, since this package does not import :mod:`core`.
"""

from __future__ import annotations

import contextlib
import enum
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import TypeVar

import numpy as np
import numpy.typing as npt

from hardware.clock import Clock, SystemClock
from hardware.errors import (
    ConfigurationError,
    CorruptStreamError,
    DeviceDisconnected,
    DeviceTimeout,
    EmergencyStopped,
    HardwareError,
    LeaseError,
    NotConnectedError,
    RigBusy,
    ServoHardwareError,
)
from hardware.finger import Finger, FingerState
from hardware.frames import TactileFrame
from hardware.lifecycle import WithBlock
from hardware.records import FloatArray, TouchRecord
from hardware.tactile import TactileRecorder, TactileSensor
from hardware.trajectories import check_trajectory, ramp
from hardware.turntable import Turntable

_T = TypeVar("_T")


class RigState(enum.StrEnum):
    """What the rig is doing."""

    DISCONNECTED = "disconnected"
    IDLE = "idle"
    MOVING = "moving"
    TOUCHING = "touching"
    FAULT = "fault"
    ESTOPPED = "estopped"


@dataclass(frozen=True)
class RigConfig:
    """Rig settings.

    Attributes:
        safe_pose_deg: Finger pose clear of every object (the table may turn). Shape (J,).
        control_period_s: Default period of the setpoint stream (50 Hz).
        state_every: Read the joint states every this many setpoints.
        ramp_velocity_fraction: Approach and retract moves use this fraction of each joint's
            velocity limit.
        safe_pose_tolerance_deg: How close to the safe pose counts as there.
        max_lost_fraction: Largest fraction of tactile frames that may be lost (by sequence
            number, corrupt ones included) before a touch is refused as corrupt.
        estop_torque_off: On emergency stop, switch the finger's torque off instead of holding.
        settle_s: Rest before each touch, the finger clear of every object, counted from the end
            of the previous touch (or from connecting, for the first). A heated fingertip's
            skin cools at every contact and recovers its temperature only over seconds; without
            the rest a touch's thermal channels depend on how long ago the last one ended, so
            the first touch of a session (rested) would differ from a collection's touches (each
            a table turn after the last) and a recognition trial's later touches (none). The
            default is five recovery times of the simulated sensor (docs/simulation.md); set
            it to your sensor's (0: no rest).
    """

    safe_pose_deg: tuple[float, ...] = (0.0, 0.0)
    control_period_s: float = 0.02
    state_every: int = 5
    ramp_velocity_fraction: float = 0.5
    safe_pose_tolerance_deg: float = 1.0
    max_lost_fraction: float = 0.05
    estop_torque_off: bool = False
    settle_s: float = 20.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.settle_s) and self.settle_s >= 0):
            raise ConfigurationError(f"settle_s: must be >= 0, received {self.settle_s}.")
        if not self.control_period_s > 0:
            raise ConfigurationError(
                f"control_period_s: must be positive, received {self.control_period_s}."
            )
        if self.state_every < 1:
            raise ConfigurationError(f"state_every: must be >= 1, received {self.state_every}.")
        if not 0 < self.ramp_velocity_fraction <= 1:
            raise ConfigurationError(
                f"ramp_velocity_fraction: must be in (0, 1], received "
                f"{self.ramp_velocity_fraction}."
            )
        if not 0 <= self.max_lost_fraction < 1:
            raise ConfigurationError(
                f"max_lost_fraction: must be in [0, 1), received {self.max_lost_fraction}."
            )


@dataclass(frozen=True)
class RigStatus:
    """A snapshot of the rig (no device is queried to make it).

    Attributes:
        state: What the rig is doing.
        lease_owner: Who holds the lease, if anyone.
        slot: Slot under the finger, if known.
        table_angle_deg: Last known table angle.
        finger_deg: Last known finger pose.
        fault: Why the rig is in FAULT or ESTOPPED.
        touches: Touches completed since the rig was made.
        devices: Whether each device is connected.
    """

    state: RigState
    lease_owner: str | None
    slot: int | None
    table_angle_deg: float | None
    finger_deg: tuple[float, ...] | None
    fault: str | None
    touches: int
    devices: dict[str, bool] = field(default_factory=dict)


@dataclass(frozen=True)
class TouchProgress:
    """Progress of a touch, passed to ``on_progress`` after each setpoint.

    Attributes:
        step: Index of the setpoint just sent.
        n_steps: Number of setpoints.
        frames: Tactile frames recorded so far.
        time_s: Time since the trajectory started.
    """

    step: int
    n_steps: int
    frames: int
    time_s: float


class Rig:
    """The three devices, a lease, limits and an emergency stop.

    Args:
        turntable: The turntable driver.
        finger: The finger driver.
        tactile: The tactile stream reader.
        config: Rig settings.
        clock: Clock pacing the control loop (the simulation's clock for simulated rigs).
    """

    def __init__(
        self,
        turntable: Turntable,
        finger: Finger,
        tactile: TactileSensor,
        config: RigConfig | None = None,
        clock: Clock | None = None,
    ) -> None:
        self.turntable = turntable
        self.finger = finger
        self.tactile = tactile
        self.config = config or RigConfig()
        self.clock: Clock = clock or SystemClock()
        if len(self.config.safe_pose_deg) != len(finger.joints):
            raise ConfigurationError(
                f"safe_pose_deg: {len(self.config.safe_pose_deg)} values for "
                f"{len(finger.joints)} joints."
            )
        self.finger.check_setpoint(self.config.safe_pose_deg)
        self._state = RigState.DISCONNECTED
        self._fault: str | None = None
        self._estop = threading.Event()
        self._status_lock = threading.Lock()
        self._lease_condition = threading.Condition()
        self._lease: RigLease | None = None
        self._operation = threading.RLock()
        self._last_finger: FloatArray | None = None
        self._touches = 0
        self._rest_from_s = -math.inf  # when the finger last left an object (or connected)

    # -- status, lease, e-stop: from any thread ------------------------------------------------

    @property
    def joint_names(self) -> tuple[str, ...]:
        """Names of the finger joints, in trajectory column order."""
        return tuple(joint.name for joint in self.finger.joints)

    @property
    def state(self) -> RigState:
        """The current state."""
        return self._state

    def status(self) -> RigStatus:
        """A snapshot of the rig's state (no I/O)."""
        with self._status_lock:
            lease = self._lease
            finger = (
                None if self._last_finger is None else tuple(float(v) for v in self._last_finger)
            )
            return RigStatus(
                state=self._state,
                lease_owner=None if lease is None else lease.owner,
                slot=self.turntable.slot,
                table_angle_deg=self.turntable.position_deg,
                finger_deg=finger,
                fault=self._fault,
                touches=self._touches,
                devices={
                    "turntable": self.turntable.connected,
                    "finger": self.finger.connected,
                    "tactile": self.tactile.connected,
                },
            )

    def _set_state(self, state: RigState, fault: str | None = None) -> None:
        with self._status_lock:
            if self._estop.is_set() and state is not RigState.ESTOPPED:
                return  # an emergency stop stays in force until recover()
            self._state = state
            self._fault = fault

    def acquire(self, owner: str, timeout_s: float = 0.0) -> RigLease:
        """Take the lease: the only way to move the rig.

        Args:
            owner: Who takes it (shown to others in :class:`~hardware.errors.RigBusy`).
            timeout_s: How long to wait for the current holder to release it.

        Raises:
            RigBusy: Someone else still holds it after ``timeout_s``.
        """
        with self._lease_condition:
            deadline = self.clock_free_deadline(timeout_s)
            while self._lease is not None:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    raise RigBusy(self._lease.owner)
                self._lease_condition.wait(remaining)
            lease = RigLease(self, owner)
            self._lease = lease
            return lease

    @staticmethod
    def clock_free_deadline(timeout_s: float) -> float:
        """A real-time deadline ``timeout_s`` from now (lease waits are in real time)."""
        return time.monotonic() + max(0.0, timeout_s)

    def holds(self, lease: RigLease) -> bool:
        """Whether ``lease`` is the rig's current lease."""
        return self._lease is lease

    def release(self, lease: RigLease) -> None:
        """Give ``lease`` back (no-op unless it is the current one); wakes a waiting taker."""
        with self._lease_condition:
            if self._lease is lease:
                self._lease = None
                self._lease_condition.notify_all()

    def revoke_lease(self) -> str | None:
        """Take the lease away from its holder (an operator's override); returns the owner."""
        with self._lease_condition:
            lease, self._lease = self._lease, None
            self._lease_condition.notify_all()
        return None if lease is None else lease.owner

    def estop(self, reason: str = "emergency stop") -> None:
        """Stop everything now. Safe to call from any thread, at any time, without the lease.

        GRBL gets a soft reset (it stops at once; after a reset during motion it raises ALARM:3
        and must be homed or unlocked again), the finger is held where it is (or its torque
        switched off, ``estop_torque_off``), and the operation in progress ends with
        :class:`~hardware.errors.EmergencyStopped`. Nothing moves again until
        :meth:`RigLease.recover`.
        """
        self._estop.set()
        with self._status_lock:
            self._state = RigState.ESTOPPED
            self._fault = reason
        try:
            if self.turntable.transport.is_open:
                self.turntable.emergency_stop()
        except HardwareError:
            pass
        if self.finger.transport.is_open:
            self.finger.emergency_stop(torque_off=self.config.estop_torque_off)

    @property
    def estopped(self) -> bool:
        """Whether an emergency stop is in force."""
        return self._estop.is_set()

    # -- operations: public, each with the lease of the caller ---------------------------------

    def _check_lease(self, lease: RigLease) -> None:
        if not lease.active:
            raise LeaseError(f"the lease of {lease.owner!r} is no longer valid.")

    def _check_estop(self) -> None:
        if self._estop.is_set():
            raise EmergencyStopped(
                f"the rig is emergency-stopped ({self._fault or 'no reason given'}); "
                f"recover it first."
            )

    def _require_ready(self) -> None:
        self._check_estop()
        if self._state is RigState.FAULT:
            raise NotConnectedError(f"the rig is in FAULT ({self._fault}); recover it first.")
        if self._state is RigState.DISCONNECTED:
            raise NotConnectedError("the rig is not connected; connect it first.")

    def connect(self, lease: RigLease) -> RigStatus:
        """See :meth:`RigLease.connect`."""
        self._check_lease(lease)
        with self._operation:
            self._check_estop()
            try:
                self.tactile.connect()
                self.finger.connect()
                self._last_finger = self.finger.read_state().positions_deg
                self._set_state(RigState.MOVING)
                self._retract()
                self.turntable.connect()
            except HardwareError as exc:
                self._fail(exc)
                raise self._estop_error(exc) from exc
            self._rest_from_s = self.clock.now()  # what the sensor touched before is unknown
            self._set_state(RigState.IDLE)
            return self.status()

    def close(self, lease: RigLease) -> None:
        """See :meth:`RigLease.close`."""
        self._check_lease(lease)
        with self._operation:
            for device in (self.tactile, self.finger, self.turntable):
                with contextlib.suppress(HardwareError):
                    device.close()
            if not self._estop.is_set():
                self._set_state(RigState.DISCONNECTED)

    def recover(self, lease: RigLease) -> RigStatus:
        """See :meth:`RigLease.recover`."""
        self._check_lease(lease)
        with self._operation:
            self._estop.clear()
            self._set_state(RigState.DISCONNECTED)
            try:
                for transport in (self.tactile.transport, self.finger.transport):
                    if not transport.is_open:
                        transport.reconnect(attempts=2, delay_s=0.2)
                try:
                    self.finger.connect()
                except ServoHardwareError:
                    self.finger.reboot()
                    self.finger.connect()
                except (DeviceDisconnected, DeviceTimeout):
                    self.finger.transport.reconnect(attempts=2, delay_s=0.2)
                    self.finger.connect()
                if not self.turntable.transport.is_open:
                    self.turntable.transport.reconnect(attempts=2, delay_s=0.2)
            except HardwareError as exc:
                self._set_state(RigState.FAULT, f"recovery failed: {type(exc).__name__}: {exc}")
                raise
            return self.connect(lease)

    def _ensure_safe_pose(self) -> None:
        state = self.finger.read_state()
        self._last_finger = state.positions_deg
        distance = np.abs(state.positions_deg - np.asarray(self.config.safe_pose_deg))
        if np.any(distance > self.config.safe_pose_tolerance_deg):
            self._retract(state)

    def _ramp_velocity(self) -> FloatArray:
        return np.array(
            [
                joint.max_velocity_deg_s * self.config.ramp_velocity_fraction
                for joint in self.finger.joints
            ]
        )

    def _retract(self, state: FingerState | None = None) -> None:
        """Move the finger to the safe pose."""
        current = (state or self.finger.read_state()).positions_deg
        path = ramp(
            current,
            self.config.safe_pose_deg,
            self._ramp_velocity(),
            self.config.control_period_s,
        )
        self._stream(check_trajectory(path, self.config.control_period_s, self.finger.joints))

    def go_safe(self, lease: RigLease) -> None:
        """See :meth:`RigLease.go_safe`."""
        self._move(lease, lambda: None)

    def move_to_slot(self, lease: RigLease, slot: int) -> float:
        """See :meth:`RigLease.move_to_slot`."""
        return self._move(
            lease,
            lambda: self.turntable.move_to_slot(slot),
            check=lambda: self.turntable.slot_angle(slot),  # validates before anything moves
        )

    def home(self, lease: RigLease) -> None:
        """See :meth:`RigLease.home`."""
        self._move(lease, self.turntable.home)

    def _move(
        self,
        lease: RigLease,
        motion: Callable[[], _T],
        check: Callable[[], object] | None = None,
    ) -> _T:
        """Put the finger in its safe pose, then run ``motion``; returns what it returns.

        The rig must be ready; ``check`` (if given) runs before anything moves. A device fault
        leaves the rig safe and FAULT (:meth:`_fail`) and is raised, as
        :class:`~hardware.errors.EmergencyStopped` when an emergency stop caused it.
        """
        self._check_lease(lease)
        with self._operation:
            self._require_ready()
            if check is not None:
                check()
            try:
                self._set_state(RigState.MOVING)
                self._ensure_safe_pose()
                result = motion()
            except HardwareError as exc:
                self._fail(exc)
                raise self._estop_error(exc) from exc
            self._set_state(RigState.IDLE)
            return result

    def _fail(self, exc: HardwareError) -> None:
        """Leave the rig safe after a fault and mark it FAULT (unless emergency-stopped)."""
        if self._estop.is_set():
            return
        self._set_state(RigState.FAULT, f"{type(exc).__name__}: {exc}")
        try:
            if self.turntable.transport.is_open:
                self.turntable.feed_hold()
        except HardwareError:
            pass
        retracted = False
        if self.finger.connected and not isinstance(exc, ServoHardwareError):
            try:
                self._retract()
                retracted = True
            except HardwareError:
                retracted = False
        if not retracted and self.finger.transport.is_open:
            self.finger.emergency_stop(torque_off=not self.finger.connected)

    def _estop_error(self, exc: HardwareError) -> HardwareError:
        """The error to raise: EmergencyStopped when an e-stop caused ``exc``."""
        if self._estop.is_set() and not isinstance(exc, EmergencyStopped):
            stopped = EmergencyStopped(f"emergency stop ({self._fault}) during the operation")
            stopped.partial_record = exc.partial_record
            return stopped
        return exc

    def _stream(
        self,
        points: FloatArray,
        dt_s: float | None = None,
        *,
        on_step: Callable[[int, float], None] | None = None,
    ) -> int:
        """Send setpoints at the control rate; returns the number of setpoints skipped late.

        ``on_step(k, t)`` runs after setpoint k was sent, t seconds after the first.
        """
        dt = self.config.control_period_s if dt_s is None else dt_s
        n = points.shape[0]
        clock = self.clock
        start = clock.now()
        late = 0
        k = 0
        while k < n:
            self._check_estop()
            target = start + k * dt
            now = clock.now()
            if now < target:
                clock.sleep(target - now)
            else:
                due = min(int((now - start) / dt), n - 1)
                if due > k:
                    late += due - k
                    k = due
            self.finger.write_goal(points[k])
            self._last_finger = points[k]
            if on_step is not None:
                on_step(k, clock.now() - start)
            k += 1
        return late

    def touch(
        self,
        lease: RigLease,
        trajectory: npt.ArrayLike,
        dt_s: float | None,
        on_progress: Callable[[TouchProgress], None] | None,
    ) -> TouchRecord:
        """See :meth:`RigLease.touch`."""
        self._check_lease(lease)
        dt = self.config.control_period_s if dt_s is None else float(dt_s)
        with self._operation:
            self._require_ready()
            points = check_trajectory(trajectory, dt, self.finger.joints)
            session = _TouchSession(self, points, dt)
            try:
                self._set_state(RigState.MOVING)
                self._settle()
                start_state = self.finger.read_state()
                approach = ramp(start_state.positions_deg, points[0], self._ramp_velocity(), dt)
                self._stream(check_trajectory(approach, dt, self.finger.joints), dt)
                self._set_state(RigState.TOUCHING)
                session.run(on_progress, self._stream, self._check_estop)
                record = session.record(complete=True, failure=None)
                session.check_integrity(record)
                self._set_state(RigState.MOVING)
                self._retract()
            except HardwareError as exc:
                if exc.partial_record is None:
                    exc.partial_record = session.record(
                        complete=False, failure=f"{type(exc).__name__}: {exc}"
                    )
                self._fail(exc)
                raise self._estop_error(exc) from exc
            finally:
                self._rest_from_s = self.clock.now()
            self._touches += 1
            self._set_state(RigState.IDLE)
            return record

    def _settle(self) -> None:
        """Rest until ``settle_s`` has passed since the last touch (or connecting), in steps of
        at most 0.1 s so that an emergency stop ends the rest."""
        clock = self.clock
        until = self._rest_from_s + self.config.settle_s
        while (remaining := until - clock.now()) > 0:
            self._check_estop()
            clock.sleep(min(remaining, 0.1))


class _TouchSession:
    """The recording side of one touch.

    Sensor and host clocks are related by the offset ``sensor time - host time`` of the freshest
    frames: a frame that waited in a buffer shows a smaller offset, so the largest offset seen is
    the best estimate (stale bytes left in buffers cannot shift the touch window).
    """

    def __init__(self, rig: Rig, points: FloatArray, dt_s: float) -> None:
        self.rig = rig
        self.points = points
        self.dt_s = dt_s
        self.recorder = TactileRecorder(len(rig.tactile.config.channel_names))
        self.joint_times: list[float] = []
        self.joint_states: list[FingerState] = []
        self.host_start: float | None = None
        self.offset = -math.inf
        self.late_steps = 0
        self.slot = rig.turntable.slot
        self._last_frame_at = 0.0

    @property
    def duration_s(self) -> float:
        return float((self.points.shape[0] - 1) * self.dt_s)

    def _add(self, frames: list[TactileFrame]) -> None:
        if not frames:
            return
        self.recorder.add(frames)
        newest = self.recorder.last_time_s
        assert newest is not None
        self.offset = max(self.offset, newest - self.rig.clock.now())
        self._last_frame_at = self.rig.tactile.transport.now()

    def _take_frames(self, wait_s: float = 0.0) -> None:
        tactile = self.rig.tactile
        frames = tactile.poll(wait_s)
        if frames:
            self._add(frames)
            return
        silence = tactile.transport.now() - self._last_frame_at
        if silence > tactile.config.frame_timeout_s:
            raise DeviceTimeout(
                f"{tactile.transport.name}: the tactile stream stalled: no frame for "
                f"{silence:.3f} s during the touch."
            )

    def run(
        self,
        on_progress: Callable[[TouchProgress], None] | None,
        stream: Callable[..., int],
        check_estop: Callable[[], None],
    ) -> None:
        """Stream the setpoints (``stream``: the rig's setpoint loop) while recording; then read
        on until the sensor's clock has passed the end (``check_estop`` between reads)."""
        rig = self.rig
        tactile = rig.tactile
        tactile.restart()
        self._add(tactile.wait_frames(tactile.config.frame_timeout_s))
        while True:  # catch up with whatever was still buffered
            frames = tactile.poll(0.0)
            if not frames:
                break
            self._add(frames)
        n = self.points.shape[0]
        every = rig.config.state_every

        def on_step(k: int, t: float) -> None:
            if self.host_start is None:
                self.host_start = rig.clock.now() - t
            if k % every == 0 or k == n - 1:
                self.joint_states.append(rig.finger.read_state())
                self.joint_times.append(t)
            self._take_frames()
            if on_progress is not None:
                on_progress(TouchProgress(k, n, len(self.recorder), t))

        self.late_steps = stream(self.points, self.dt_s, on_step=on_step)
        # Keep reading until the sensor's clock has passed the end of the trajectory.
        assert self.host_start is not None
        while (self.recorder.last_time_s or -math.inf) < self._sensor_start() + self.duration_s:
            check_estop()
            self._take_frames(wait_s=tactile.config.frame_timeout_s / 4)

    def _sensor_start(self) -> float:
        assert self.host_start is not None
        return self.host_start + self.offset

    def record(self, complete: bool, failure: str | None) -> TouchRecord:
        rig = self.rig
        times, values, sequence = self.recorder.arrays()
        if self.host_start is not None and math.isfinite(self.offset):
            relative = times - self._sensor_start()
            keep = (relative >= 0.0) & (relative <= self.duration_s + 1e-9)
        else:
            relative = times
            keep = np.zeros(times.shape, dtype=bool)
        stats = rig.tactile.stats
        kept_sequence = sequence[keep]
        # Frames missing inside the touch window (stale bytes flushed at the start and the
        # frames after the end do not count).
        dropped = int(np.sum((np.diff(kept_sequence) - 1) % 65536)) if kept_sequence.size else 0
        n_joints = len(rig.finger.joints)
        if self.joint_states:
            positions = np.stack([s.positions_deg for s in self.joint_states])
            currents = np.stack([s.currents_ma for s in self.joint_states])
        else:
            positions = np.zeros((0, n_joints))
            currents = np.zeros((0, n_joints))
        return TouchRecord(
            slot=self.slot,
            channel_names=tuple(rig.tactile.config.channel_names),
            joint_names=rig.joint_names,
            dt_s=self.dt_s,
            commanded_deg=self.points,
            tactile_times_s=np.ascontiguousarray(relative[keep]),
            tactile=np.ascontiguousarray(values[keep]),
            tactile_sequence=np.ascontiguousarray(kept_sequence),
            joint_times_s=np.asarray(self.joint_times, dtype=np.float64),
            joint_positions_deg=positions,
            joint_currents_ma=currents,
            dropped_frames=dropped,
            corrupt_frames=stats.corrupt,
            discarded_bytes=stats.discarded_bytes,
            late_steps=self.late_steps,
            complete=complete,
            failure=failure,
            started_s=self.host_start,
        )

    def check_integrity(self, record: TouchRecord) -> None:
        stats = self.rig.tactile.stats
        expected = record.n_frames + record.dropped_frames
        lost = record.dropped_frames / expected if expected else 1.0
        if record.n_frames == 0 or lost > self.rig.config.max_lost_fraction:
            error = CorruptStreamError(
                f"{self.rig.tactile.transport.name}: {record.dropped_frames} of {expected} "
                f"tactile frames lost during the touch ({lost:.1%}; {stats.crc_errors} CRC "
                f"errors, {stats.malformed} malformed, {stats.discarded_bytes} bytes skipped), "
                f"more than the {self.rig.config.max_lost_fraction:.1%} allowed."
            )
            error.partial_record = replace(
                record, complete=False, failure=f"CorruptStreamError: {error}"
            )
            raise error


class RigLease(WithBlock):
    """The right to drive the rig, held by one run at a time (a context manager).

    Every method raises :class:`~hardware.errors.LeaseError` once the lease is released or
    revoked, and :class:`~hardware.errors.EmergencyStopped` while an emergency stop is in force.
    """

    def __init__(self, rig: Rig, owner: str) -> None:
        self.rig = rig
        self.owner = owner
        self._active = True

    @property
    def active(self) -> bool:
        """Whether this lease still drives the rig (not released, not revoked)."""
        return self._active and self.rig.holds(self)

    def connect(self) -> RigStatus:
        """Connect the three devices; the finger goes to its safe pose, the table is homed or
        unlocked."""
        return self.rig.connect(self)

    def close(self) -> None:
        """Close the three ports."""
        self.rig.close(self)

    def recover(self) -> RigStatus:
        """Clear an emergency stop or a fault: reboot faulty servos, reconnect, re-home."""
        return self.rig.recover(self)

    def home(self) -> None:
        """Retract the finger and run the turntable's homing cycle."""
        self.rig.home(self)

    def go_safe(self) -> None:
        """Move the finger to its safe pose."""
        self.rig.go_safe(self)

    def move_to_slot(self, slot: int) -> float:
        """Retract the finger and put ``slot`` under it; returns the table angle."""
        return self.rig.move_to_slot(self, slot)

    def touch(
        self,
        trajectory: npt.ArrayLike,
        dt_s: float | None = None,
        on_progress: Callable[[TouchProgress], None] | None = None,
    ) -> TouchRecord:
        """Execute a touch and record it.

        Args:
            trajectory: Joint positions in degrees, one row per setpoint. Shape (T, J).
            dt_s: Time between setpoints (default: the rig's control period).
            on_progress: Called after every setpoint.

        Returns:
            The :class:`~hardware.records.TouchRecord`; its ``observation`` is y.

        Raises:
            UnsafeTrajectoryError: A limit is broken; nothing moved.
            DeviceTimeout, DeviceDisconnected, CorruptStreamError, ServoHardwareError, ...:
                A fault; the rig is left safe and the error's ``partial_record`` holds what
                was recorded.
            EmergencyStopped: :meth:`Rig.estop` was called.
        """
        return self.rig.touch(self, trajectory, dt_s, on_progress)

    def status(self) -> RigStatus:
        """The rig's status."""
        return self.rig.status()

    def release(self) -> None:
        """Give the lease back (idempotent)."""
        if self._active:
            self._active = False
            self.rig.release(self)

    def _end(self) -> None:
        self.release()
