"""The discriminative policy: object predictives, the label-information estimates, planning."""

from __future__ import annotations

import numpy as np
import pytest

from core.errors import InvalidInputError
from core.gp.posterior import condition, predict
from core.recognition.moments import action_statistics
from core.recognition.object_information import (
    label_information_bounds,
    label_information_mc,
    object_predictives,
)
from core.recognition.planning import (
    POLICY_NAMES,
    ActivePolicy,
    DiscriminativePolicy,
    FixedPolicy,
    PassivePolicy,
    Planner,
    make_policy,
)
from core.recognition.session import RecognitionSession, default_prior
from core.types import Hyperparameters, ManifoldModel, TrainingData
from tests.core.test_moments import small_model


def shared_design_model(seed: int = 1, n_objects: int = 4, n_actions: int = 9) -> ManifoldModel:
    """A model conditioned on a complete shared design (the Kronecker posterior)."""
    rng = np.random.default_rng(seed)
    latents = rng.standard_normal((n_objects, 2))
    design = rng.standard_normal((n_actions, 2))
    actions = np.tile(design, (n_objects, 1))
    index = np.repeat(np.arange(n_objects), n_actions)
    observations = np.sin((actions + latents[index]) @ rng.standard_normal((2, 3))) + 0.1 * (
        rng.standard_normal((actions.shape[0], 3))
    )
    data = TrainingData(tuple(f"o{i}" for i in range(n_objects)), index, actions, observations)
    hyper = Hyperparameters(
        signal_variance=np.array([1.0, 0.7, 1.5]),
        noise_variance=np.array([0.02, 0.05, 0.03]),
        latent_lengthscales=np.full((3, 2), 1.2),
        action_lengthscales=np.full((3, 2), 0.9),
    )
    return condition(data, latents, hyper, structure="kronecker")


