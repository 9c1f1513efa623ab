"""Cushions with a stiffer insert: the series contact law and what the `cushions` table shows."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from app.rig.actions import TouchActions
from bench.sim_tables import QUIET, touch_all
from hardware.errors import ConfigurationError
from hardware.sim.materials import (
    CUSHION_FOAM,
    CUSHION_INSERT_DEPTH_MM,
    OBJECTS,
    Material,
    get_table,
)
from hardware.sim.world import INSERT_EDGE_MM, FingerModel, _series_force, _softplus

PAD = FingerModel().pad_stiffness_n_per_mm


def _with_insert(stiffness: float, depth_mm: float = CUSHION_INSERT_DEPTH_MM) -> Material:
    return replace(CUSHION_FOAM, insert_depth_mm=depth_mm, insert_stiffness_n_per_mm=stiffness)


def test_a_plain_surface_is_the_pad_and_surface_in_series() -> None:
    for d in (0.0, 0.5, 3.0, 12.0):
        k = 1.0 / (1.0 / PAD + 1.0 / CUSHION_FOAM.stiffness_n_per_mm)
        assert _series_force(CUSHION_FOAM, PAD, d) == pytest.approx(k * d, rel=1e-12)


@pytest.mark.parametrize("insert_n_per_mm", [0.5, 2.0, 20.0, 80.0])
def test_the_insert_force_balances_pad_and_surface(insert_n_per_mm: float) -> None:
    material = _with_insert(insert_n_per_mm)
    k_s, depth = material.stiffness_n_per_mm, CUSHION_INSERT_DEPTH_MM
    for d in np.linspace(0.0, 14.0, 57):
        force = _series_force(material, PAD, float(d))
        compression = d - force / PAD  # the pad carries the force
        insert = _softplus(compression - depth, INSERT_EDGE_MM) - _softplus(-depth, INSERT_EDGE_MM)
        surface = k_s * compression + insert_n_per_mm * insert
        assert surface == pytest.approx(force, rel=1e-9, abs=1e-12)
        assert 0.0 <= compression <= d + 1e-12


def test_the_insert_is_felt_only_past_its_depth() -> None:
    wood = _with_insert(20.0)
    plain = CUSHION_FOAM
    depths = np.linspace(0.0, 14.0, 281)
    force = np.array([_series_force(wood, PAD, float(d)) for d in depths])
    plain_force = np.array([_series_force(plain, PAD, float(d)) for d in depths])
    assert np.all(np.diff(force) > 0)  # stiffer with every millimetre
    shallow = depths < CUSHION_INSERT_DEPTH_MM - 2.5
    assert np.allclose(force[shallow], plain_force[shallow], rtol=0.01)
    # The slope is the pad in series with the surface's tangent stiffness k_s + k_i σ((u − t)/w)
    # (implicit differentiation of the force balance), checked by central differences.
    for d in (4.0, 6.5, 8.0, 11.0, 14.0):
        h = 1e-5
        slope = (_series_force(wood, PAD, d + h) - _series_force(wood, PAD, d - h)) / (2 * h)
        compression = d - _series_force(wood, PAD, d) / PAD
        engaged = 1.0 / (1.0 + np.exp(-(compression - CUSHION_INSERT_DEPTH_MM) / INSERT_EDGE_MM))
        tangent = plain.stiffness_n_per_mm + 20.0 * engaged
        assert slope == pytest.approx(1.0 / (1.0 / PAD + 1.0 / tangent), rel=1e-6)


def test_an_insert_needs_a_depth_and_a_stiffness() -> None:
    with pytest.raises(ConfigurationError, match="insert"):
        replace(CUSHION_FOAM, insert_depth_mm=5.0)
    with pytest.raises(ConfigurationError, match="insert"):
        replace(CUSHION_FOAM, insert_depth_mm=-1.0, insert_stiffness_n_per_mm=2.0)
    assert OBJECTS["cushion_wood"].properties()["insert_depth_mm"] == CUSHION_INSERT_DEPTH_MM
    assert "insert_depth_mm" not in OBJECTS["cushion_plain"].properties()


def test_only_a_deep_press_tells_the_cushions_apart() -> None:
    # Noise-free touches through the simulated rig: at the teaching touch the four cushions
    # press alike (within 0.06 in pressure, less than one touch's pressure noise, 0.075),
    # pressed deeper (flexion weights x_0 = x_1 = +3.75) they are ordered by their insert's
    # stiffness and far apart.
    objects = get_table("cushions").objects
    probes = np.zeros((2, 6))
    probes[1, :2] = 3.75
    clean = touch_all(objects, TouchActions.from_teaching(), probes, QUIET, seed=0)
    pressure = clean[:, :, 2]
    assert np.ptp(pressure[:, 0]) < 0.06
    assert np.all(np.diff(pressure[:, 1]) > 0.3)
    heat = clean[:, :, 3]
    assert np.all(np.diff(heat[:, 1]) > 0.5)  # a larger contact area draws more heat


def test_each_table_says_how_widely_to_vary_its_touches() -> None:
    assert get_table("cushions").action_std == 1.5
    assert get_table("paper").action_std == 0.75
    assert get_table("default").action_std == 1.0
