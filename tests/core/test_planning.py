"""Planning: candidates in the box, active ≥ the best of a candidate set, policies, bad input."""

from __future__ import annotations

import numpy as np
import pytest

from core.errors import InvalidInputError
from core.recognition.planning import (
    ActionBox,
    ActionPrior,
    ActivePolicy,
    FixedPolicy,
    PassivePolicy,
    Planner,
    sobol_candidates,
)
from core.types import GaussianBelief, ManifoldModel
from tests.core.test_moments import BELIEFS, small_model

BOX = ActionBox(lower=np.array([-1.5, -1.0]), upper=np.array([1.0, 2.0]))


@pytest.fixture(scope="module")
def model() -> ManifoldModel:
    return small_model()


def test_sobol_candidates_fill_the_box() -> None:
    candidates = sobol_candidates(BOX, 100, seed=3)
    assert candidates.shape == (100, 2)
    assert BOX.contains(candidates)
    # Spread over the box: every quarter of each side holds some candidates.
    for dim in range(2):
        unit = (candidates[:, dim] - BOX.lower[dim]) / (BOX.upper[dim] - BOX.lower[dim])
        counts = np.histogram(unit, bins=4, range=(0.0, 1.0))[0]
        assert np.all(counts >= 20)
    np.testing.assert_array_equal(candidates, sobol_candidates(BOX, 100, seed=3))


@pytest.mark.parametrize("belief_name", sorted(BELIEFS))
def test_active_plan_stays_in_the_box_and_beats_the_candidates(
    model: ManifoldModel, belief_name: str
) -> None:
    belief = BELIEFS[belief_name]
    planner = Planner(model, ActivePolicy(), box=BOX, n_candidates=64, n_refine=2)
    rng = np.random.default_rng(0)
    planned = planner.plan(belief, rng)
    assert planned.policy == "active"
    assert BOX.contains(planned.action)
    recomputed = planner.mutual_information(belief, planned.action[None, :])[0]
    assert planned.mutual_information == pytest.approx(recomputed, rel=1e-10)
    candidate_scores = planner.mutual_information(belief, planner.candidate_statistics.actions)
    assert planned.mutual_information >= candidate_scores.max() - 1e-12
    passive = Planner(model, PassivePolicy(), box=BOX)
    draws = np.array([passive.plan(belief, rng).action for _ in range(64)])
    assert planned.mutual_information >= planner.mutual_information(belief, draws).max()
    unrefined = Planner(model, ActivePolicy(), box=BOX, n_candidates=64, n_refine=0)
    coarse = unrefined.plan(belief, rng)
    assert coarse.mutual_information == pytest.approx(candidate_scores.max(), rel=1e-12)
    assert planned.mutual_information >= coarse.mutual_information


def test_refinement_reaches_a_stationary_point_or_the_boundary(model: ManifoldModel) -> None:
    belief = BELIEFS["correlated"]
    planner = Planner(model, ActivePolicy(), box=BOX, n_candidates=32, refine_iterations=200)
    planned = planner.plan(belief, np.random.default_rng(0))
    step = 1e-4
    for dim in range(2):
        for sign in (-1.0, 1.0):
            moved = BOX.clip(planned.action + sign * step * np.eye(2)[dim])
            value = planner.mutual_information(belief, moved[None, :])[0]
            assert value <= planned.mutual_information + 1e-6


def test_candidate_statistics_are_computed_once_and_reused(model: ManifoldModel) -> None:
    planner = Planner(model, ActivePolicy(), box=BOX, n_candidates=16)
    stats = planner.candidate_statistics
    rng = np.random.default_rng(0)
    for belief in BELIEFS.values():
        planner.plan(belief, rng)
        assert planner.candidate_statistics is stats


