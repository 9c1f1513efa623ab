"""A trial whose world refuses one touch ends as a RefusedTrial holding what came before it."""

from __future__ import annotations

import numpy as np
import pytest

from core.errors import InvalidInputError, TouchRefused
from core.evaluation.records import RefusedTrial, TrialRecord, outcome_from_dict, trial_seed
from core.evaluation.reference_model import experiment1_at_true_latents
from core.evaluation.trial_engine import Touch, TouchSource, TrialSettings, WorldTouches, run_trial
from core.evaluation.worlds import Experiment1World
from core.recognition.planning import Planner, policy_entry
from core.types import ManifoldModel
from core.validation import FloatArray

SETTINGS = TrialSettings(steps=5, tolerance=0.0)


@pytest.fixture(scope="module")
def model() -> ManifoldModel:
    """Experiment 1 conditioned at the true θ (normalised) with fixed hyperparameters."""
    return experiment1_at_true_latents()


def refusing_at(touch: int, target: str):
    """Experiment 1's observations of ``target``, but touch ``touch`` (1-based) is refused."""
    inner = WorldTouches(Experiment1World(), target)
    count = [0]

    class Refusing:
        def touch(self, action: FloatArray, rng: np.random.Generator) -> Touch:
            count[0] += 1
            if count[0] == touch:
                raise TouchRefused("ServoHardwareError", "servo FFJ3 (ID 1): OVERLOAD")
            return inner.touch(action, rng)

    return Refusing()


def run(model: ManifoldModel, policy: str, touches: TouchSource) -> TrialRecord | RefusedTrial:
    return run_trial(
        model,
        Planner(model, policy_entry(policy).make()),
        policy=policy,
        target="O2",
        trial=1,
        seed=trial_seed(4, "O2", 1),
        touches=touches,
        settings=SETTINGS,
    )


@pytest.mark.parametrize(("policy", "touch"), [("active", 3), ("passive", 1), ("passive", 5)])
def test_a_refused_touch_ends_the_trial_keeping_the_touches_before(
    model: ManifoldModel,
    policy: str,
    touch: int,
) -> None:
    whole = run(model, policy, WorldTouches(Experiment1World(), "O2"))
    assert isinstance(whole, TrialRecord)
    assert whole.touches == 5
    refused = run(model, policy, refusing_at(touch, "O2"))
    assert isinstance(refused, RefusedTrial)
    assert (refused.key, refused.seed) == (whole.key, whole.seed)
    # The same trial up to the refusal: its touches, and the action it was refused.
    assert (refused.touch, refused.touches) == (touch, touch - 1)
    assert refused.actions == whole.actions[: touch - 1]
    assert refused.answers == whole.answers[: touch - 1]
    assert refused.probabilities == whole.probabilities[: touch - 1]
    assert refused.mutual_information == whole.mutual_information[: touch - 1]
    assert refused.action == whole.actions[touch - 1]
    assert (refused.error, refused.reason) == ("ServoHardwareError", "servo FFJ3 (ID 1): OVERLOAD")
    assert refused.correct is False
    document = refused.to_dict()
    assert (document["stop_reason"], document["correct"]) == ("refused", False)
    assert document["refused"]["touch"] == touch
    assert outcome_from_dict(document) == refused
    assert outcome_from_dict(whole.to_dict()) == whole


def test_any_other_error_of_the_world_propagates(model: ManifoldModel) -> None:
    class Broken:
        def touch(self, action: FloatArray, rng: np.random.Generator) -> Touch:
            raise ConnectionError("the finger's port went away")

    with pytest.raises(ConnectionError, match="port went away"):
        run(model, "active", Broken())


def test_a_refused_trial_checks_its_lengths() -> None:
    with pytest.raises(InvalidInputError, match=r"touch - 1 = 1.*'answers': 0"):
        RefusedTrial("active", "O1", 0, (0, 1, 0), 2, (0.5,), "E", "r", actions=((0.1,),))
    with pytest.raises(InvalidInputError, match="refused trial record: missing"):
        RefusedTrial.from_dict({"policy": "active", "refused": {}})