@pytest.mark.parametrize("kind", ["dense", "kronecker"])
def test_object_predictives_equal_the_gp_prediction_at_each_learned_latent(kind: str) -> None:
    model = small_model() if kind == "dense" else shared_design_model()
    assert (model.posterior.kronecker is not None) == (kind == "kronecker")
    actions = np.random.default_rng(4).uniform(-2.0, 2.0, (7, model.hyperparameters.action_dim))
    mean, variance = object_predictives(model, action_statistics(model, actions))
    n_objects = model.data.n_objects
    for obj in range(n_objects):
        expected_mean, expected_variance = predict(
            model, np.repeat(model.latents[obj : obj + 1], 7, axis=0), actions
        )
        np.testing.assert_allclose(mean[:, obj], expected_mean, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(variance[:, obj], expected_variance, rtol=1e-7, atol=1e-10)


def _brute_force_information(
    p: np.ndarray, mean: np.ndarray, variance: np.ndarray, n: int, seed: int
) -> float:
    """I(l; y) by plain Monte Carlo: draw l ~ p, y ~ N(m_l, V_l), average log p(y|l)/p(y)."""
    rng = np.random.default_rng(seed)
    labels = rng.choice(p.shape[0], size=n, p=p)
    y = mean[labels] + np.sqrt(variance[labels]) * rng.standard_normal((n, mean.shape[1]))
    log_density = -0.5 * np.sum(
        np.log(2 * np.pi * variance)[None] + (y[:, None, :] - mean[None]) ** 2 / variance[None],
        axis=2,
    )  # (n, L)
    own = log_density[np.arange(n), labels]
    mixture = np.logaddexp.reduce(log_density + np.log(p)[None], axis=1)
    return float(np.mean(own - mixture))


MIXTURES = {
    "separated": (np.array([0.25, 0.25, 0.5]), np.array([[0.0, 0.0], [3.0, 0.0], [0.0, 4.0]])),
    "overlapping": (np.array([0.6, 0.3, 0.1]), np.array([[0.0, 0.0], [0.5, 0.2], [0.2, -0.6]])),
    "nearly_certain": (np.array([0.98, 0.01, 0.01]), np.array([[0.0, 0.0], [1.0, 0.0], [0, 1.0]])),
}


@pytest.mark.parametrize("name", sorted(MIXTURES))
def test_monte_carlo_estimate_and_bounds_agree_with_brute_force(name: str) -> None:
    p, mean = MIXTURES[name]
    variance = np.array([[1.0, 0.5], [0.7, 1.2], [0.4, 0.9]])
    draws = np.random.default_rng(0).standard_normal((4000, 2))
    estimate = label_information_mc(p, mean[None], variance[None], draws)[0]
    reference = _brute_force_information(p, mean, variance, 400_000, seed=1)
    # Brute force: standard error ≲ 0.002 nats at n = 400 000; the CRN estimate with K = 4000
    # draws per object: ≲ 0.01.
    assert estimate == pytest.approx(reference, abs=0.03)
    lower, upper = label_information_bounds(p, mean[None], variance[None])
    assert lower[0] - 0.01 <= reference <= upper[0] + 0.01
    entropy = -np.sum(p * np.log(p))
    assert 0.0 <= lower[0] <= upper[0] <= entropy + 1e-12


def test_label_information_limits() -> None:
    mean = np.array([[[0.0, 0.0], [50.0, 0.0]]])
    variance = np.ones((1, 2, 2))
    draws = np.random.default_rng(0).standard_normal((64, 2))
    # Far apart: the touch reveals the label, I = H(p).
    p = np.array([0.3, 0.7])
    entropy = -np.sum(p * np.log(p))
    assert label_information_mc(p, mean, variance, draws)[0] == pytest.approx(entropy, abs=1e-9)
    # Identical predictives: nothing to learn.
    same = np.zeros((1, 2, 2))
    assert label_information_mc(p, same, variance, draws)[0] == pytest.approx(0.0, abs=1e-12)
    # Certain of the object: nothing to learn either.
    certain = np.array([1.0, 0.0])
    assert label_information_mc(certain, mean, variance, draws)[0] == 0.0
    with pytest.raises(InvalidInputError, match="probabilities"):
        label_information_mc(np.array([0.5, 0.6]), mean, variance, draws)


def test_common_random_numbers_rank_candidates_consistently() -> None:
    # Two candidates whose separations differ a little: with the same draws the ranking is right
    # in every repetition.
    mean = np.array([[[0.0], [1.0]], [[0.0], [1.1]]])
    variance = np.ones((2, 2, 1))
    p = np.array([0.5, 0.5])
    for seed in range(20):
        draws = np.random.default_rng(seed).standard_normal((64, 1))
        scores = label_information_mc(p, mean, variance, draws)
        assert scores[1] > scores[0]


def test_discriminative_planner_picks_the_best_candidate_and_reuses_the_statistics() -> None:
    model = shared_design_model()
    planner = Planner(model, DiscriminativePolicy(), n_candidates=64)
    stats = planner.candidate_statistics
    p = np.array([0.4, 0.3, 0.2, 0.1])
    planned = planner.plan(default_prior(model), np.random.default_rng(0), p)
    assert planned.policy == "discriminative"
    scores = planner.object_information(p)
    assert planned.object_information == pytest.approx(scores.max())
    np.testing.assert_array_equal(planned.action, stats.actions[int(np.argmax(scores))])
    assert planner.candidate_statistics is stats  # computed once
    # The brute-force information of the chosen action is at least that of random candidates.
    mean, variance = object_predictives(model, stats)
    best = _brute_force_information(
        p, mean[np.argmax(scores)], variance[np.argmax(scores)], 50_000, 3
    )
    others = [
        _brute_force_information(p, mean[c], variance[c], 50_000, 3)
        for c in np.random.default_rng(5).choice(64, 8, replace=False)
    ]
    assert best >= max(others) - 0.02
    # Deterministic: the same planner and probabilities give the same action.
    again = planner.plan(default_prior(model), np.random.default_rng(9), p)
    np.testing.assert_array_equal(again.action, planned.action)


def test_the_session_hands_the_object_probabilities_to_the_planner() -> None:
    model = shared_design_model()
    seen: list[np.ndarray | None] = []

    class Recording(Planner):
        def plan(self, belief, rng, probabilities=None):  # type: ignore[no-untyped-def]
            seen.append(None if probabilities is None else probabilities.copy())
            return super().plan(belief, rng, probabilities)

    session = RecognitionSession(model, Recording(model, DiscriminativePolicy(), n_candidates=32))
    rng = np.random.default_rng(0)
    first = session.suggest(rng)
    y = predict(model, model.latents[2:3], first.action[None])[0][0]
    session.observe(first.action, y)
    session.suggest(rng)
    assert seen[0] is not None
    np.testing.assert_allclose(seen[0], np.full(4, 0.25))
    assert seen[1] is not None
    np.testing.assert_allclose(seen[1], session.probabilities)
    assert int(np.argmax(seen[1])) == 2


def test_policies_are_made_in_one_place() -> None:
    assert set(POLICY_NAMES) == {"active", "discriminative", "passive", "fixed"}
    assert isinstance(make_policy("active"), ActivePolicy)
    assert isinstance(make_policy("discriminative"), DiscriminativePolicy)
    assert isinstance(make_policy("passive"), PassivePolicy)
    fixed = make_policy("fixed", np.array([0.5, 1.0]))
    assert isinstance(fixed, FixedPolicy)
    with pytest.raises(InvalidInputError, match="action to repeat"):
        make_policy("fixed")
    with pytest.raises(InvalidInputError, match="discriminative"):
        make_policy("greedy")
    with pytest.raises(InvalidInputError, match="n_draws"):
        DiscriminativePolicy(n_draws=1)
