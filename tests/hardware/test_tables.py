"""Named simulated tables, coated surfaces, and what separates the look-alike objects."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from app.cli.main import app
from app.rig.actions import TouchActions
from app.rig.build import SimulationMode, open_rig
from bench.sim_tables import QUIET, touch_all
from hardware.errors import ConfigurationError
from hardware.sim.materials import (
    DEFAULT_TABLE,
    DEFAULT_TABLE_NAME,
    OBJECTS,
    PET,
    PET_ON_WATER,
    TABLES,
    Material,
    design_std,
    get_table,
)


def test_every_table_names_known_objects_and_the_default_stays() -> None:
    assert get_table(DEFAULT_TABLE_NAME).objects == DEFAULT_TABLE
    for table in TABLES.values():
        assert table.objects
        assert set(table.objects) <= set(OBJECTS)
        assert len(set(table.objects)) == len(table.objects)
    with pytest.raises(ConfigurationError, match="tables: default, paper"):
        get_table("kitchen")


def test_a_coated_surface_feels_like_its_coating_then_like_its_body() -> None:
    water = PET_ON_WATER
    assert water.coating_effusivity is not None
    assert water.effusivity_at(0.0) == water.coating_effusivity
    assert water.effusivity_at(0.3) == pytest.approx(water.coating_effusivity, rel=1e-9)
    assert water.effusivity_at(1e6) == pytest.approx(water.effusivity, rel=2e-3)
    times = np.geomspace(0.1, 1e5, 50)
    values = [water.effusivity_at(t) for t in times]
    assert np.all(np.diff(values) >= -1e-9)  # a better conductor below: rising monotonically
    # Image series against a brute sum of many more terms at t = τ.
    coat, body, tau = 560.0, 1580.0, water.coating_time_s
    gamma = (coat - body) / (coat + body)
    brute = coat * (1 + 2 * sum((-gamma) ** n * np.exp(-(n**2)) for n in range(1, 400)))
    assert water.effusivity_at(tau) == pytest.approx(brute, rel=1e-12)
    # An insulating body under a conducting coat: falling instead.
    inverted = Material("steel on foam", 80.0, 0.3, 0.05, 0.4, 0.5, 60.0, 7600.0, 2.0)
    assert inverted.effusivity_at(0.01) > inverted.effusivity_at(100.0)
    assert PET.effusivity_at(5.0) == PET.effusivity
    with pytest.raises(ConfigurationError, match="coating"):
        Material("bad", 1.0, 0.3, 0.1, 1.0, 1.0, 500.0, coating_effusivity=100.0)


def test_open_rig_takes_a_table_name() -> None:
    handle = open_rig(simulate=SimulationMode.in_process, table="lookalike_cups")
    try:
        assert handle.table is TABLES["lookalike_cups"]
        assert handle.object_names == list(TABLES["lookalike_cups"].objects)
    finally:
        handle.close()
    with pytest.raises(ConfigurationError, match="unknown table"):
        open_rig(simulate=SimulationMode.in_process, table="kitchen")


def test_rig_status_lists_a_tables_objects_and_refuses_unknown_tables() -> None:
    runner = CliRunner()
    result = runner.invoke(app, ["rig", "status", "--sim", "--table", "textures", "--json"])
    assert result.exit_code == 0, result.output
    document = json.loads(result.stdout)
    assert document["simulated_table"] == "textures"
    assert document["simulated_objects"] == list(TABLES["textures"].objects)
    bad = runner.invoke(app, ["rig", "status", "--sim", "--table", "kitchen"])
    assert bad.exit_code == 2
    assert "lookalike_cups" in bad.stderr


def test_a_deep_press_separates_the_stiffness_look_alikes_more_than_a_shallow_one() -> None:
    # Noise-free touches on the simulated rig: the thicker wall's extra pressure grows with the
    # press depth (flexion weights x_0, x_1), and sliding faster (x_3 < 0) shows more of the
    # wax film's missing stick-slip; the wall thickness does not change the heat flux much.
    actions = TouchActions.from_teaching()
    objects = ("pet_cup", "pet_cup_stiff", "pet_cup_waxed")
    probes = np.zeros((3, 6))
    probes[1, :2] = -5.0  # shallow press
    probes[2, :2] = 5.0  # deep press
    clean = touch_all(objects, actions, probes, QUIET, seed=0)
    pressure = clean[:, :, 2]
    stiff_gap = pressure[1] - pressure[0]
    assert 0 < stiff_gap[1] < stiff_gap[0] < stiff_gap[2]
    assert stiff_gap[2] > 1.5 * stiff_gap[1]
    vibration_gap = clean[0, :, 1] - clean[2, :, 1]
    assert np.all(vibration_gap > 0)  # less stick-slip on wax
    assert vibration_gap[2] > vibration_gap[1]


def test_a_design_spread_is_the_given_one_else_the_tables() -> None:
    assert design_std("cushions") == get_table("cushions").action_std == 1.5
    assert design_std("cushions", 0.5) == 0.5
    assert design_std("kitchen", 0.5) == 0.5  # a given spread needs no table
    with pytest.raises(ConfigurationError, match="unknown table 'kitchen'"):
        design_std("kitchen")
