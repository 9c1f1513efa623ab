"""The ``rig`` world: trials on the simulated rig in process (virtual time), seeded per trial."""

from __future__ import annotations

import numpy as np
import pytest

from app.errors import BadInputError
from app.evaluation.context import rig_tables
from app.evaluation.runner import run_evaluation
from app.evaluation.spec import EvaluationSpec, Placement
from app.rig.actions import TouchActions
from tests.app.conftest import RIG_OBJECTS, fitted_on_the_rig


def spec(**changes: object) -> EvaluationSpec:
    values: dict[str, object] = {
        "world": "rig",
        "trials_per_target": 1,
        "steps": 2,
        "targets": ("paper_cup", "foam_sponge"),
        "table": "default",
    }
    values.update(changes)
    return EvaluationSpec(**values)  # type: ignore[arg-type]


def test_rig_trials_touch_the_simulated_table_and_are_reproducible(rig_model):
    first = run_evaluation(rig_model, spec())
    assert [r.key for r in first.records] == [
        ("active", "foam_sponge", 0),
        ("active", "paper_cup", 0),
        ("passive", "foam_sponge", 0),
        ("passive", "paper_cup", 0),
    ]
    assert all(len(r.actions[0]) == 6 and 1 <= r.touches <= 2 for r in first.records)
    again = run_evaluation(rig_model, spec(policies=("passive",), targets=("paper_cup",)))
    assert again.records == first.records[3:]


def test_a_rig_trial_stopped_by_the_confidence_rule_records_it(rig_model):
    from tests.app.test_evaluation import assert_stopped_by_confidence

    report = run_evaluation(
        rig_model,
        spec(steps=4, tolerance=0.0, stop_at_confidence=True, confidence=0.6, trials_per_target=2),
    )
    assert_stopped_by_confidence(report.records, 0.6)


def test_rig_targets_must_be_model_objects(rig_model):
    with pytest.raises(BadInputError, match=r"targets: \['cork_board'\] are not objects"):
        run_evaluation(rig_model, spec(targets=("cork_board",)))


def test_an_unknown_table_lists_the_tables(rig_model):
    with pytest.raises(BadInputError, match=r"table: 'kitchen'.*'default'"):
        run_evaluation(rig_model, spec(table="kitchen"))


def test_tables_come_by_name_from_the_simulator() -> None:
    from hardware.sim import materials

    tables = rig_tables()
    assert set(tables) == set(materials.TABLES)
    assert tables["default"] == tuple(materials.DEFAULT_TABLE)
    assert tables["cushions"] == materials.get_table("cushions").objects


# Placements count every object's arrivals under the finger: once per trial, or for touches 2
# and 3 the neighbour's arrival and the target's return (1 + 2 · 2).
@pytest.mark.parametrize(("placement", "placements"), [("trial", 1), ("touch", 5)])
def test_a_rig_trial_places_its_object_once_or_before_every_touch(
    placement: Placement, placements: int
) -> None:
    from app.evaluation.rig_trial import RigTrial

    trial = RigTrial(
        TouchActions.from_teaching(),
        rig_tables()["default"],
        "paper_cup",
        rig_seed=5,
        placement=placement,
    )
    try:
        for _ in range(3):
            trial.touch(np.zeros(6), np.random.default_rng(0))
        devices = trial._handle.simulation.devices  # type: ignore[union-attr]
        assert devices.plant.events.placements == placements
        assert devices.plant.events.touched == {"paper_cup": 3}
    finally:
        trial.close()


def test_placement_must_be_trial_or_touch(rig_model):
    with pytest.raises(BadInputError, match=r"placement: 'shelf'.*\['trial', 'touch'\]"):
        run_evaluation(rig_model, spec(placement="shelf"))


def test_only_the_rig_world_places_objects(rig_model):
    with pytest.raises(BadInputError, match="placement: only the rig world"):
        run_evaluation(rig_model, spec(world="model", table=None, placement="touch"))


def test_a_rig_evaluation_simulates_the_servers_table_unless_told(tmp_path) -> None:
    from fastapi.testclient import TestClient

    from app.documents.model import model_to_document
    from app.main import create_app
    from tests.app.conftest import make_settings

    cushions = rig_tables()["cushions"]
    model = fitted_on_the_rig("cushions", cushions, touches=3, latent_dim=1, seed=1)
    settings = make_settings(tmp_path, sim_table="cushions")
    with TestClient(create_app(settings)) as client:
        imported = client.post("/api/v1/models/import", json=model_to_document(model))
        assert imported.status_code == 201, imported.text
        body = {
            "model_id": imported.json()["id"],
            "world": "rig",
            "policies": ["passive"],
            "trials_per_target": 1,
            "steps": 1,
            "targets": ["cushion_cork"],
        }
        created = client.post("/api/v1/evaluations", json=body)
        assert created.status_code in (201, 202), created.text
        assert created.json()["spec"]["table"] == "cushions"
        # Naming another table still wins (and there the model's objects are not found).
        other = client.post("/api/v1/evaluations", json={**body, "table": "default"})
        assert other.status_code == 422
        assert "cushion_cork" in other.json()["detail"]


def test_a_rig_trial_simulates_the_noise_model_it_is_given() -> None:
    from dataclasses import replace

    from app.evaluation.rig_trial import RigTrial
    from hardware.sim.noise import NO_DRIFT, NoiseModel

    quiet = replace(NoiseModel(), drift=NO_DRIFT, placement_std_deg=0.0)
    trial = RigTrial(
        TouchActions.from_teaching(), RIG_OBJECTS, "ceramic_mug", rig_seed=1, noise=quiet
    )
    try:
        assert trial._handle.simulation.devices.plant.noise is quiet  # type: ignore[union-attr]
    finally:
        trial.close()


# Three active touches: the third action's mutual information depends on the second touch's
# observation, which depends on where the object was placed.
@pytest.mark.parametrize(("source", "world"), [("rig", "rig"), ("gp", "model")])
def test_the_sim_tables_bench_runs_the_engines_trials(rig_model, source: str, world: str) -> None:
    """bench/sim_tables.py's trials are the engine's: the same records as ``run_evaluation``."""
    from bench.sim_tables import policy_records

    placement = "touch" if world == "rig" else "trial"
    engine = run_evaluation(
        rig_model,
        spec(
            world=world,
            policies=("active",),
            targets=None,
            steps=3,
            table="default" if world == "rig" else None,
            tolerance=0.0,
            seed=4,
            placement=placement,
        ),
    )
    bench = policy_records(
        rig_model,
        "active",
        1,
        3,
        4,
        source=source,
        table="default",
        placement=placement,
    )
    assert len(bench) == len(rig_model.object_names) == 3
    assert sorted(bench, key=lambda r: r.key) == sorted(engine.records, key=lambda r: r.key)
