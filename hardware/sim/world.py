"""The simulated physical world: finger joints, turntable, objects and the tactile response.

:class:`Plant` is the one physical state that the three simulated devices share. The servo
emulator sets joint goals and reads joint states from it; the turntable emulator tells it where
the table is; the tactile source receives one sample of the five channels per sensor period. Time
comes from a :class:`~hardware.clock.Clock`; the plant integrates lazily up to the time of each
event, and every sensor sample is taken, in order, before any later change is applied.

The tactile response (:func:`tactile_response`) is a smooth function of the fingertip's motion,
with physically motivated forms:

- contact: the fingertip (on a link of ``length_mm`` turned by FFJ3) meets the surface at the
  object's contact angle; the indentation, smoothed by a softplus, loads a series spring of the
  fingertip pad and the surface: F = k_eff · d (1 + d / 10 mm).
- pressure: proportional to the normal force (the sensor's fluid pressure).
- vibration: sliding at speed v over a texture of period λ excites f = v / λ with an amplitude
  growing with roughness and √F; two channels see it through a low-pass and a high-pass band.
  Stick-slip adds an amplitude ∝ (μ_s − μ_k) μ F at low speed, mostly in the high band.
- heat flux: two semi-infinite bodies in contact exchange q = A e_eff ΔT / √(π t) with
  e_eff = e_skin e_obj / (e_skin + e_obj) (contact time t, contact area A growing with F).
- temperature: the heated sensor (core 33 °C) cools by that flux with a first-order recovery.

Noise (:mod:`hardware.sim.noise`, documented in docs/simulation.md): per-frame noise correlated
across channels and in time, an offset per contact, the vibration noise growing with the normal
force, and slow drift — the heater's set point and the room temperature wander (both enter the
heat exchange, so heat flux and temperature drift together) and so does the pressure baseline.
Each placement of an object (the table arriving at its slot) and each lift-off also shifts the
object slightly, so repeated touches with one action differ.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np

from hardware.clock import Clock
from hardware.errors import ConfigurationError, ServoHardwareErrorFlags
from hardware.sim.electrodes import PLAIN, SurfaceDetail, WholeTouchChannels, WholeTouchSensor
from hardware.sim.materials import Material, TactileObject
from hardware.sim.noise import (
    DRIFT_AMBIENT_C,
    DRIFT_CORE_C,
    DRIFT_PRESSURE,
    NoiseModel,
    NoiseProcess,
)

__all__ = ["Contact", "FingerModel", "NoiseModel", "Plant", "PlantEvents"]

TableState = Callable[[float], tuple[float, float]]
"""Table angle (deg) and angular velocity (deg/s) at a time."""

Sampler = Callable[[float, tuple[float, ...]], None]
"""Receives one tactile sample: time (s) and the channel values (the five, then any whole-touch
channels of :mod:`hardware.sim.electrodes`)."""


@dataclass(frozen=True)
class FingerModel:
    """Mechanical and thermal constants of the simulated finger and sensor.

    Attributes:
        length_mm: Distance from the FFJ3 axis to the fingertip.
        pad_stiffness_n_per_mm: Stiffness of the fingertip pad.
        skin_effusivity: Thermal effusivity of the sensor skin.
        core_temperature_c: Temperature the sensor's heater keeps.
        recovery_time_s: Time constant of the heater's recovery.
        heat_capacity_j_per_k: Heat capacity of the sensor's skin layer.
        max_contact_area_mm2: Contact area at large forces.
        torque_constant_nm_per_a: Servo output torque per ampere.
        idle_current_ma: Current drawn when unloaded.
        servo_time_constant_s: First-order lag of the servo's position loop.
        current_limit_ma: Above this for ``overload_time_s`` the servo shuts down (OVERLOAD).
        overload_time_s: How long an overload is tolerated.
    """

    length_mm: float = 80.0
    pad_stiffness_n_per_mm: float = 1.2
    skin_effusivity: float = 900.0
    core_temperature_c: float = 33.0
    recovery_time_s: float = 4.0
    heat_capacity_j_per_k: float = 0.4
    max_contact_area_mm2: float = 80.0
    torque_constant_nm_per_a: float = 1.78
    idle_current_ma: float = 40.0
    servo_time_constant_s: float = 0.03
    current_limit_ma: float = 1500.0
    overload_time_s: float = 0.5


@dataclass(frozen=True)
class Contact:
    """The fingertip's contact with the surface.

    Attributes:
        force_n: Normal force.
        slide_speed_mm_s: Sliding speed of the fingertip along the surface.
        indentation_mm: Smoothed indentation.
    """

    force_n: float
    slide_speed_mm_s: float
    indentation_mm: float


NO_CONTACT = Contact(0.0, 0.0, 0.0)


def _softplus(value: float, width: float) -> float:
    scaled = value / width
    if scaled > 30.0:
        return value
    return width * math.log1p(math.exp(scaled))


def contact(
    target: TactileObject | None,
    finger: FingerModel,
    flexion_deg: float,
    flexion_velocity_deg_s: float,
    abduction_velocity_deg_s: float,
    offset_deg: float = 0.0,
) -> Contact:
    """Contact of the fingertip with ``target`` (None: nothing under the finger)."""
    if target is None:
        return NO_CONTACT
    reach = finger.length_mm
    surface = math.radians(target.contact_angle_deg + offset_deg)
    penetration = reach * (math.sin(math.radians(flexion_deg)) - math.sin(surface))
    indentation = _softplus(penetration, 0.3)
    force = _series_force(target.material, finger.pad_stiffness_n_per_mm, indentation)
    force *= 1.0 + indentation / 10.0
    engaged = force / (force + 0.2)
    speed = (
        reach
        * math.radians(abs(abduction_velocity_deg_s) + 0.3 * abs(flexion_velocity_deg_s))
        * engaged
    )
    return Contact(force, speed, indentation)


INSERT_EDGE_MM = 0.3
"""Width over which an insert's stiffness comes in (the softplus of the compression past it)."""


