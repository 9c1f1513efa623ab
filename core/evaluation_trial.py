"""One evaluation trial: a policy recognises a target whose touches come from a world or a replay.

The policies an evaluation may name are resolved here, in :data:`POLICIES`, and nowhere else: a
new policy is one entry (how to build its planner policy, and how it picks among recorded touches
in a replay).

Observations come from an ``Observe`` function (action (dx,), the trial's world generator) →
observation (dy,): :func:`world_observer` for a synthetic world, :func:`model_observer` for the
learned GP's predictive distribution (the paper's Experiment 2 protocol), or any other source
(the simulated rig, composed in ``app``). A replay trial (:func:`run_replay_trial`) instead picks
among the target's recorded held-out touches without replacement (METHOD.md, "Evaluation
protocols").
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from core.errors import InvalidInputError, TouchRefused
from core.evaluation_records import RefusedTrial, TrialRecord, trial_generators
from core.moments import action_statistics
from core.object_information import label_information_mc, object_predictives
from core.planning import ActivePolicy, DiscriminativePolicy, PassivePolicy, Planner, Policy
from core.posterior import predict_model_space
from core.recognition import (
    RecognitionSession,
    RecognitionSettings,
    RecognitionStep,
    default_prior,
    iter_recognize,
)
from core.types import GaussianBelief, ManifoldModel, TrainingData
from core.validation import FloatArray, as_float_array
from core.worlds import World

#: Observation source of a trial: (action (dx,), the trial's world generator) → observation (dy,).
#: It raises :class:`core.errors.TouchRefused` when the world refuses that one action (the trial
#: ends as a :class:`core.evaluation_records.RefusedTrial`); anything else it raises propagates.
Observe = Callable[[FloatArray, np.random.Generator], FloatArray]

#: How a policy scores the unused recorded actions (C, dx) of a replay, given the planning belief
#: and the current object posterior (L,); the largest score is touched next. Shape (C,).
ReplayScore = Callable[[Planner, GaussianBelief, FloatArray, FloatArray], FloatArray]


def information_score(
    planner: Planner, belief: GaussianBelief, probabilities: FloatArray, actions: FloatArray
) -> FloatArray:
    """U1 of each recorded action under the belief (METHOD.md (M4)); the posterior is unused."""
    return planner.mutual_information(belief, actions)


def label_information_score(
    planner: Planner, belief: GaussianBelief, probabilities: FloatArray, actions: FloatArray
) -> FloatArray:
    """Estimated I(l; y | x) of each recorded action under the object posterior.

    The discriminative policy's score (:mod:`core.object_information`), evaluated at the
    recorded actions instead of the planner's candidates, with fixed standard-normal draws
    seeded by the planner's candidate seed (common random numbers: deterministic).
    """
    policy = planner.policy
    n_draws = policy.n_draws if isinstance(policy, DiscriminativePolicy) else 128
    mean, variance = object_predictives(planner.model, action_statistics(planner.model, actions))
    draws = np.random.default_rng(planner.candidate_seed).standard_normal(
        (n_draws, planner.model.hyperparameters.observation_dim)
    )
    return label_information_mc(probabilities, mean, variance, draws)


@dataclass(frozen=True)
class PolicyEntry:
    """How an evaluation runs a policy.

    Attributes:
        make: Builds the planner's policy.
        replay_score: Scores unused recorded touches in a replay (largest first); ``None``
            picks one at random (from the trial's policy generator).
    """

    make: Callable[[], Policy]
    replay_score: ReplayScore | None


#: The policies an evaluation may name. Add a policy here, in one line.
POLICIES: dict[str, PolicyEntry] = {
    "active": PolicyEntry(ActivePolicy, information_score),
    "discriminative": PolicyEntry(DiscriminativePolicy, label_information_score),
    "passive": PolicyEntry(PassivePolicy, None),
}


def policy_entry(name: str) -> PolicyEntry:
    """The entry of a policy name.

    Raises:
        InvalidInputError: Unknown name (the message lists the allowed ones).
    """
    try:
        return POLICIES[name]
    except KeyError:
        raise InvalidInputError(
            f"policy: {name!r} is not a policy; choose from {sorted(POLICIES)}."
        ) from None


@dataclass(frozen=True)
class TrialSettings:
    """Stop rule and prior of every trial of an evaluation.

    Attributes:
        steps: T, the largest number of touches.
        tolerance: Stop when the Gaussian mean moves less (normalised latent units; 0 disables).
        stop_confidence: Stop when the object posterior's largest probability reaches it
            (``None``: never).
        prior_variance: Σ0 = prior_variance · I around the mean of the learned latents.
    """

    steps: int
    tolerance: float = 1e-3
    stop_confidence: float | None = None
    prior_variance: float = 5.0

    def recognition(self, steps: int | None = None) -> RecognitionSettings:
        """The recognition settings (``steps`` overrides T, e.g. capped by a replay pool)."""
        return RecognitionSettings(
            max_steps=self.steps if steps is None else steps,
            tolerance=self.tolerance,
            confidence_threshold=self.stop_confidence,
        )

    def prior(self, model: ManifoldModel) -> GaussianBelief:
        """The initial belief of a trial."""
        return default_prior(model, self.prior_variance)


def world_observer(world: World, target: str) -> Observe:
    """Observations of object ``target`` (by name) of a synthetic world: h(θ, x) + noise.

    Raises:
        InvalidInputError: ``target`` is not an object of the world.
    """
    if target not in world.object_names:
        raise InvalidInputError(
            f"target: {target!r} is not an object of the world {list(world.object_names)}."
        )
    index = world.object_names.index(target)

    def observe(action: FloatArray, rng: np.random.Generator) -> FloatArray:
        return np.asarray(world.observe(index, action[None, :], rng)[0], dtype=np.float64)

    return observe


def model_observer(model: ManifoldModel, target: str) -> Observe:
    """Draws from the learned GP's predictive distribution at the target's latent.

    y' ~ N(m(s_k, x), diag v(s_k, x)), the predictive mean and variance (noise included) of
    :func:`core.posterior.predict_model_space`, mapped to raw units by the model's observation
    transform (if any) — the paper's Experiment 2 protocol.

    Raises:
        InvalidInputError: ``target`` is not an object of the model.
    """
    if target not in model.object_names:
        raise InvalidInputError(
            f"target: {target!r} is not an object of the model {list(model.object_names)}."
        )
    latent = model.latents[model.object_names.index(target)][None, :]

    def observe(action: FloatArray, rng: np.random.Generator) -> FloatArray:
        # Drawn where the GPs' features are independent (the model space y' of a noise model)
        # and mapped to raw units: with correlated noise the raw predictive is not diagonal.
        mean, variance = predict_model_space(model, latent, action[None, :])
        noise = rng.standard_normal(mean.shape[1])
        draw = mean + np.sqrt(variance) * noise
        if model.transform is not None:
            draw = model.transform.restore_mean(draw)
        return np.asarray(draw[0], dtype=np.float64)

    return observe


def _record(
    model: ManifoldModel,
    policy: str,
    target: str,
    trial: int,
    seed: tuple[int, ...],
    steps: Sequence[RecognitionStep],
) -> TrialRecord:
    names = model.object_names
    answers = tuple(names[s.answer] for s in steps)
    return TrialRecord(
        policy=policy,
        target=target,
        trial=trial,
        seed=tuple(seed),
        answers=answers,
        probabilities=tuple(tuple(float(p) for p in s.probabilities) for s in steps),
        actions=tuple(tuple(float(v) for v in s.action) for s in steps),
        mutual_information=tuple(float(s.mutual_information) for s in steps),
        touches=len(steps),
        stop_reason=str(steps[-1].stop_reason),
        correct=answers[-1] == target,
        nearest=tuple(names[s.nearest_object] for s in steps),
    )


def run_trial(
    model: ManifoldModel,
    planner: Planner,
    *,
    policy: str,
    target: str,
    trial: int,
    seed: tuple[int, ...],
    observe: Observe,
    settings: TrialSettings,
) -> TrialRecord | RefusedTrial:
    """One trial: the planner chooses each action, ``observe`` answers it.

    Args:
        model: A conditioned model.
        planner: A planner for ``model`` under ``policy``.
        policy: The policy's name (recorded).
        target: The object touched (a model object).
        trial: Index of the trial within its (policy, target) cell (recorded).
        seed: The trial's seed tuple (:func:`core.evaluation_records.trial_seed`); the
            planner's and the world's generators are spawned from it.
        observe: The observation source.
        settings: Stop rule and prior.

    Returns:
        The trial's record, or a :class:`RefusedTrial` (with the touches performed before it)
        when ``observe`` refused a touch (:class:`core.errors.TouchRefused`).
    """
    if target not in model.object_names:
        raise InvalidInputError(
            f"target: {target!r} is not an object of the model {list(model.object_names)}."
        )
    policy_rng, world_rng = trial_generators(seed)
    asked: list[FloatArray] = []

    def observe_action(action: FloatArray) -> FloatArray:
        asked[:] = [action]
        return observe(action, world_rng)

    steps: list[RecognitionStep] = []
    try:
        for step in iter_recognize(
            model,
            observe_action,
            planner,
            settings.prior(model),
            settings.recognition(),
            policy_rng,
        ):
            steps.append(step)
    except TouchRefused as refusal:
        names = model.object_names
        return RefusedTrial(
            policy=policy,
            target=target,
            trial=trial,
            seed=tuple(seed),
            touch=len(steps) + 1,
            action=tuple(float(v) for v in asked[0]),
            error=refusal.error,
            reason=refusal.reason,
            answers=tuple(names[s.answer] for s in steps),
            probabilities=tuple(tuple(float(p) for p in s.probabilities) for s in steps),
            actions=tuple(tuple(float(v) for v in s.action) for s in steps),
            mutual_information=tuple(float(s.mutual_information) for s in steps),
        )
    return _record(model, policy, target, trial, seed, steps)


@dataclass(frozen=True)
class ReplayPool:
    """The recorded held-out touches of one object.

    Attributes:
        actions: Shape (n, dx).
        observations: Shape (n, dy).
    """

    actions: FloatArray
    observations: FloatArray

    def __post_init__(self) -> None:
        actions = as_float_array(self.actions, "replay actions", (None, None))
        as_float_array(self.observations, "replay observations", (actions.shape[0], None))

    @property
    def size(self) -> int:
        """n, the number of recorded touches."""
        return int(self.actions.shape[0])


def replay_pools(data: TrainingData) -> dict[str, ReplayPool]:
    """The pool of every object of a held-out data set, by name."""
    return {
        name: ReplayPool(
            actions=data.actions[data.object_index == k],
            observations=data.observations[data.object_index == k],
        )
        for k, name in enumerate(data.object_names)
    }


def run_replay_trial(
    model: ManifoldModel,
    planner: Planner,
    *,
    policy: str,
    target: str,
    trial: int,
    seed: tuple[int, ...],
    pool: ReplayPool,
    settings: TrialSettings,
    steps: int | None = None,
) -> TrialRecord:
    """One replay trial: each touch is an unused recorded touch of the target.

    The policy's :attr:`PolicyEntry.replay_score` picks the unused touch with the largest score
    under the planning belief (active: the largest mutual information), or a random unused one
    when it has none (passive); the observation is that touch's recorded y.

    Args:
        steps: Touches at most (≤ the pool size); ``settings.steps`` when ``None``.

    Raises:
        InvalidInputError: Unknown policy, a target not in the model, a pool of the wrong
            dimensions, or more steps than recorded touches.
    """
    entry = policy_entry(policy)
    if target not in model.object_names:
        raise InvalidInputError(
            f"target: {target!r} is not an object of the model {list(model.object_names)}."
        )
    h = model.hyperparameters
    if (pool.actions.shape[1], pool.observations.shape[1]) != (h.action_dim, h.observation_dim):
        raise InvalidInputError(
            f"replay pool of {target!r}: has dx={pool.actions.shape[1]}, "
            f"dy={pool.observations.shape[1]}; the model has dx={h.action_dim}, "
            f"dy={h.observation_dim}."
        )
    limit = settings.steps if steps is None else steps
    if limit > pool.size:
        raise InvalidInputError(
            f"steps: {limit} touches asked but {target!r} has only {pool.size} recorded touches."
        )
    policy_rng, _ = trial_generators(seed)
    session = RecognitionSession(model, planner, settings.prior(model), settings.recognition(limit))
    unused = list(range(pool.size))
    while not session.done:
        belief = session.planning_belief()
        candidates = pool.actions[unused]
        if entry.replay_score is None:
            chosen = int(policy_rng.integers(len(unused)))
        else:
            scores = entry.replay_score(planner, belief, session.probabilities, candidates)
            chosen = int(np.argmax(scores))
        index = unused.pop(chosen)
        session.observe(pool.actions[index], pool.observations[index])
    return _record(model, policy, target, trial, seed, session.steps)
