"""The adaptive training design: a round's actions are where the planners score highest."""

from __future__ import annotations

import numpy as np
import pytest

from core.errors import InvalidInputError
from core.evaluation.adaptive_design import (
    planner_round,
    round_sizes,
    situation_scores,
    take_in_turns,
)
from core.evaluation.reference_model import experiment1_at_true_latents
from core.recognition.planning import (
    ActionBox,
    ActivePolicy,
    DiscriminativePolicy,
    Planner,
    sobol_candidates,
)
from core.recognition.session import default_prior


@pytest.fixture(scope="module")
def model():  # type: ignore[no-untyped-def]
    return experiment1_at_true_latents(seed=0, touches_per_object=8)


def test_the_situations_are_the_planners_own_scores(model) -> None:  # type: ignore[no-untyped-def]
    n_objects = model.data.n_objects
    active = Planner(model, ActivePolicy(), n_candidates=64)
    discriminative = Planner(model, DiscriminativePolicy(), n_candidates=64)
    candidates = active.candidate_statistics.actions
    scores = situation_scores(model, candidates)
    assert scores.shape == (2 + n_objects * (n_objects - 1) // 2, 64)
    np.testing.assert_allclose(
        scores[0], active.mutual_information(default_prior(model), candidates), rtol=1e-9
    )
    np.testing.assert_allclose(scores[1], discriminative.object_information(None), rtol=1e-9)
    p = np.zeros(n_objects)
    p[[0, 1]] = 0.5  # the first pair
    np.testing.assert_allclose(scores[2], discriminative.object_information(p), rtol=1e-9)


def test_situations_take_their_best_untaken_candidate_in_turn() -> None:
    scores = np.array([[5.0, 4.0, 3.0, 0.0], [5.0, 0.0, 1.0, 2.0]])
    # Situation 0 takes 0; situation 1's best (0) is taken, so 3; then 1, then 2.
    assert take_in_turns(scores, 4) == [0, 3, 1, 2]
    assert take_in_turns(scores, 1) == [0]
    with pytest.raises(InvalidInputError, match="n_actions"):
        take_in_turns(scores, 5)


def test_a_round_touches_every_object_at_the_planners_best_actions(model) -> None:  # type: ignore[no-untyped-def]
    n_objects, dx = model.data.n_objects, model.hyperparameters.action_dim
    design = planner_round(model, 5, np.random.default_rng(3), n_candidates=64)
    assert design.shared
    assert np.bincount(design.object_index).tolist() == [5] * n_objects  # each object equally
    actions = design.actions.reshape(n_objects, 5, dx)
    for obj in range(1, n_objects):
        np.testing.assert_array_equal(actions[obj], actions[0])
    # The same candidate set (the rng's next seed), scored: the first two chosen are active's
    # and the discriminative planner's best.
    seed = int(np.random.default_rng(3).integers(2**31))
    candidates = sobol_candidates(ActionBox.from_model(model), 64, seed)
    scores = situation_scores(model, candidates)
    np.testing.assert_array_equal(actions[0, 0], candidates[np.argmax(scores[0])])
    if np.argmax(scores[1]) != np.argmax(scores[0]):
        np.testing.assert_array_equal(actions[0, 1], candidates[np.argmax(scores[1])])
    assert ActionBox.from_model(model).contains(actions[0])
    assert len(np.unique(actions[0], axis=0)) == 5


def test_the_rounds_spend_the_budget_left_after_the_initial_design() -> None:
    assert round_sizes(100, 50, 2) == [25, 25]
    assert round_sizes(10, 3, 2) == [4, 3]
    assert sum(round_sizes(37, 18, 3)) == 19
    with pytest.raises(InvalidInputError, match="initial"):
        round_sizes(10, 10, 1)
    with pytest.raises(InvalidInputError, match="rounds"):
        round_sizes(4, 3, 2)
