"""Simulated rigs: the real drivers on simulated devices.

Two levels, both running the same drivers (turntable, finger, tactile sensor and rig):

- :func:`in_process_rig` — the devices are called directly through
  :class:`~hardware.transport.InProcessTransport`; with the default
  :class:`~hardware.clock.VirtualClock` a touch costs only its computation and runs are
  deterministic for a seed.
- :func:`pty_rig` — each device runs behind a pseudo-terminal
  (:class:`~hardware.sim.pty.PtyEmulator`) and the drivers open ``/dev/pts/N`` with pyserial,
  at 115200 / 1 000 000 / 460800 baud as on the
  real rig; simulated time runs ``speed`` times faster than real time.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TypedDict, Unpack

import numpy as np

from hardware.clock import Clock, ScaledClock, VirtualClock
from hardware.errors import ConfigurationError
from hardware.finger import DYNAMIXEL_BAUDRATE, Finger, FingerConfig
from hardware.frames import CHANNELS
from hardware.lifecycle import WithBlock
from hardware.rig import Rig, RigConfig
from hardware.sim.dynamixel_device import DynamixelBus
from hardware.sim.electrodes import WholeTouchSensor, surface_detail
from hardware.sim.grbl_device import GrblDevice
from hardware.sim.materials import DEFAULT_TABLE, TactileObject, get_object
from hardware.sim.pty import PtyEmulator
from hardware.sim.tactile_device import TactileSource
from hardware.sim.world import FingerModel, NoiseModel, Plant
from hardware.tactile import TACTILE_BAUDRATE, TactileConfig, TactileSensor
from hardware.transport import InProcessTransport, SerialTransport, Transport
from hardware.turntable import GRBL_BAUDRATE, Turntable, TurntableConfig


@dataclass
class SimulatedDevices:
    """The simulated world and its three devices.

    Attributes:
        clock: Simulation clock.
        plant: Shared physical state.
        grbl: Turntable controller.
        bus: Servo bus.
        sensor: Tactile sensor.
        objects_by_slot: What stands where.
    """

    clock: Clock
    plant: Plant
    grbl: GrblDevice
    bus: DynamixelBus
    sensor: TactileSource
    objects_by_slot: dict[int, TactileObject] = field(default_factory=dict)

    @property
    def channel_names(self) -> tuple[str, ...]:
        """The tactile frame's channels: the five, then any whole-touch ones."""
        whole = self.plant.whole_touch
        return CHANNELS + (() if whole is None else whole.channel_names)

    def tactile_config(self, given: TactileConfig | None) -> TactileConfig:
        """``given``, or the default settings for this sensor's channels."""
        return given or TactileConfig(channel_names=self.channel_names)

    def slot_of(self, name: str) -> int:
        """The slot holding the object called ``name``."""
        for slot, item in self.objects_by_slot.items():
            if item.name == name:
                return slot
        raise ConfigurationError(
            f"no object {name!r} on the table; it holds "
            f"{', '.join(o.name for o in self.objects_by_slot.values())}."
        )


def table_channel_names(objects: Sequence[str | TactileObject]) -> tuple[str, ...]:
    """The tactile frame's channels of a simulated table with its default sensor: the five,
    then the whole-touch ones when an object has a surface detail (as
    :func:`simulated_devices` builds it with ``whole_touch=None``)."""
    names = [item if isinstance(item, str) else item.name for item in objects]
    if any(surface_detail(name) is not None for name in names):
        return CHANNELS + WholeTouchSensor().channel_names
    return CHANNELS