def _series_force(material: Material, pad_n_per_mm: float, indentation_mm: float) -> float:
    """Force of the fingertip pad and the surface in series, pressed ``indentation_mm`` together.

    A plain surface is a linear spring: F = k_eff d with 1/k_eff = 1/k_pad + 1/k_surface. With an
    insert at depth t under a soft surface, the surface's force at compression u is
    k_s u + k_i [softplus(u − t) − softplus(−t)] (the insert's stiffness k_i adds once the soft
    layer is pressed down to it); the pad carries the same force, k_pad (d − u). Solved for u by
    Newton's method from the plain-surface solution: the residual is convex and increasing in u
    and the start lies at or above the root, so the iterates decrease monotonically to it.
    """
    k_pad, k_surface = pad_n_per_mm, material.stiffness_n_per_mm
    if material.insert_depth_mm is None or indentation_mm <= 0.0:
        return indentation_mm / (1.0 / k_pad + 1.0 / k_surface)
    depth, k_insert = material.insert_depth_mm, material.insert_stiffness_n_per_mm
    at_rest = _softplus(-depth, INSERT_EDGE_MM)
    compression = k_pad * indentation_mm / (k_pad + k_surface)
    for _ in range(30):
        past = (compression - depth) / INSERT_EDGE_MM
        engaged = 1.0 / (1.0 + math.exp(-past)) if past > -30.0 else 0.0
        residual = (
            k_surface * compression
            + k_insert * (_softplus(compression - depth, INSERT_EDGE_MM) - at_rest)
            - k_pad * (indentation_mm - compression)
        )
        step = residual / (k_surface + k_insert * engaged + k_pad)
        compression -= step
        if abs(step) < 1e-12:
            break
    return k_pad * (indentation_mm - compression)


def vibration(target: TactileObject | None, touch: Contact) -> tuple[float, float]:
    """Noise-free envelopes of the two vibration channels (low band, high band)."""
    floor = 0.3
    if target is None or touch.force_n <= 0.0:
        return floor, floor
    material = target.material
    speed = touch.slide_speed_mm_s
    texture = 0.04 * material.roughness_um * math.sqrt(touch.force_n) * speed / (speed + 10.0)
    ratio = (speed / material.texture_period_mm) / 80.0
    low_gain = 1.0 / math.sqrt(1.0 + ratio * ratio)
    high_gain = ratio * low_gain
    stick_slip = (
        3.0
        * material.stick_slip
        * material.friction
        * touch.force_n
        * speed
        / (speed + 3.0)
        * math.exp(-speed / 100.0)
    )
    return floor + texture * low_gain + 0.4 * stick_slip, floor + texture * high_gain + stick_slip


def heat_flow_w(
    target: TactileObject | None,
    finger: FingerModel,
    touch: Contact,
    skin_temperature_c: float,
    object_temperature_c: float,
    contact_time_s: float,
) -> float:
    """Heat flowing from the sensor into the object, in watts (semi-infinite contact)."""
    if target is None or touch.force_n <= 0.0:
        return 0.0
    area_m2 = finger.max_contact_area_mm2 * 1e-6 * touch.force_n / (touch.force_n + 1.5)
    skin, body = finger.skin_effusivity, target.material.effusivity_at(contact_time_s)
    effective = skin * body / (skin + body)
    return (
        area_m2
        * effective
        * (skin_temperature_c - object_temperature_c)
        / math.sqrt(math.pi * (contact_time_s + 0.2))
    )


