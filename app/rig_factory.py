"""Composition of the rig: build it from ports or a simulation, and turn actions into touches.

``hardware`` knows devices and ``core`` knows DMPs; neither imports the other. Here they meet:

- :func:`open_rig` builds a :class:`~hardware.rig.Rig` on serial ports, or on simulated devices
  (in process, or behind pseudo-terminals), and returns a :class:`RigHandle` to close it.
- :class:`TouchActions` fits the DMPs of the teaching trajectory (25 basis functions per joint,
  3 dominant weights per joint, dx = 6) and maps an action x to a joint trajectory
  (action → DMP → trajectory → rig).
- :func:`iter_collect` runs a collection on a leased rig as a generator (one event per touch), so
  callers can stream progress, persist as they go and stop.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np
import numpy.typing as npt

from core.dmp import BasisResponses, DMPActionSpace, action_space, basis_responses, fit_dmp
from core.dmp import trajectory_for_action as dmp_trajectory
from hardware.clock import Clock, ScaledClock, VirtualClock
from hardware.errors import ConfigurationError
from hardware.finger import DYNAMIXEL_BAUDRATE, Finger, FingerConfig
from hardware.records import TouchRecord
from hardware.rig import Rig, RigConfig, RigLease, TouchProgress
from hardware.sim.materials import DEFAULT_TABLE_NAME, Table, TactileObject, get_table
from hardware.sim.noise import NoiseModel
from hardware.sim.rig import SimulatedRig, in_process_rig, pty_rig
from hardware.tactile import TACTILE_BAUDRATE, TactileConfig, TactileSensor
from hardware.teaching import PAPER_TOUCH_DURATION_S, teaching_trajectory
from hardware.transport import SerialTransport
from hardware.turntable import GRBL_BAUDRATE, Turntable, TurntableConfig

FloatArray = npt.NDArray[np.float64]


class SimulationMode(StrEnum):
    """How a simulated rig is wired."""

    in_process = "in-process"
    pty = "pty"


@dataclass(frozen=True)
class RigPorts:
    """Serial ports of a real rig.

    Attributes:
        turntable: GRBL controller (115200 baud).
        finger: Dynamixel bus (1 Mbaud).
        tactile: Tactile sensor stream (460800 baud).
    """

    turntable: str
    finger: str
    tactile: str
    turntable_baudrate: int = GRBL_BAUDRATE
    finger_baudrate: int = DYNAMIXEL_BAUDRATE
    tactile_baudrate: int = TACTILE_BAUDRATE


@dataclass
class RigHandle:
    """A rig and what must be closed with it.

    Attributes:
        rig: The rig.
        simulation: The simulated devices, when the rig is simulated.
        table: A simulated rig's table (None: a real rig, or a list of objects).
    """

    rig: Rig
    simulation: SimulatedRig | None = None
    table: Table | None = None

    @property
    def object_names(self) -> list[str] | None:
        """Objects on a simulated table by slot (None for a real rig: the operator knows)."""
        return None if self.simulation is None else self.simulation.object_names

    def object_properties(self) -> dict[str, dict[str, float | str | int]] | None:
        """What is known of each object of a simulated table, by name (None for a real rig).

        Each record holds the ``slot`` and the object's material and temperature (see
        :meth:`hardware.sim.materials.TactileObject.properties`).
        """
        if self.simulation is None:
            return None
        return {
            item.name: {"slot": slot, **item.properties()}
            for slot, item in self.simulation.objects_by_slot.items()
        }

    def close(self) -> None:
        """Close the ports (and stop the emulators of a simulation)."""
        if self.simulation is not None:
            self.simulation.close()
            return
        for transport in (
            self.rig.turntable.transport,
            self.rig.finger.transport,
            self.rig.tactile.transport,
        ):
            transport.close()


def serial_rig(
    ports: RigPorts,
    *,
    rig_config: RigConfig | None = None,
    turntable_config: TurntableConfig | None = None,
    finger_config: FingerConfig | None = None,
    tactile_config: TactileConfig | None = None,
) -> Rig:
    """A rig on real serial ports (not connected yet: use a lease's ``connect``)."""
    return Rig(
        Turntable(SerialTransport(ports.turntable, ports.turntable_baudrate), turntable_config),
        Finger(SerialTransport(ports.finger, ports.finger_baudrate), finger_config),
        TactileSensor(SerialTransport(ports.tactile, ports.tactile_baudrate), tactile_config),
        rig_config,
    )


def open_rig(
    *,
    ports: RigPorts | None = None,
    simulate: SimulationMode | None = None,
    table: str | Table = DEFAULT_TABLE_NAME,
    objects: Sequence[str | TactileObject] | None = None,
    seed: int = 0,
    speed: float | None = None,
    rig_config: RigConfig | None = None,
    noise: NoiseModel | None = None,
) -> RigHandle:
    """Build a rig on ports, or a simulated one.

    Args:
        ports: Serial ports of a real rig (ignored when ``simulate`` is given).
        simulate: Simulate the devices in process or behind pseudo-terminals.
        table: Table of a simulated rig: a name (:data:`hardware.sim.materials.TABLES`;
            default: the paper's four cups, then a ceramic mug, a wooden block and a foam
            sponge) or a table read from a file (:mod:`hardware.sim.table_file`).
        objects: Objects of a simulated table (preset names or objects), slot 0 first,
            instead of ``table``'s.
        seed: Seed of the simulated world.
        speed: Simulated seconds per real second. In process, None means virtual time (as fast
            as the computer goes); behind pseudo-terminals the default is 20.
        rig_config: Rig settings.
        noise: Noise model of a simulated world (``None``: the simulator's default).

    Raises:
        ConfigurationError: Neither ports nor a simulation were given, or an unknown table
            (the message lists the tables).
    """
    table_used = None
    if simulate is not None and objects is None:
        table_used = get_table(table)
        objects = table_used.slots
    if simulate is SimulationMode.pty:
        assert objects is not None
        return RigHandle(
            *_sim(
                pty_rig(objects, seed=seed, speed=speed or 20.0, rig_config=rig_config, noise=noise)
            ),
            table=table_used,
        )
    if simulate is SimulationMode.in_process:
        assert objects is not None
        clock: Clock = VirtualClock() if speed is None else ScaledClock(speed)
        return RigHandle(
            *_sim(
                in_process_rig(objects, seed=seed, clock=clock, rig_config=rig_config, noise=noise)
            ),
            table=table_used,
        )
    if ports is None:
        raise ConfigurationError(
            "no rig: give the turntable, finger and tactile ports, or simulate one."
        )
    return RigHandle(serial_rig(ports, rig_config=rig_config))


def _sim(simulation: SimulatedRig) -> tuple[Rig, SimulatedRig]:
    return simulation.rig, simulation


@dataclass(frozen=True)
class TouchActions:
    """Actions x ∈ R^6 as joint trajectories, through the DMPs of the teaching trajectory.

    Attributes:
        space: The DMP action space (x = 0 reproduces the teaching trajectory).
        dt_s: Period of the generated trajectories (the rig's control period).
        duration_s: Duration of a touch.
        responses: DMP basis responses on that time grid.
    """

    space: DMPActionSpace
    dt_s: float
    duration_s: float
    responses: BasisResponses = field(repr=False)

    @classmethod
    def from_teaching(
        cls,
        teaching: npt.ArrayLike | None = None,
        teaching_dt_s: float = 0.02,
        *,
        dt_s: float = 0.02,
        duration_s: float = PAPER_TOUCH_DURATION_S,
        n_basis: int = 25,
        n_dominant: int = 3,
        offset_deg_per_unit: float = 1.0,
    ) -> TouchActions:
        """Fit the DMPs of a teaching trajectory (default: the rig's synthetic demonstration).

        Args:
            teaching: Joint angles in degrees, shape (T, J), sampled every ``teaching_dt_s``.
            teaching_dt_s: Sample period of ``teaching``.
            dt_s: Period of the generated trajectories.
            duration_s: Duration of a generated touch (DMP time scaling).
            n_basis: Basis functions per joint (the paper: 25).
            n_dominant: Dominant weights per joint offset by the action (the paper: 3).
            offset_deg_per_unit: Peak joint change caused by one unit of one action component.
        """
        demo = (
            teaching_trajectory(dt_s=teaching_dt_s)
            if teaching is None
            else np.asarray(teaching, dtype=np.float64)
        )
        dmp = fit_dmp(demo, teaching_dt_s, n_basis=n_basis)
        space = action_space(dmp, n_dominant=n_dominant, offset_deg_per_unit=offset_deg_per_unit)
        responses = basis_responses(dmp, dt_s=dt_s, duration_s=duration_s)
        return cls(space, float(dt_s), float(duration_s), responses)

    @property
    def action_dim(self) -> int:
        """dx."""
        return self.space.action_dim

    def trajectory(self, action: npt.ArrayLike) -> FloatArray:
        """The joint trajectory of action x. Shape (T, J)."""
        return dmp_trajectory(self.space, action, responses=self.responses)

    def touch(
        self,
        lease: RigLease,
        action: npt.ArrayLike,
        slot: int | None = None,
        on_progress: Callable[[TouchProgress], None] | None = None,
    ) -> TouchRecord:
        """Execute action x on the leased rig (after turning ``slot`` under the finger)."""
        trajectory = self.trajectory(action)
        if slot is not None:
            lease.move_to_slot(slot)
        return lease.touch(trajectory, self.dt_s, on_progress)


@dataclass(frozen=True)
class CollectedTouch:
    """One touch of a collection.

    Attributes:
        index: Position in the collection (0-based).
        total: Number of touches planned.
        object_name: The object touched.
        slot: Its slot.
        action: x. Shape (dx,).
        record: What the rig recorded; ``record.observation`` is y.
        placement: Which placement of its object the touch met (0, 1, …), when the collection
            recorded placements; ``None`` when every touch met its own.
    """

    index: int
    total: int
    object_name: str
    slot: int
    action: FloatArray
    record: TouchRecord
    placement: int | None = None


def iter_collect(
    lease: RigLease,
    actions: TouchActions,
    slots: dict[str, int],
    action_design: npt.ArrayLike,
) -> Iterator[CollectedTouch]:
    """Touch every object with every action of a design, turning the table between touches.

    The order is action-major (each action on every object, as the turntable makes natural),
    which also gives the shared-action-design (Kronecker) structure of docs/method.md.

    Args:
        lease: A lease on a connected rig.
        actions: The action → trajectory map.
        slots: Object name → slot.
        action_design: The actions. Shape (M, dx).

    Yields:
        One :class:`CollectedTouch` per touch, as soon as it is recorded.
    """
    design = np.asarray(action_design, dtype=np.float64)
    if design.ndim != 2 or design.shape[1] != actions.action_dim:
        raise ConfigurationError(
            f"action_design: expected shape (M, {actions.action_dim}), received {design.shape}."
        )
    if not slots:
        raise ConfigurationError("slots: at least one object is needed.")
    total = design.shape[0] * len(slots)
    index = 0
    for action in design:
        for name, slot in slots.items():
            record = actions.touch(lease, action, slot=slot)
            yield CollectedTouch(index, total, name, slot, action.copy(), record)
            index += 1