def simulated_devices(
    objects: Sequence[str | TactileObject] = DEFAULT_TABLE,
    *,
    clock: Clock,
    seed: int = 0,
    slot_count: int = 10,
    frame_rate_hz: float = 100.0,
    grbl_settings: dict[int, float] | None = None,
    noise: NoiseModel | None = None,
    finger_model: FingerModel | None = None,
    whole_touch: WholeTouchSensor | None = None,
) -> SimulatedDevices:
    """Build the world: objects in slots 0, 1, ... and the three devices.

    Args:
        objects: Preset names or objects, one per slot from slot 0.
        clock: Simulation clock.
        seed: Seed of the world's randomness.
        slot_count: Slots on the table.
        frame_rate_hz: Tactile frames per simulated second.
        grbl_settings: Overrides of the GRBL emulator's settings.
        noise: Noise model.
        finger_model: Finger constants.
        whole_touch: Whole-touch channels of the sensor (:mod:`hardware.sim.electrodes`);
            ``None`` adds them, with their default settings, when an object has a surface
            detail (the ``twins`` table), and not otherwise.
    """
    if len(objects) > slot_count:
        raise ConfigurationError(f"{len(objects)} objects do not fit in {slot_count} slots.")
    placed = {
        slot: (get_object(item) if isinstance(item, str) else item)
        for slot, item in enumerate(objects)
    }
    details = {
        item.name: detail
        for item in placed.values()
        if (detail := surface_detail(item.name)) is not None
    }
    if whole_touch is None and details:
        whole_touch = WholeTouchSensor()
    plant = Plant(
        placed,
        clock,
        np.random.default_rng(seed),
        slot_count=slot_count,
        finger=finger_model,
        noise=noise,
        whole_touch=whole_touch,
        details=details,
    )
    grbl = GrblDevice(clock, grbl_settings)
    plant.attach_table(grbl.position)
    bus = DynamixelBus(plant)
    sensor = TactileSource(plant, frame_rate_hz=frame_rate_hz)
    return SimulatedDevices(clock, plant, grbl, bus, sensor, placed)


class SimulatedRig(WithBlock):
    """A :class:`~hardware.rig.Rig` wired to simulated devices (a context manager).

    Attributes:
        devices: The simulated devices (for fault injection and inspection).
        rig: The rig, built from the real drivers.
        emulators: The pseudo-terminal emulators (empty in process).
    """

    def __init__(
        self, devices: SimulatedDevices, rig: Rig, emulators: Sequence[PtyEmulator] = ()
    ) -> None:
        self.devices = devices
        self.rig = rig
        self.emulators = list(emulators)

    @property
    def object_names(self) -> list[str]:
        """Objects on the table, by slot."""
        return [self.devices.objects_by_slot[s].name for s in sorted(self.devices.objects_by_slot)]

    @property
    def objects_by_slot(self) -> dict[int, TactileObject]:
        """Objects on the table with what is known of them (material, temperature), by slot."""
        return dict(sorted(self.devices.objects_by_slot.items()))

    def slot_of(self, name: str) -> int:
        """The slot of an object."""
        return self.devices.slot_of(name)

    def close(self) -> None:
        """Close the drivers' ports and stop the emulators."""
        for transport in (
            self.rig.turntable.transport,
            self.rig.finger.transport,
            self.rig.tactile.transport,
        ):
            transport.close()
        for emulator in self.emulators:
            emulator.stop()

    def _end(self) -> None:
        self.close()


#: The turntable's, finger's and tactile sensor's transports, and the emulators behind them.
_Wiring = tuple[tuple[Transport, Transport, Transport], list[PtyEmulator]]


class RigSettings(TypedDict, total=False):
    """Settings shared by :func:`in_process_rig` and :func:`pty_rig` (keyword arguments).

    Attributes:
        frame_rate_hz: Tactile frame rate (default 100 frames per simulated second).
        rig_config: Rig settings (default :class:`~hardware.rig.RigConfig`).
        turntable_config: Turntable driver settings (default: a 0.3 s banner timeout).
        finger_config: Finger driver settings.
        tactile_config: Tactile driver settings (default: the sensor's channels).
        noise: Noise model of the world.
    """

    frame_rate_hz: float
    rig_config: RigConfig | None
    turntable_config: TurntableConfig | None
    finger_config: FingerConfig | None
    tactile_config: TactileConfig | None
    noise: NoiseModel | None


