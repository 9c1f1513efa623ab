"""Building the rig: on serial ports, or on simulated devices (in process, or behind ptys).

:func:`open_rig` builds a :class:`~hardware.rig.Rig` and returns a :class:`RigHandle` to close it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from enum import StrEnum

from hardware.clock import Clock, ScaledClock, VirtualClock
from hardware.errors import ConfigurationError
from hardware.finger import DYNAMIXEL_BAUDRATE, Finger, FingerConfig
from hardware.rig import Rig, RigConfig
from hardware.sim.materials import DEFAULT_TABLE_NAME, Table, TactileObject, get_table
from hardware.sim.noise import NoiseModel
from hardware.sim.rig import SimulatedRig, in_process_rig, pty_rig
from hardware.tactile import TACTILE_BAUDRATE, TactileConfig, TactileSensor
from hardware.transport import SerialTransport
from hardware.turntable import GRBL_BAUDRATE, Turntable, TurntableConfig


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


def missing_ports(
    turntable: str | None, finger: str | None, tactile: str | None
) -> tuple[str, ...]:
    """Which of a real rig's three serial ports (:class:`RigPorts`) are not given:
    ``turntable``, ``finger``, ``tactile``."""
    given = {"turntable": turntable, "finger": finger, "tactile": tactile}
    return tuple(name for name, port in given.items() if not port)


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
