"""The simulated tactile world: contact, vibration and heat behave as physics says."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hardware.clock import VirtualClock
from hardware.errors import ConfigurationError
from hardware.sim.materials import OBJECTS, PAPER_CUPS, get_object
from hardware.sim.world import FingerModel, Plant, _follow, contact, heat_flow_w, vibration

FINGER = FingerModel()


def test_presets_hold_the_papers_four_cups_and_more() -> None:
    assert PAPER_CUPS == ("paper_cup", "bumpy_glass", "clear_plastic_cup", "stainless_cup")
    assert set(PAPER_CUPS) < set(OBJECTS)
    assert len(OBJECTS) >= 8
    assert get_object("ceramic_mug", temperature_c=50.0).temperature_c == 50.0
    with pytest.raises(ConfigurationError, match="presets: "):
        get_object("teapot")


def test_no_object_no_contact() -> None:
    assert contact(None, FINGER, 40.0, 0.0, 10.0).force_n == 0.0
    assert vibration(None, contact(None, FINGER, 40.0, 0.0, 10.0)) == (0.3, 0.3)


def test_force_grows_smoothly_with_flexion_and_stiffness() -> None:
    paper, steel = get_object("paper_cup"), get_object("stainless_cup")
    angles = np.linspace(15.0, 30.0, 61)
    forces = np.array([contact(steel, FINGER, a, 0.0, 0.0).force_n for a in angles])
    assert np.all(np.diff(forces) > 0)  # monotone
    assert forces[0] < 0.01  # 5° before the surface: no contact
    # Smooth: no kink at first contact (second differences stay small).
    assert np.max(np.abs(np.diff(forces, 2))) < 0.1 * np.max(np.diff(forces))
    soft = contact(paper, FINGER, 25.0, 0.0, 0.0).force_n
    hard = contact(steel, FINGER, 25.0, 0.0, 0.0).force_n
    assert hard > 3.0 * soft  # a thin paper wall gives way; steel does not


def test_bumps_vibrate_more_than_smooth_surfaces_when_sliding() -> None:
    rough = get_object("bumpy_glass")
    smooth = get_object("clear_plastic_cup")
    for target_speed in (5.0, 20.0):
        low_r, _ = vibration(rough, contact(rough, FINGER, 24.0, 0.0, target_speed))
        low_s, _ = vibration(smooth, contact(smooth, FINGER, 24.0, 0.0, target_speed))
        assert low_r > 2.0 * low_s
    still = vibration(rough, contact(rough, FINGER, 24.0, 0.0, 0.0))
    sliding = vibration(rough, contact(rough, FINGER, 24.0, 0.0, 10.0))
    assert sliding[0] > still[0]


def test_heat_flux_orders_by_effusivity() -> None:
    names = ["foam_sponge", "paper_cup", "clear_plastic_cup", "bumpy_glass", "stainless_cup"]
    flows = []
    for name in names:
        target = get_object(name)
        touch = contact(target, FINGER, 24.0, 0.0, 0.0)
        # Same force for every material: compare effusivity alone.
        touch = type(touch)(5.0, 0.0, touch.indentation_mm)
        flows.append(heat_flow_w(target, FINGER, touch, 33.0, 22.0, 1.0))
    assert flows == sorted(flows)
    warm = get_object("warm_ceramic_mug")
    touch = type(contact(warm, FINGER, 24.0, 0.0, 0.0))(5.0, 0.0, 1.0)
    assert heat_flow_w(warm, FINGER, touch, 33.0, 45.0, 1.0) < 0  # heat flows into the sensor


def test_servo_follow_is_rate_limited_then_exponential() -> None:
    position, velocity = _follow(0.0, 30.0, 60.0, 0.03, 0.1)
    assert position == pytest.approx(6.0)
    assert velocity == pytest.approx(60.0)
    position, velocity = _follow(0.0, 30.0, 60.0, 0.03, 2.0)
    assert position == pytest.approx(30.0, abs=1e-6)
    position, _ = _follow(0.0, 1.0, 0.0, 0.03, 0.03)  # unlimited: first order
    assert position == pytest.approx(1.0 - math.exp(-1.0))


def test_plant_samples_in_order_and_is_deterministic_per_seed() -> None:
    def run(seed: int) -> list[tuple[float, tuple[float, ...]]]:
        clock = VirtualClock()
        plant = Plant({0: get_object("stainless_cup")}, clock, np.random.default_rng(seed))
        samples: list[tuple[float, tuple[float, ...]]] = []
        plant.attach_sampler(lambda t, values: samples.append((t, values)), 0.01)
        plant.set_torque(0, True)
        plant.set_torque(1, True)
        plant.set_goal(0, 25.0)
        clock.sleep(1.0)
        plant.advance()
        return samples

    first, again, other = run(1), run(1), run(2)
    assert len(first) == 100
    assert [t for t, _ in first] == sorted(t for t, _ in first)
    assert first == again
    assert first != other
    # The finger pressed on the steel cup: pressure rose, the skin cooled.
    assert first[-1][1][2] > 3.0
    assert first[-1][1][4] < first[0][1][4]


def test_overload_when_pressing_too_hard() -> None:
    clock = VirtualClock()
    plant = Plant({0: get_object("stainless_cup")}, clock, np.random.default_rng(0))
    plant.attach_sampler(lambda t, values: None, 0.01)
    plant.set_torque(0, True)
    plant.set_goal(0, 55.0)  # far past the surface
    clock.sleep(2.0)
    assert plant.hardware_error(0)
    assert plant.joint_state(0)[3] is False  # the servo switched its torque off
    assert plant.events.overloads == 1