def _simulated_rig(
    objects: Sequence[str | TactileObject],
    seed: int,
    clock: Clock,
    settings: RigSettings,
    wire: Callable[
        [SimulatedDevices], tuple[tuple[Transport, Transport, Transport], list[PtyEmulator]]
    ],
) -> SimulatedRig:
    """Build the devices, connect the drivers to them through ``wire`` (which returns the
    turntable's, finger's and tactile sensor's transports, and any emulators it started), and
    assemble the rig."""
    devices = simulated_devices(
        objects,
        clock=clock,
        seed=seed,
        frame_rate_hz=settings.get("frame_rate_hz", 100.0),
        noise=settings.get("noise"),
    )
    (table, bus, sensor), emulators = wire(devices)
    turntable_config = settings.get("turntable_config") or TurntableConfig(banner_timeout_s=0.3)
    rig = Rig(
        Turntable(table, turntable_config),
        Finger(bus, settings.get("finger_config")),
        TactileSensor(sensor, devices.tactile_config(settings.get("tactile_config"))),
        settings.get("rig_config"),
        clock,
    )
    return SimulatedRig(devices, rig, emulators)


def in_process_rig(
    objects: Sequence[str | TactileObject] = DEFAULT_TABLE,
    *,
    seed: int = 0,
    clock: Clock | None = None,
    **settings: Unpack[RigSettings],
) -> SimulatedRig:
    """A rig on in-process simulated devices (fast; deterministic with the default clock).

    Args:
        objects: Objects in slots 0, 1, ... (default: the paper's four cups and three more).
        seed: World seed.
        clock: Simulation clock (default: a new :class:`~hardware.clock.VirtualClock`).
        **settings: Frame rate, driver settings and noise (:class:`RigSettings`).
    """
    sim_clock: Clock = clock or VirtualClock()

    def wire(devices: SimulatedDevices) -> _Wiring:
        transports = (
            InProcessTransport(devices.grbl, sim_clock, "simulated GRBL"),
            InProcessTransport(devices.bus, sim_clock, "simulated Dynamixel bus"),
            InProcessTransport(devices.sensor, sim_clock, "simulated tactile sensor"),
        )
        return transports, []

    return _simulated_rig(objects, seed, sim_clock, settings, wire)


def start_emulators(devices: SimulatedDevices) -> dict[str, PtyEmulator]:
    """Serve the three devices on pseudo-terminals; keys ``turntable``, ``finger``, ``tactile``."""
    emulators = {
        "turntable": PtyEmulator(devices.grbl, "grbl"),
        "finger": PtyEmulator(devices.bus, "dynamixel"),
        "tactile": PtyEmulator(devices.sensor, "tactile"),
    }
    for emulator in emulators.values():
        emulator.start()
    return emulators


def pty_rig(
    objects: Sequence[str | TactileObject] = DEFAULT_TABLE,
    *,
    seed: int = 0,
    speed: float = 20.0,
    **settings: Unpack[RigSettings],
) -> SimulatedRig:
    """A rig whose drivers talk to emulators on pseudo-terminals through pyserial.

    Args:
        objects: Objects in slots 0, 1, ... (default: the paper's four cups and three more).
        seed: World seed.
        speed: Simulated seconds per real second.
        **settings: Frame rate, driver settings and noise (:class:`RigSettings`).
    """

    def wire(devices: SimulatedDevices) -> _Wiring:
        emulators = start_emulators(devices)
        transports = (
            SerialTransport(emulators["turntable"].port, GRBL_BAUDRATE),
            SerialTransport(emulators["finger"].port, DYNAMIXEL_BAUDRATE),
            SerialTransport(emulators["tactile"].port, TACTILE_BAUDRATE),
        )
        return transports, list(emulators.values())

    return _simulated_rig(objects, seed, ScaledClock(speed), settings, wire)
