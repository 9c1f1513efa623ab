"""The rig of this server (mock or serial) and what may drive it.

- The rig is built on first use from the settings (``hardware=mock``: an in-process simulated
  rig with the paper's four cups and three more objects; ``serial``: the configured ports).
- Who holds the rig is recorded in one place, the rig's lease (:meth:`RigService.take`,
  :class:`hardware.rig.RigLease`). Operator actions (connect, home, turntable) take it for their
  duration; a job that drives the rig (a rig trial or a collection) takes it when it is created
  and the job runner (:mod:`app.services.jobs`) gives it back when the job ends. A second taker
  gets a 409 naming the holder.
- ``estop`` works in any state and bypasses every lock; it also asks the job holding the rig to
  abort.
"""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from typing import Any

import numpy as np

from app.config import Settings
from app.documents.raw_touches import record_observation
from app.errors import ConflictError, DeviceUnavailableError
from app.rig.action_layout import has_press_depth
from app.rig.actions import TouchActions
from app.rig.build import RigHandle, RigPorts, SimulationMode, missing_ports, open_rig
from app.rig.press_depth import rig_action_dim
from app.schemas import RigPublic
from app.services.events import EventBus
from app.services.jobs import JobRunner
from app.services.touch import Touch
from core.features.pipeline import FeaturePipeline
from core.types import ManifoldModel
from core.validation import FloatArray
from hardware.errors import HardwareError, RigBusy
from hardware.records import TouchRecord
from hardware.rig import RigConfig, RigLease, RigState
from hardware.sim.materials import Table
from hardware.teaching import PAPER_TOUCH_DURATION_S

OPERATOR = "operator"


def touch_trajectory(record: TouchRecord) -> dict[str, Any]:
    """What a step keeps of a touch: the commanded trajectory and the stream's health."""
    return {
        "joint_names": list(record.joint_names),
        "dt_s": record.dt_s,
        "commanded_deg": record.commanded_deg.tolist(),
        "n_frames": record.n_frames,
        "dropped_frames": record.dropped_frames,
        "corrupt_frames": record.corrupt_frames,
        "late_steps": record.late_steps,
        "slot": record.slot,
    }


def raw_series(record: TouchRecord) -> dict[str, Any]:
    """The raw tactile time series of a touch (kept with a collected sample): the frames
    (``channel_names``, ``tactile``) and :func:`motion_series`."""
    return {
        "channel_names": list(record.channel_names),
        "tactile": record.tactile.tolist(),
        **motion_series(record),
    }


def motion_series(record: TouchRecord) -> dict[str, Any]:
    """What a raw-touch line of ``collect --raw`` keeps beside the touch's channels: the frame
    times, the joint series and :func:`touch_trajectory` (the frames themselves are in the
    line's ``channels``, ``docs/raw-touches.md``)."""
    return {
        "tactile_times_s": record.tactile_times_s.tolist(),
        "joint_times_s": record.joint_times_s.tolist(),
        "joint_positions_deg": record.joint_positions_deg.tolist(),
        **touch_trajectory(record),
    }


def trace_preview(record: TouchRecord, max_points: int = 200) -> dict[str, Any]:
    """The raw tactile series of a touch, thinned for a live plot.

    Frames are picked at evenly spaced indices (first and last kept), so the values are raw
    samples, not averages; a touch with fewer frames than ``max_points`` is sent whole.

    Args:
        record: The touch.
        max_points: Most frames to keep (at least 2).

    Returns:
        ``channel_names`` (C,), ``tactile_times_s`` (P,), ``tactile`` (P, C) with
        P = min(n_frames, max_points), and ``n_frames`` (frames recorded).
    """
    if max_points < 2:
        raise ValueError(f"max_points: expected at least 2, received {max_points}.")
    n = int(record.tactile_times_s.shape[0])
    index = np.arange(n) if n <= max_points else np.linspace(0, n - 1, max_points).round()
    index = index.astype(np.intp)
    return {
        "channel_names": list(record.channel_names),
        "tactile_times_s": record.tactile_times_s[index].tolist(),
        "tactile": record.tactile[index].tolist(),
        "n_frames": n,
    }