def test_passive_draws_from_the_prior_clipped_to_the_box(model: ManifoldModel) -> None:
    prior = ActionPrior(mean=np.array([0.2, 0.5]), cov=np.diag([0.04, 0.09]))
    wide_box = ActionBox(lower=np.array([-10.0, -10.0]), upper=np.array([10.0, 10.0]))
    planner = Planner(model, PassivePolicy(), box=wide_box, prior=prior)
    rng = np.random.default_rng(4)
    belief = BELIEFS["broad"]
    plans = [planner.plan(belief, rng) for _ in range(200)]
    draws = np.array([p.action for p in plans])
    assert np.all(np.abs(draws.mean(axis=0) - prior.mean) < 4 * np.sqrt(np.diag(prior.cov) / 200))
    np.testing.assert_allclose(np.cov(draws.T), prior.cov, rtol=0.3, atol=0.025)
    assert plans[0].policy == "passive"
    assert plans[0].mutual_information == pytest.approx(
        planner.mutual_information(belief, draws[:1])[0], rel=1e-12
    )
    clipped = Planner(
        model, PassivePolicy(), box=BOX, prior=ActionPrior(np.zeros(2), 25 * np.eye(2))
    )
    clipped_draws = np.array([clipped.plan(belief, rng).action for _ in range(100)])
    assert BOX.contains(clipped_draws)
    assert np.any(clipped_draws == BOX.upper)
    assert np.any(clipped_draws == BOX.lower)


def test_fixed_policy_repeats_its_action(model: ManifoldModel) -> None:
    planner = Planner(model, FixedPolicy(np.array([0.3, -0.2])), box=BOX)
    rng = np.random.default_rng(0)
    for belief in BELIEFS.values():
        planned = planner.plan(belief, rng)
        np.testing.assert_array_equal(planned.action, [0.3, -0.2])
        assert planned.policy == "fixed"
        assert planned.mutual_information == pytest.approx(
            planner.mutual_information(belief, planned.action[None, :])[0], rel=1e-12
        )


def test_defaults_come_from_the_training_actions(model: ManifoldModel) -> None:
    planner = Planner(model, PassivePolicy())
    actions = model.data.actions
    mean, std = actions.mean(axis=0), actions.std(axis=0)
    # Mean ± 2 std, within the range of the training actions.
    np.testing.assert_allclose(
        planner.box.lower, np.maximum(actions.min(axis=0), mean - 2 * std), rtol=1e-12
    )
    np.testing.assert_allclose(
        planner.box.upper, np.minimum(actions.max(axis=0), mean + 2 * std), rtol=1e-12
    )
    assert np.all(planner.box.lower >= actions.min(axis=0))
    assert np.all(planner.box.upper <= actions.max(axis=0))
    whole = ActionBox.from_model(model, spread_std=None)
    np.testing.assert_array_equal(whole.lower, actions.min(axis=0))
    np.testing.assert_array_equal(whole.upper, actions.max(axis=0))
    narrow = ActionBox.from_model(model, spread_std=0.5)
    np.testing.assert_allclose(narrow.upper - narrow.lower, std, rtol=1e-12)
    with pytest.raises(InvalidInputError, match="spread_std"):
        ActionBox.from_model(model, spread_std=0.0)
    np.testing.assert_allclose(planner.prior.mean, model.data.actions.mean(axis=0))


def test_bad_input_is_rejected_with_the_argument_named(model: ManifoldModel) -> None:
    with pytest.raises(InvalidInputError, match="box"):
        ActionBox(lower=np.array([0.0, 1.0]), upper=np.array([1.0, 0.0]))
    with pytest.raises(InvalidInputError, match="box lower"):
        ActionBox(lower=np.array([np.nan, 0.0]), upper=np.array([1.0, 1.0]))
    with pytest.raises(InvalidInputError, match="box"):
        Planner(model, ActivePolicy(), box=ActionBox(np.zeros(3), np.ones(3)))
    with pytest.raises(InvalidInputError, match="fixed action"):
        Planner(model, FixedPolicy(np.zeros(3)))
    with pytest.raises(InvalidInputError, match="fixed action"):
        FixedPolicy(np.array([np.inf, 0.0]))
    with pytest.raises(InvalidInputError, match="action prior cov"):
        ActionPrior(mean=np.zeros(2), cov=np.array([[1.0, 0.0], [0.0, -1.0]]))
    with pytest.raises(InvalidInputError, match="n_candidates"):
        Planner(model, ActivePolicy(), n_candidates=0)
    planner = Planner(model, PassivePolicy(), box=BOX)
    with pytest.raises(InvalidInputError, match="belief"):
        planner.plan(GaussianBelief(np.zeros(3), np.eye(3)), np.random.default_rng(0))
    with pytest.raises(InvalidInputError, match="actions"):
        planner.mutual_information(BELIEFS["broad"], np.array([[np.nan, 0.0]]))
