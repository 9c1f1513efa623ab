"""Recognition: object posterior, the step-wise session, stopping rules, Experiment 1.

The Experiment-1 model is conditioned (not fitted) on the paper's data with the latents set to the
normalised true θ and hyperparameters near their maximum-likelihood values for those latents, so
these tests do not depend on the manifold fitting.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.stats

from core.errors import InvalidInputError
from core.evaluation.trial_engine import PlannedTouches, WorldTouches, iter_trial
from core.evaluation.worlds import EXPERIMENT1_THETAS, Experiment1World, sample_experiment1
from core.gp.posterior import condition, predict
from core.recognition.moments import action_statistics, predictive_moments, update_belief
from core.recognition.object_mixture import ObjectMixture
from core.recognition.object_posterior import normalise_log_probabilities, object_posterior
from core.recognition.planning import ActivePolicy, FixedPolicy, PassivePolicy, Planner
from core.recognition.session import (
    OBJECT_COMPONENT_VARIANCE,
    DisagreementRule,
    RecognitionFinishedError,
    RecognitionSession,
    RecognitionSettings,
    default_prior,
)
from core.types import GaussianBelief, Hyperparameters, ManifoldModel

WORLD = Experiment1World(noise_std=0.1)


@pytest.fixture(scope="module")
def model() -> ManifoldModel:
    data = sample_experiment1(np.random.default_rng(0), noise_std=0.1)
    theta = np.array(EXPERIMENT1_THETAS)[:, None]
    centred = theta - theta.mean()
    latents = centred / np.sqrt(np.mean(centred**2))
    hyper = Hyperparameters(
        signal_variance=np.array([0.18, 0.18, 0.2]),
        noise_variance=np.full(3, 0.01),
        latent_lengthscales=np.array([[1.9], [1.9], [7.0]]),
        action_lengthscales=np.array([[0.85], [0.9], [0.85]]),
    )
    return condition(data, latents, hyper)


@pytest.fixture(scope="module")
def active(model: ManifoldModel) -> Planner:
    return Planner(model, ActivePolicy(), n_candidates=64)


def _touches(obj: int, n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    actions = rng.standard_normal((n, 1))
    return actions, WORLD.observe(obj, actions, rng)


def test_independent_object_posterior_is_the_normalised_gp_product(model: ManifoldModel) -> None:
    actions, observations = _touches(2, 4, seed=1)
    log_weights = np.zeros(4)
    for obj in range(4):
        latents = np.tile(model.latents[obj], (4, 1))
        mean, variance = predict(model, latents, actions)
        log_weights[obj] = scipy.stats.norm.logpdf(observations, mean, np.sqrt(variance)).sum()
    expected = np.exp(log_weights - scipy.special.logsumexp(log_weights))
    probabilities = object_posterior(model, actions, observations, "independent")
    np.testing.assert_allclose(probabilities, expected, rtol=1e-10, atol=1e-300)
    assert probabilities.sum() == pytest.approx(1.0, abs=1e-12)
    assert int(np.argmax(probabilities)) == 2
    uniform = object_posterior(model, np.empty((0, 1)), np.empty((0, 3)))
    np.testing.assert_allclose(uniform, 0.25, rtol=1e-15)


@pytest.mark.parametrize("obj", range(4))
def test_each_experiment1_object_is_recognised_within_ten_active_touches(
    model: ManifoldModel, active: Planner, obj: int
) -> None:
    settings = RecognitionSettings(max_steps=10, tolerance=0.0)
    for trial in range(3):
        rng = np.random.default_rng(100 * obj + trial)
        session = RecognitionSession(model, active, default_prior(model, variance=5.0), settings)
        touches = PlannedTouches(WorldTouches(WORLD, WORLD.object_names[obj]))
        steps = [s.step for s in iter_trial(session, touches, rng, rng)]
        assert len(steps) == 10
        assert steps[-1].done
        assert steps[-1].stop_reason == "max_steps"
        assert steps[-1].answer == obj
        assert steps[-1].nearest_object == obj  # the paper's rule agrees
        assert steps[-1].probabilities[obj] > 0.99


def test_session_matches_the_update_and_the_posterior_of_its_touches(
    model: ManifoldModel, active: Planner
) -> None:
    session = RecognitionSession(model, active, default_prior(model), RecognitionSettings())
    actions, observations = _touches(1, 3, seed=5)
    belief = session.belief
    for action, observation in zip(actions, observations, strict=True):
        moments = predictive_moments(model, belief, action_statistics(model, action[None, :]))
        belief = update_belief(belief, moments, 0, observation)
        step = session.observe(action, observation)  # observed without asking first
        np.testing.assert_allclose(step.belief.mean, belief.mean, rtol=1e-12)
        np.testing.assert_allclose(step.belief.cov, belief.cov, rtol=1e-12)
    np.testing.assert_allclose(
        session.probabilities, object_posterior(model, actions, observations), rtol=1e-10
    )
    assert [s.step for s in session.steps] == [1, 2, 3]


def test_caller_may_perform_a_different_action_than_suggested(
    model: ManifoldModel, active: Planner
) -> None:
    session = RecognitionSession(model, active, None, RecognitionSettings(tolerance=0.0))
    suggestion = session.suggest(np.random.default_rng(0))
    performed = suggestion.action + 0.25
    y = WORLD.observe(0, performed[None, :], np.random.default_rng(1))[0]
    step = session.observe(performed, y)
    np.testing.assert_array_equal(step.action, performed)
    prior = default_prior(model)
    moments = predictive_moments(model, prior, action_statistics(model, performed[None, :]))
    np.testing.assert_allclose(step.belief.mean, update_belief(prior, moments, 0, y).mean)


def test_stops_after_max_steps_and_refuses_more(model: ManifoldModel) -> None:
    planner = Planner(model, PassivePolicy())
    session = RecognitionSession(model, planner, None, RecognitionSettings(3, tolerance=0.0))
    rng = np.random.default_rng(2)
    for _ in range(3):
        action = session.suggest(rng).action
        step = session.observe(action, WORLD.observe(3, action[None, :], rng)[0])
    assert step.done
    assert step.stop_reason == "max_steps"
    assert step.step == 3
    with pytest.raises(RecognitionFinishedError, match="step 3"):
        session.suggest(rng)
    with pytest.raises(RecognitionFinishedError):
        session.observe(np.zeros(1), np.zeros(3))


def test_stops_when_confident(model: ManifoldModel, active: Planner) -> None:
    settings = RecognitionSettings(max_steps=10, tolerance=0.0, confidence_threshold=0.999)
    rng = np.random.default_rng(3)
    session = RecognitionSession(model, active, None, settings)
    touches = PlannedTouches(WorldTouches(WORLD, WORLD.object_names[0]))
    steps = [s.step for s in iter_trial(session, touches, rng, rng)]
    assert steps[-1].stop_reason == "confident"
    assert steps[-1].probabilities.max() >= 0.999
    assert all(s.probabilities.max() < 0.999 for s in steps[:-1])
    assert steps[-1].answer == 0


def test_stops_when_the_mean_stops_moving(model: ManifoldModel) -> None:
    planner = Planner(model, FixedPolicy(np.array([0.1])))
    settings = RecognitionSettings(max_steps=10, tolerance=1e3, on_disagreement="ignore")
    session = RecognitionSession(model, planner, None, settings)
    step = session.observe(np.array([0.1]), np.array([0.5, 0.5, 0.5]))
    assert step.done
    assert step.stop_reason == "converged"
    assert step.mean_shift < 1e3


def _locked_session(model: ManifoldModel, rule: DisagreementRule) -> RecognitionSession:
    """A confident Gaussian at object 0 while object 3 is touched (the known failure mode)."""
    wrong = GaussianBelief(mean=model.latents[0], cov=np.array([[1e-4]]))
    planner = Planner(model, ActivePolicy(), n_candidates=64)
    settings = RecognitionSettings(
        max_steps=6, tolerance=0.0, on_disagreement=rule, plan_under="gaussian"
    )
    return RecognitionSession(model, planner, wrong, settings)


def test_a_gaussian_locked_on_the_wrong_object_is_recentred(model: ManifoldModel) -> None:
    session = _locked_session(model, "recentre")
    rng = np.random.default_rng(4)
    while not session.done:
        action = session.suggest(rng).action
        step = session.observe(action, WORLD.observe(3, action[None, :], rng)[0])
        if step.recentred:
            np.testing.assert_allclose(step.belief.mean, step.probabilities @ model.latents)
    assert any(s.recentred for s in session.steps)
    assert step.answer == 3
    assert step.nearest_object == 3  # the Gaussian itself has moved to the right object


def test_a_gaussian_locked_on_the_wrong_object_is_replanned_around(model: ManifoldModel) -> None:
    session = _locked_session(model, "replan")
    rng = np.random.default_rng(4)
    replanned = False
    while not session.done:
        if session.disagrees():
            planning = session.planning_belief()
            assert planning.mean[0] != session.belief.mean[0]
            assert planning.cov[0, 0] > session.belief.cov[0, 0]
            replanned = True
        action = session.suggest(rng).action
        step = session.observe(action, WORLD.observe(3, action[None, :], rng)[0])
        assert not step.recentred
    assert replanned
    assert step.answer == 3
    ignoring = _locked_session(model, "ignore")
    ignoring.observe(np.array([1.0]), WORLD.observe(3, np.array([[1.0]]), rng)[0])
    assert ignoring.disagrees()
    assert ignoring.planning_belief() is ignoring.belief


def test_default_prior_is_centred_on_the_latents(model: ManifoldModel) -> None:
    prior = default_prior(model, variance=5.0)
    np.testing.assert_allclose(prior.mean, model.latents.mean(axis=0))
    np.testing.assert_array_equal(prior.cov, 5.0 * np.eye(1))


def test_the_objects_prior_has_the_moments_of_the_uniform_mixture(model: ManifoldModel) -> None:
    # Monte Carlo of (1/L) Σ_l N(s_l, c I): pick an object uniformly, then draw around it.
    prior = default_prior(model)
    rng = np.random.default_rng(0)
    n = 400_000
    picks = rng.integers(model.latents.shape[0], size=n)
    draws = model.latents[picks] + np.sqrt(OBJECT_COMPONENT_VARIANCE) * rng.standard_normal(
        (n, model.latent_dim)
    )
    np.testing.assert_allclose(prior.mean, draws.mean(axis=0), atol=5e-3)
    np.testing.assert_allclose(prior.cov, np.cov(draws.T).reshape(prior.cov.shape), rtol=1e-2)
    # Narrower than the paper's Σ0 = 5 I: the objects lie about 1 from their centre.
    assert np.all(np.linalg.eigvalsh(prior.cov) < 5.0)


def test_bad_input_is_rejected_with_the_argument_named(
    model: ManifoldModel, active: Planner
) -> None:
    session = RecognitionSession(model, active, None, None)
    with pytest.raises(InvalidInputError, match="action"):
        session.observe(np.array([np.nan]), np.zeros(3))
    with pytest.raises(InvalidInputError, match="action"):
        session.observe(np.zeros(2), np.zeros(3))
    with pytest.raises(InvalidInputError, match="observation"):
        session.observe(np.zeros(1), np.zeros(2))
    with pytest.raises(InvalidInputError, match="observation"):
        session.observe(np.zeros(1), np.array([0.0, np.nan, 0.0]))
    assert session.steps == ()
    with pytest.raises(InvalidInputError, match="max_steps"):
        RecognitionSettings(max_steps=0)
    with pytest.raises(InvalidInputError, match="tolerance"):
        RecognitionSettings(tolerance=-1.0)
    with pytest.raises(InvalidInputError, match="confidence_threshold"):
        RecognitionSettings(confidence_threshold=1.5)
    with pytest.raises(InvalidInputError, match="decision"):
        RecognitionSettings(decision="vote")  # type: ignore[arg-type]
    with pytest.raises(InvalidInputError, match="variance"):
        default_prior(model, variance=0.0)
    with pytest.raises(InvalidInputError, match="prior"):
        RecognitionSession(model, active, GaussianBelief(np.zeros(2), np.eye(2)), None)
    other = condition(model.data, model.latents + 0.1, model.hyperparameters)
    with pytest.raises(InvalidInputError, match="planner"):
        RecognitionSession(other, active, None, None)
    with pytest.raises(InvalidInputError, match="observations"):
        object_posterior(model, np.zeros((2, 1)), np.zeros((3, 3)))


@pytest.mark.parametrize("scale", [1.0, 1e4, 1e7, 1e12])
def test_probabilities_sum_to_one_at_any_magnitude_of_the_log_weights(scale: float) -> None:
    """A trial far outside every object's predictive has log-likelihoods of -10⁷ and below;
    its probabilities must still sum to 1 (an object mixture refuses more than 10⁻⁹ off) and
    keep the ratios exp(w_i - w_j)."""
    rng = np.random.default_rng(int(np.log10(scale)))
    offsets = np.array([0.0, -0.5, -3.0, -40.0, -800.0])
    log_weights = -scale * (1.0 + rng.random()) + offsets
    p = normalise_log_probabilities(log_weights)
    assert abs(p.sum() - 1.0) <= 4 * np.finfo(float).eps
    assert p[1] / p[0] == pytest.approx(np.exp(-0.5), rel=1e-6 if scale > 1e10 else 1e-9)
    assert p[4] == 0.0
    ObjectMixture(np.zeros((5, 1)), p, np.eye(1))