class RigService:
    """Owns this server's rig.

    Args:
        settings: ``hardware``, the device ports and the simulated table.
        jobs: The job runner (the job holding the rig is told of an emergency stop).
        events: Where rig state changes are announced.

    Raises:
        app.config.ConfigurationError: The simulated table is unusable.
    """

    def __init__(self, settings: Settings, jobs: JobRunner, events: EventBus) -> None:
        self._settings = settings
        self._jobs = jobs
        self._events = events
        #: The simulated table (``mock`` hardware's, and simulated rig trials').
        self.simulated_table: Table = settings.simulated_table()
        self._lock = threading.Lock()
        self._handle: RigHandle | None = None
        self._actions: dict[tuple[bool, float], TouchActions] = {}

    # --- construction -------------------------------------------------------------------------

    def handle(self) -> RigHandle:
        """The rig, built on first use.

        Raises:
            DeviceUnavailableError: Serial hardware without all three ports.
        """
        with self._lock:
            if self._handle is None:
                self._handle = self._open()
            return self._handle

    def _open(self) -> RigHandle:
        s = self._settings
        config = RigConfig(settle_s=s.settle_s)
        if s.hardware == "mock":
            return open_rig(
                simulate=SimulationMode.in_process,
                table=self.simulated_table,
                seed=0,
                rig_config=config,
            )
        ports = missing_ports(s.turntable_port, s.finger_port, s.tactile_port)
        missing = [f"{name}_port" for name in ports]
        if missing:
            raise DeviceUnavailableError(
                f"Serial hardware needs ports: {', '.join(missing)} not set "
                "(ACTIVETOUCH_TURNTABLE_PORT, ... or activetouch serve --turntable-port ...).",
                missing=missing,
            )
        assert s.turntable_port
        assert s.finger_port
        assert s.tactile_port
        return open_rig(
            ports=RigPorts(s.turntable_port, s.finger_port, s.tactile_port), rig_config=config
        )

    def actions(self, press_depth: bool = False, duration_s: float | None = None) -> TouchActions:
        """Action → trajectory map of the rig (DMPs of the teaching trajectory), with the
        press-depth component as the last dimension if ``press_depth``, for touches of
        ``duration_s`` (``None``: the teaching trajectory's 14.4 s, what a collection uses unless
        it is given one and a model assumes unless its data recorded one)."""
        duration = PAPER_TOUCH_DURATION_S if duration_s is None else float(duration_s)
        with self._lock:
            key = (press_depth, duration)
            if key not in self._actions:
                self._actions[key] = TouchActions.from_teaching(
                    press_depth=press_depth, duration_s=duration
                )
            return self._actions[key]

    def actions_for(self, model: ManifoldModel) -> TouchActions:
        """The action map a model was trained on: with the press depth if its dx has it, for
        touches as long as its training touches (when they recorded it)."""
        return self.actions(
            has_press_depth(model.hyperparameters.action_dim) is True,
            model.raw_data.touch_duration_s,
        )

    def rig_action_dim(self, model: ManifoldModel) -> int:
        """dx of the rig's actions for ``model``: the model's if the rig can make it (with or
        without the press depth), else the plain DMP actions' (for the error message)."""
        return rig_action_dim(model.hyperparameters.action_dim)

    @property
    def sim_table(self) -> tuple[str, ...]:
        """The objects of the simulated table (``mock`` hardware's, and simulated rig trials')."""
        return self.simulated_table.objects

    @property
    def design_std(self) -> float:
        """Default spread of a collection's actions: the simulated table's ``action_std``.

        A simulated table (``mock`` hardware) knows how far out its objects differ; a real
        rig's objects are not known, so its default is the unit spread.
        """
        return self.simulated_table.action_std if self._settings.hardware == "mock" else 1.0

    @property
    def action_dim(self) -> int:
        """dx of rig actions without the press depth."""
        return self.actions().action_dim

    @property
    def observation_dim(self) -> int:
        """dy of rig observations (tactile channels)."""
        return len(self.channel_names)

    @property
    def channel_names(self) -> tuple[str, ...]:
        """The tactile frame's channels."""
        return tuple(self.handle().rig.tactile.config.channel_names)

    def close(self) -> None:
        """Close the ports (or the simulation)."""
        with self._lock:
            handle, self._handle = self._handle, None
        if handle is not None:
            handle.close()

    # --- status and operator actions ----------------------------------------------------------

    def status(self) -> RigPublic:
        """What the rig is doing and who holds it (no device I/O)."""
        with self._lock:
            handle = self._handle
        if handle is None:
            return RigPublic(
                hardware=self._settings.hardware,
                connected=False,
                state="disconnected",
                held_by=None,
                detail={"objects_by_slot": None},
            )
        status = handle.rig.status()
        return RigPublic(
            hardware=self._settings.hardware,
            connected=status.state
            not in (RigState.DISCONNECTED, RigState.FAULT, RigState.ESTOPPED),
            state=str(status.state),
            held_by=status.lease_owner,
            detail={
                "slot": status.slot,
                "table_angle_deg": status.table_angle_deg,
                "finger_deg": None if status.finger_deg is None else list(status.finger_deg),
                "fault": status.fault,
                "touches": status.touches,
                "devices": status.devices,
                "objects_by_slot": handle.object_names,
                "object_properties": handle.object_properties(),
            },
        )

    def _announce(self) -> RigPublic:
        public = self.status()
        self._events.publish("rig.state", public.model_dump(mode="json"))
        return public

    @property
    def holder(self) -> str | None:
        """Who holds the rig's lease (``trial 3``, ``collection 5``, ``operator``), if anyone."""
        with self._lock:
            handle = self._handle
        return None if handle is None else handle.rig.status().lease_owner

    def take(self, owner: str) -> RigLease:
        """Take the rig's lease for ``owner`` (building the rig if needed); release it when done.

        Raises:
            ConflictError: (409) someone holds it (``held_by`` names them).
            DeviceUnavailableError: (503) serial hardware without its ports.
        """
        try:
            return self.handle().rig.acquire(owner)
        except RigBusy as exc:
            raise ConflictError(
                f"The rig is in use by {exc.owner}; stop it or wait for it to finish.",
                held_by=exc.owner,
            ) from exc

    @staticmethod
    def ensure_connected(lease: RigLease) -> None:
        """Connect the rig through ``lease`` if it is disconnected."""
        if lease.rig.state is RigState.DISCONNECTED:
            lease.connect()

    @contextmanager
    def lease(self, owner: str) -> Iterator[RigLease]:
        """Hold the rig for ``owner`` (409 if someone holds it); connect it if needed."""
        with self.take(owner) as lease:
            self.ensure_connected(lease)
            yield lease

    def connect(self) -> RigPublic:
        """Connect the devices, or recover after an emergency stop or a fault."""
        with self.take(OPERATOR) as lease:
            rig = lease.rig
            if rig.estopped or rig.state is RigState.FAULT:
                lease.recover()
            elif rig.state is RigState.DISCONNECTED:
                lease.connect()
        return self._announce()

    def home(self) -> RigPublic:
        """Retract the finger and home the turntable."""
        try:
            with self.lease(OPERATOR) as lease:
                lease.home()
        finally:
            self._announce()
        return self.status()

    def turn_to(self, slot: int) -> RigPublic:
        """Put ``slot`` under the finger."""
        try:
            with self.lease(OPERATOR) as lease:
                lease.move_to_slot(slot)
        finally:
            self._announce()
        return self.status()

    def estop(self) -> RigPublic:
        """Emergency stop: works in any state, takes no lock; aborts the job holding the rig."""
        # The job is told first, so that the fault the e-stop causes in its touch reads as an
        # abort by the operator, not a device failure.
        job = self._jobs.rig_job()
        if job is not None:
            job.request_stop("aborted")
        with self._lock:
            handle = self._handle
        if handle is not None:
            handle.rig.estop("operator emergency stop")
        return self._announce()

    def halt(self) -> None:
        """Stop the rig at once (abort of a rig run), if it exists."""
        with self._lock:
            handle = self._handle
        if handle is not None:
            handle.rig.estop("run aborted")

    # --- touching -----------------------------------------------------------------------------

    def object_properties(self) -> dict[str, dict[str, Any]] | None:
        """A simulated table's objects by name: slot, material and temperature (None: real rig)."""
        return self.handle().object_properties()

    def slot_of(self, name: str) -> int | None:
        """The slot of a simulated table's object called ``name`` (None if unknown)."""
        names = self.handle().object_names
        if names is None or name not in names:
            return None
        return names.index(name)