@dataclass
class _Joint:
    position_deg: float = 0.0
    velocity_deg_s: float = 0.0
    goal_deg: float = 0.0
    torque: bool = False
    max_velocity_deg_s: float = 0.0  # 0: unlimited (profile velocity 0)
    hardware_error: ServoHardwareErrorFlags = ServoHardwareErrorFlags.NONE
    overload_s: float = 0.0
    current_ma: float = 0.0


@dataclass
class PlantEvents:
    """Counters of notable physical events.

    Attributes:
        placements: Times an object arrived under the finger.
        collisions: Samples where the table turned while the finger pressed on an object.
        overloads: Servo overload shutdowns.
    """

    placements: int = 0
    collisions: int = 0
    overloads: int = 0
    touched: dict[str, int] = field(default_factory=dict)


class Plant:
    """The shared physical state of a simulated rig.

    Args:
        objects_by_slot: Object standing in each occupied slot.
        clock: The simulation clock.
        rng: Randomness of the world (noise, placement).
        slot_count: Slots on the table.
        finger: Finger constants.
        noise: Noise model.
        joint_count: Number of finger joints (joint 0 flexes, joint 1 abducts).
        slot_tolerance_deg: How far from a slot's angle its object is still under the finger.
        whole_touch: Whole-touch channels appended to each sample (``None``: the five only).
        details: What the whole touch feels of each object, by name (others: a plain surface).
    """

    def __init__(
        self,
        objects_by_slot: Mapping[int, TactileObject],
        clock: Clock,
        rng: np.random.Generator,
        slot_count: int = 10,
        finger: FingerModel | None = None,
        noise: NoiseModel | None = None,
        joint_count: int = 2,
        slot_tolerance_deg: float = 1.0,
        whole_touch: WholeTouchSensor | None = None,
        details: Mapping[str, SurfaceDetail] | None = None,
    ) -> None:
        for slot in objects_by_slot:
            if not 0 <= slot < slot_count:
                raise ConfigurationError(f"slot {slot} is outside 0..{slot_count - 1}.")
        if joint_count < 2:
            raise ConfigurationError(f"joint_count: at least 2, received {joint_count}.")
        self.objects_by_slot = dict(objects_by_slot)
        self.clock = clock
        self.rng = rng
        self.slot_count = slot_count
        self.finger = finger or FingerModel()
        self.noise = noise or NoiseModel()
        self.slot_tolerance_deg = slot_tolerance_deg
        self.lock = threading.RLock()
        self.joints = [_Joint() for _ in range(joint_count)]
        self.table: TableState = lambda _t: (0.0, 0.0)
        self.events = PlantEvents()
        self._time = clock.now()
        self._sampler: Sampler | None = None
        self._sample_period = 0.0
        self._next_sample = math.inf
        self._sample_origin = self._time
        self._sample_index = 0
        self._last_sample = self._time
        self._skin_temperature = self.finger.core_temperature_c
        self._contact_time = 0.0
        self._in_contact = False
        self._slot: int | None = None
        self._offset_deg = 0.0
        self._object_temperature_shift = 0.0
        self._contact = NO_CONTACT
        # The noise processes draw from their own stream, spawned from the world's.
        self._noise_rng = rng.spawn(1)[0]
        self._noise: NoiseProcess | None = None
        self._contact_offset: list[float] | None = None
        self.whole_touch = whole_touch
        self._details = dict(details or {})
        self._whole = (
            None if whole_touch is None else WholeTouchChannels(whole_touch, rng.spawn(1)[0])
        )

    # -- wiring -------------------------------------------------------------------------------

    def attach_table(self, table: TableState) -> None:
        """Where the table is, as a function of time (the turntable emulator provides it)."""
        with self.lock:
            self.table = table

    def attach_sampler(self, sampler: Sampler, period_s: float) -> None:
        """Receive one tactile sample every ``period_s`` from now on."""
        if not period_s > 0:
            raise ConfigurationError(f"period_s: must be positive, received {period_s}.")
        with self.lock:
            self._sampler = sampler
            self._sample_period = float(period_s)
            self._noise = NoiseProcess(self.noise, self._noise_rng, float(period_s))
            self._sample_origin = self._time
            self._sample_index = 1
            self._next_sample = self._time + period_s

    # -- time ---------------------------------------------------------------------------------

    @property
    def time_s(self) -> float:
        """Time the plant has been integrated to."""
        return self._time

    def advance(self, until_s: float | None = None) -> None:
        """Integrate to ``until_s`` (default: the clock's now), taking every sensor sample due."""
        with self.lock:
            target = self.clock.now() if until_s is None else until_s
            while self._next_sample <= target:
                moment = self._next_sample
                self._integrate(moment)
                self._take_sample(moment)
                # Sample k is at origin + k * period: no drift from summing periods.
                self._sample_index += 1
                self._next_sample = self._sample_origin + self._sample_index * self._sample_period
            self._integrate(target)

    def _integrate(self, until_s: float) -> None:
        step = until_s - self._time
        if step <= 0:
            return
        lag = self.finger.servo_time_constant_s
        for joint in self.joints:
            if not joint.torque:
                joint.velocity_deg_s = 0.0
                continue
            joint.position_deg, joint.velocity_deg_s = _follow(
                joint.position_deg, joint.goal_deg, joint.max_velocity_deg_s, lag, step
            )
        self._time = until_s

    # -- the world at a moment ----------------------------------------------------------------

    def _object_at(self, moment: float) -> tuple[TactileObject | None, float]:
        angle, speed = self.table(moment)
        spacing = 360.0 / self.slot_count
        slot = round((angle % 360.0) / spacing) % self.slot_count
        distance = abs(((angle - slot * spacing) + 180.0) % 360.0 - 180.0)
        if distance > self.slot_tolerance_deg:
            slot_here: int | None = None
        else:
            slot_here = slot
        if slot_here != self._slot:
            self._slot = slot_here
            if slot_here is not None and slot_here in self.objects_by_slot:
                self.events.placements += 1
                self._offset_deg = float(self.rng.normal(0.0, self.noise.placement_std_deg))
                self._object_temperature_shift = float(
                    self.rng.normal(0.0, self.noise.object_temperature_std_c)
                )
        target = None if slot_here is None else self.objects_by_slot.get(slot_here)
        return target, speed

    def _take_sample(self, moment: float) -> None:
        period = moment - self._last_sample
        self._last_sample = moment
        target, table_speed = self._object_at(moment)
        flexion, abduction = self.joints[0], self.joints[1]
        touch = contact(
            target,
            self.finger,
            flexion.position_deg,
            flexion.velocity_deg_s,
            abduction.velocity_deg_s,
            self._offset_deg,
        )
        self._contact = touch
        touching = touch.force_n > 0.1
        if touching and target is not None and not self._in_contact:
            self.events.touched[target.name] = self.events.touched.get(target.name, 0) + 1
        if self._in_contact and not touching:
            self._offset_deg += float(self.rng.normal(0.0, self.noise.slip_std_deg))
            self._contact_offset = None
        if touching and not self._in_contact and self._noise is not None:
            self._contact_offset = self._noise.contact_offset()
        self._in_contact = touching
        if touching:
            self._contact_time += period
        else:
            self._contact_time = max(0.0, self._contact_time - 3.0 * period)
        if touching and abs(table_speed) > 1e-6:
            self.events.collisions += 1
            self._overload(1)
        frame_noise, drift = self._noise.next_row() if self._noise is not None else (None, None)
        ambient_drift = 0.0 if drift is None else drift[DRIFT_AMBIENT_C]
        object_temperature = ambient_drift + (
            22.0 if target is None else target.temperature_c + self._object_temperature_shift
        )
        heat = heat_flow_w(
            target,
            self.finger,
            touch,
            self._skin_temperature,
            object_temperature,
            self._contact_time,
        )
        core = self.finger.core_temperature_c + (0.0 if drift is None else drift[DRIFT_CORE_C])
        recovery = (core - self._skin_temperature) / self.finger.recovery_time_s
        self._skin_temperature += (recovery - heat / self.finger.heat_capacity_j_per_k) * period
        self._update_currents(touch, target, period)
        if self._sampler is None or frame_noise is None or drift is None:
            return
        low, high = vibration(target, touch)
        pressure = 0.9 * touch.force_n + drift[DRIFT_PRESSURE]
        clean = (low, high, pressure, 1000.0 * heat, self._skin_temperature)
        noise = list(frame_noise)
        if self._contact_offset is not None:
            noise = [n + o for n, o in zip(noise, self._contact_offset, strict=True)]
        # Pressure scales the vibration: its noise grows with the normal force.
        gain = 1.0 + self.noise.vibration_gain_per_n * touch.force_n
        noise[0] *= gain
        noise[1] *= gain
        sample = tuple(c + n for c, n in zip(clean, noise, strict=True))
        if self._whole is not None:
            detail = None if target is None else self._details.get(target.name, PLAIN)
            sample += self._whole.sample(touch.force_n, touch.slide_speed_mm_s, detail, period)
        self._sampler(moment, sample)

    def _update_currents(self, touch: Contact, target: TactileObject | None, period: float) -> None:
        finger = self.finger
        lever_m = finger.length_mm / 1000.0
        flexion, abduction = self.joints[0], self.joints[1]
        friction = 0.0 if target is None else target.material.friction
        loads_nm = (
            touch.force_n * lever_m,
            friction * touch.force_n * lever_m * _sign(abduction.velocity_deg_s),
        )
        for index, (joint, load) in enumerate(zip((flexion, abduction), loads_nm, strict=True)):
            if not joint.torque:
                joint.current_ma = 0.0
                continue
            current = 1000.0 * load / finger.torque_constant_nm_per_a
            current += finger.idle_current_ma * _sign(joint.velocity_deg_s)
            joint.current_ma = current
            if abs(current) > finger.current_limit_ma:
                joint.overload_s += period
                if joint.overload_s > finger.overload_time_s:
                    self._overload(index)
            else:
                joint.overload_s = 0.0

    def _overload(self, index: int) -> None:
        joint = self.joints[index]
        if not joint.hardware_error & ServoHardwareErrorFlags.OVERLOAD:
            self.events.overloads += 1
        joint.hardware_error |= ServoHardwareErrorFlags.OVERLOAD
        joint.torque = False
        joint.velocity_deg_s = 0.0

    # -- the servo side -----------------------------------------------------------------------

    def set_goal(self, index: int, goal_deg: float) -> None:
        """A new goal position for joint ``index`` (applied now)."""
        with self.lock:
            self.advance()
            self.joints[index].goal_deg = float(goal_deg)

    def set_torque(self, index: int, enabled: bool) -> None:
        """Torque on/off; switching on makes the present position the goal."""
        with self.lock:
            self.advance()
            joint = self.joints[index]
            if enabled and not joint.torque:
                joint.goal_deg = joint.position_deg
            joint.torque = bool(enabled)

    def set_max_velocity(self, index: int, velocity_deg_s: float) -> None:
        """The servo's profile velocity (0: unlimited)."""
        with self.lock:
            self.advance()
            self.joints[index].max_velocity_deg_s = max(0.0, float(velocity_deg_s))

    def joint_state(self, index: int) -> tuple[float, float, float, bool]:
        """Position (deg), velocity (deg/s), current (mA) and torque of joint ``index`` now."""
        with self.lock:
            self.advance()
            joint = self.joints[index]
            return joint.position_deg, joint.velocity_deg_s, joint.current_ma, joint.torque

    def hardware_error(self, index: int) -> ServoHardwareErrorFlags:
        """The joint servo's Hardware Error Status."""
        with self.lock:
            self.advance()
            return self.joints[index].hardware_error

    def inject_hardware_error(self, index: int, flags: ServoHardwareErrorFlags) -> None:
        """Fault injection: the servo detects ``flags`` and shuts its torque off."""
        with self.lock:
            self.advance()
            joint = self.joints[index]
            joint.hardware_error |= flags
            joint.torque = False
            joint.velocity_deg_s = 0.0

    def reboot(self, index: int) -> None:
        """A servo reboot: errors cleared, torque off."""
        with self.lock:
            self.advance()
            joint = self.joints[index]
            joint.hardware_error = ServoHardwareErrorFlags.NONE
            joint.torque = False
            joint.overload_s = 0.0

    @property
    def contact_now(self) -> Contact:
        """The contact at the last sensor sample."""
        return self._contact

    @property
    def skin_temperature_c(self) -> float:
        """The sensor skin's temperature."""
        return self._skin_temperature


def _sign(value: float) -> float:
    return 0.0 if value == 0.0 else math.copysign(1.0, value)


def _follow(
    position: float, goal: float, max_velocity: float, lag_s: float, step_s: float
) -> tuple[float, float]:
    """Exact motion of a rate-limited first-order position loop over ``step_s``."""
    error = goal - position
    if max_velocity > 0 and abs(error) > max_velocity * lag_s:
        direction = 1.0 if error > 0 else -1.0
        linear_time = (abs(error) - max_velocity * lag_s) / max_velocity
        if step_s <= linear_time:
            return position + direction * max_velocity * step_s, direction * max_velocity
        position += direction * max_velocity * linear_time
        step_s -= linear_time
        error = goal - position
    remaining = error * math.exp(-step_s / lag_s)
    return goal - remaining, remaining / lag_s
