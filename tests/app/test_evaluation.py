"""Evaluations end to end in process: every synthetic world, the report, resuming, bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest

from app.documents.model import model_from_document
from app.errors import BadInputError
from app.evaluation.report import FORMAT, EvaluationReport
from app.evaluation.runner import run_evaluation
from app.evaluation.spec import EvaluationSpec
from core.evaluation.worlds import random_experiment2_world, sample_dataset, sample_experiment1
from core.gp.posterior import condition
from core.types import Hyperparameters, ManifoldModel
from tests.app.conftest import experiment1_document


@pytest.fixture(scope="module")
def exp1_model() -> ManifoldModel:
    return model_from_document(experiment1_document())


@pytest.fixture(scope="module")
def exp2_model() -> ManifoldModel:
    """The exp2 world of world_seed 0, conditioned at its true latents (no fit)."""
    world = random_experiment2_world(np.random.default_rng(0), noise_std=0.05)
    data = sample_dataset(world, np.random.default_rng(1), touches_per_object=15)
    centred = world.latents - world.latents.mean(axis=0)
    latents = centred / np.sqrt(np.mean(np.sum(centred**2, axis=1)))
    hyper = Hyperparameters(
        signal_variance=np.full(5, 0.5),
        noise_variance=np.full(5, 0.0025),
        latent_lengthscales=np.full((5, 2), 1.0),
        action_lengthscales=np.full((5, 6), 1.5),
    )
    return condition(data, latents, hyper)


def spec(**changes: object) -> EvaluationSpec:
    values: dict[str, object] = {"world": "exp1", "trials_per_target": 2, "steps": 4}
    values.update(changes)
    return EvaluationSpec(**values)  # type: ignore[arg-type]


@pytest.mark.parametrize("world", ["exp1", "model"])
def test_exp1_and_model_worlds_give_a_full_report(exp1_model, world):
    report = run_evaluation(exp1_model, spec(world=world))
    assert len(report.records) == 2 * 4 * 2
    assert report.workers == 1
    assert not report.stopped
    document = json.loads(json.dumps(report.to_dict()))
    assert document["format"] == FORMAT
    assert document["world"] == world
    assert document["steps"] == 4
    assert set(document["policies"]) == {"active", "passive"}
    active = document["policies"]["active"]
    assert len(active["accuracy_by_touch"]) == 4
    assert len(active["accuracy_interval"]) == 4
    assert set(active["per_object"]) == {"O1", "O2", "O3", "O4"}
    assert sum(sum(row.values()) for row in active["confusion"].values()) == 8
    assert len(document["trials"]) == 16
    keys = [(t["policy"], t["target"], t["trial"]) for t in document["trials"]]
    assert keys == sorted(keys)


def test_exp2_world_runs_on_an_exp2_model(exp2_model):
    report = run_evaluation(exp2_model, spec(world="exp2", targets=("O1", "O4")))
    assert {r.target for r in report.records} == {"O1", "O4"}
    assert all(len(r.actions[0]) == 6 for r in report.records)


def test_a_trial_alone_equals_the_same_trial_in_a_batch(exp1_model):
    whole = run_evaluation(exp1_model, spec(trials_per_target=3))
    alone = run_evaluation(exp1_model, spec(trials_per_target=3, targets=("O3",)))
    mine = [r for r in whole.records if r.target == "O3"]
    assert list(alone.records) == mine


def test_resume_skips_done_trials_and_stop_keeps_finished_ones(exp1_model):
    whole = run_evaluation(exp1_model, spec())
    seen = []
    resumed = run_evaluation(
        exp1_model, spec(), done=whole.records[:5], on_trial=lambda r: seen.append(r.key)
    )
    assert resumed.records == whole.records
    assert len(seen) == len(whole.records) - 5
    seen.clear()
    stopped = run_evaluation(
        exp1_model,
        spec(),
        on_trial=lambda r: seen.append(r.key),
        should_stop=lambda: len(seen) >= 3,
    )
    assert stopped.stopped
    assert stopped.records == whole.records[:3]
    assert stopped.to_dict()["notes"]


def test_csv_rows_have_one_row_per_trial_and_touch(exp1_model):
    report = run_evaluation(exp1_model, spec(policies=("active",)))
    rows = report.csv_rows()
    assert rows[0][:4] == ["policy", "target", "trial", "touch"]
    assert rows[0][-1] == "stop_reason"
    assert len(rows) == 1 + sum(r.touches for r in report.records)
    last_of_first = rows[report.records[0].touches]
    assert last_of_first[-1] == report.records[0].stop_reason


def assert_stopped_by_confidence(records, threshold):
    """Every trial whose answer reached ``threshold`` stopped at that touch saying "confident";
    no other trial says it; and at least one did."""
    assert any(r.stop_reason == "confident" for r in records)
    for record in records:
        reached = [t for t, p in enumerate(record.probabilities, 1) if max(p) >= threshold]
        if reached:
            assert record.stop_reason == "confident", record
            assert record.touches == reached[0]
        else:
            assert record.stop_reason != "confident", record


@pytest.mark.parametrize("world", ["exp1", "model", "replay"])
def test_a_trial_stopped_by_the_confidence_rule_records_it(exp1_model, world):
    held_out = sample_experiment1(np.random.default_rng(6), touches_per_object=10)
    report = run_evaluation(
        exp1_model,
        spec(world=world, steps=10, tolerance=0.0, stop_at_confidence=True, confidence=0.9),
        replay=held_out if world == "replay" else None,
    )
    assert_stopped_by_confidence(report.records, 0.9)
    # The CSV says so on the trial's last touch.
    rows = report.csv_rows()
    last = {(r[0], r[1], r[2]): r[-1] for r in rows[1:] if r[-1]}
    for record in report.records:
        assert last[record.key] == record.stop_reason


def test_replay_world_caps_t_at_the_pool_and_says_so(exp1_model):
    held_out = sample_experiment1(np.random.default_rng(5), touches_per_object=3)
    report = run_evaluation(
        exp1_model, spec(world="replay", steps=10, tolerance=0.0), replay=held_out
    )
    assert report.steps == 3
    assert all(r.touches == 3 for r in report.records)
    document = report.to_dict()
    assert document["steps"] == 3
    assert document["steps_requested"] == 10
    assert "capped at 3" in document["notes"][0]
    assert "active choose(s) the recorded touch deterministically" in document["notes"][1]
    active = [r for r in report.records if r.policy == "active" and r.target == "O2"]
    assert active[0].actions == active[1].actions


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"world": "moon"}, r"world: 'moon'.*'exp1', 'exp2', 'rig', 'model', 'replay'"),
        (
            {"policies": ("active", "greedy")},
            r"\['greedy'\] unknown.*\['active', 'discriminative', 'passive'\]",
        ),
        ({"policies": ()}, "policies"),
        ({"trials_per_target": 0}, "trials_per_target"),
        ({"steps": 0}, "steps"),
        ({"confidence": 1.5}, "confidence"),
        ({"targets": ("O2", "cup")}, r"\['cup'\]"),
        ({"world": "exp2"}, "world: exp2 has dx=6, dy=5 but the model has dx=1, dy=3"),
        ({"world": "rig"}, "the simulated rig has dx=6"),
        ({"world": "rig", "table": "moon"}, "table: 'moon'.*'default'"),
        ({"world": "replay"}, "data: the replay world needs held-out touches"),
        ({"trial_likelihood": "product"}, r"trial_likelihood: 'product'.*'joint', 'independent'"),
        ({"plan_under": "mixture"}, r"plan_under: 'mixture'.*'objects', 'gaussian'"),
    ],
)
def test_bad_specs_are_named(exp1_model, changes, message):
    with pytest.raises(BadInputError, match=message):
        run_evaluation(exp1_model, spec(**changes))


def test_replay_data_that_does_not_match_the_model_is_named(exp1_model, exp2_model):
    other = sample_dataset(
        random_experiment2_world(np.random.default_rng(0)), np.random.default_rng(0), 3
    )
    with pytest.raises(BadInputError, match="held-out data has dx=6, dy=5"):
        run_evaluation(exp1_model, spec(world="replay"), replay=other)
    renamed = sample_experiment1(np.random.default_rng(5), touches_per_object=3)
    renamed = type(renamed)(
        object_names=("O1", "O2", "O3", "mug"),
        object_index=renamed.object_index,
        actions=renamed.actions,
        observations=renamed.observations,
    )
    with pytest.raises(BadInputError, match=r"objects \['mug'\] of the held-out data"):
        run_evaluation(exp1_model, spec(world="replay"), replay=renamed)
    with pytest.raises(BadInputError, match="workers and scheduler"):
        run_evaluation(exp1_model, spec(), workers=2, scheduler="tcp://127.0.0.1:1")


def test_report_sorts_records_and_survives_an_empty_run(exp1_model):
    report = EvaluationReport(
        spec=spec(), records=(), seconds=0.0, workers=1, stopped=True, object_names=("O1",)
    )
    assert report.to_dict()["policies"] == {}
    assert report.csv_rows()[0][0] == "policy"


@pytest.mark.parametrize(
    ("world", "placement", "shared"),
    [("rig", "trial", True), ("rig", "touch", False), ("replay", "trial", False)],
)
def test_the_placement_variance_enters_only_trials_that_share_a_placement(world, placement, shared):
    settings = EvaluationSpec(
        world=world, trials_per_target=1, steps=3, placement=placement
    ).trial_settings()
    assert settings.recognition().shared_placement is shared
    assert settings.recognition().trial_likelihood == "joint"
    assert settings.recognition().plan_under == "objects"