class RigTouchSource:
    """Touches one slot of a rig with DMP actions, holding the rig's lease.

    Args:
        lease: A lease on a connected rig (released by :meth:`close`).
        actions: Action → trajectory map.
        slot: Slot to touch.
        release: Called once at :meth:`close` (gives the rig back).
        features: The model's feature pipeline, which makes y of each touch (``None``: the
            channel means).
    """

    def __init__(
        self,
        lease: RigLease,
        actions: TouchActions,
        slot: int,
        release: Any = None,
        features: FeaturePipeline | None = None,
    ) -> None:
        self._features = features
        self._lease = lease
        self._actions = actions
        self._slot = slot
        self._release = release
        self._at_slot = False

    def touch(self, action: FloatArray, rng: np.random.Generator) -> Touch:
        """One touch with action x (the table turns to the slot before the first)."""
        slot = None if self._at_slot else self._slot
        record = self._actions.touch(self._lease, action, slot=slot)
        self._at_slot = True
        return Touch(
            action=np.asarray(action, dtype=np.float64),
            observation=record_observation(record, self._features),
            trajectory=touch_trajectory(record),
        )

    def close(self) -> None:
        """Release the lease (and the rig)."""
        with suppress(HardwareError):
            self._lease.release()
        if self._release is not None:
            self._release()
