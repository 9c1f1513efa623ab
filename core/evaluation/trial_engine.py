"""The trial engine: the one loop that runs a recognition trial over an observation source.

Every recognition trial — the API's server-driven trials (simulated world or rig), ``activetouch
recognize``, the evaluations (``activetouch evaluate``, ``paper``, the server's jobs) and the
benchmarks — runs :func:`iter_trial`: the :class:`~core.recognition.session.RecognitionSession`
state machine (the step-wise core, which a scripted API trial drives directly, one posted
observation at a time) fed by an observation source, one touch per step. It is a generator, so a
caller records, streams, paces or stops the trial between touches.

An observation source (:class:`ObservationSource`) gives the next touch of a session:

* :class:`PlannedTouches` asks the session's planner for the action and performs it on a
  :class:`TouchSource` — a synthetic world (:class:`WorldTouches`), draws from the learned GP
  (:class:`ModelTrial`, the paper's Experiment 2 protocol with the model's placement effect),
  the simulated or the real rig (composed in ``app``);
* :class:`ReplayTouches` picks among the target's recorded held-out touches without replacement
  (each trial offered its own random half of them, :func:`replay_offer`), by the policy's replay
  score (:data:`core.recognition.planning.POLICIES`; docs/method.md,
  "Evaluation protocols").

:func:`run_trial` runs a trial of an evaluation to its end and returns its outcome, a
:class:`~core.evaluation.records.TrialRecord` (which says why it stopped) or a
:class:`~core.evaluation.records.RefusedTrial` (a touch the world refused).
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple, Protocol

import numpy as np

from core.errors import InvalidInputError, TouchRefused
from core.evaluation.records import RefusedTrial, TrialOutcome, TrialRecord, trial_generators
from core.gp.input_shift import mean_jacobian
from core.gp.posterior import predict_model_space
from core.recognition.object_posterior import TrialLikelihood
from core.recognition.planning import EVALUATION_POLICIES, Planner, ReplayScore, policy_entry
from core.recognition.session import (
    PlanningBelief,
    RecognitionSession,
    RecognitionSettings,
    RecognitionStep,
    default_prior,
)
from core.types import GaussianBelief, ManifoldModel, TrainingData
from core.validation import FloatArray, as_float_array


@dataclass(frozen=True)
class Touch:
    """One touch: the action performed (dx,), the observation (dy,), optional trajectory.

    The action performed may differ from the one asked for (a rig clips it to what it can do).
    """

    action: FloatArray
    observation: FloatArray
    trajectory: dict[str, Any] | None = None


class TouchSource(Protocol):
    """Performs an action on the target object: (action (dx,), the world's generator) → touch.

    It raises :class:`core.errors.TouchRefused` when the world refuses that one action (an
    evaluation trial then ends as a :class:`~core.evaluation.records.RefusedTrial`); anything
    else it raises propagates.
    """

    def touch(self, action: FloatArray, rng: np.random.Generator) -> Touch:
        """Perform ``action`` (dx,) and return the touch."""
        ...


class ObservationSource(Protocol):
    """Gives the next touch of a running session."""

    def next_touch(
        self,
        session: RecognitionSession,
        policy_rng: np.random.Generator,
        world_rng: np.random.Generator,
    ) -> Touch:
        """The next touch (its action chosen with ``policy_rng``, observed with ``world_rng``)."""
        ...


class EngineStep(NamedTuple):
    """One step of :func:`iter_trial`: the session's step and the touch it was given."""

    step: RecognitionStep
    touch: Touch


@dataclass
class PlannedTouches:
    """The session's planner chooses each action; ``source`` performs it.

    Attributes:
        source: Where the touches happen.
        asked: The last action asked of ``source`` (the refused one, after a refusal).
    """

    source: TouchSource
    asked: FloatArray | None = None

    def next_touch(
        self,
        session: RecognitionSession,
        policy_rng: np.random.Generator,
        world_rng: np.random.Generator,
    ) -> Touch:
        """Plan with ``policy_rng``, then touch with ``world_rng``."""
        planned = session.suggest(policy_rng)
        self.asked = planned.action
        return self.source.touch(planned.action, world_rng)


def iter_trial(
    session: RecognitionSession,
    source: ObservationSource,
    policy_rng: np.random.Generator,
    world_rng: np.random.Generator,
) -> Iterator[EngineStep]:
    """Run a trial: touch, update, decide, until the session stops; stop iterating to cancel.

    Args:
        session: A session that has not stopped (it may already hold touches).
        source: Gives each touch.
        policy_rng: The planner's (and a replay's choice's) randomness.
        world_rng: The observation noise's randomness; may be ``policy_rng`` itself (one
            stream for both, as the API's simulated trials and ``activetouch recognize`` use).

    Yields:
        One :class:`EngineStep` per touch; the last one's step has ``done`` set. Whatever the
        source raises propagates (the steps before it have been yielded).
    """
    while not session.done:
        touch = source.next_touch(session, policy_rng, world_rng)
        yield EngineStep(session.observe(touch.action, touch.observation), touch)


# --- observation sources ----------------------------------------------------------------------


class Observed(Protocol):
    """What :class:`WorldTouches` touches: named objects, each answering an action with an
    observation (a synthetic :class:`~core.evaluation.worlds.World`, or :class:`ModelSamples`)."""

    @property
    def object_names(self) -> tuple[str, ...]:
        """The objects, by index."""
        ...

    def observe(
        self, object_index: int, actions: FloatArray, rng: np.random.Generator
    ) -> FloatArray:
        """Observations (n, dy) of object ``object_index`` at ``actions`` (n, dx)."""
        ...


@dataclass(frozen=True)
class WorldTouches:
    """Touches of object ``target`` (by name) of a world: h(θ, x) + noise of a synthetic world,
    or draws from the learned GP (:class:`ModelSamples`).

    Raises:
        InvalidInputError: ``target`` is not an object of the world.
    """

    world: Observed
    target: str

    def __post_init__(self) -> None:
        _check_target(self.world.object_names, self.target, "world")

    def touch(self, action: FloatArray, rng: np.random.Generator) -> Touch:
        """y = h(target, x) + noise."""
        index = self.world.object_names.index(self.target)
        observation = self.world.observe(index, action[None, :], rng)[0]
        return Touch(
            action=np.asarray(action, dtype=np.float64),
            observation=np.asarray(observation, dtype=np.float64),
        )

    def close(self) -> None:
        """Nothing to release."""


@dataclass(frozen=True)
class ModelSamples:
    """The learned GP as the world touched: draws from its predictive distribution at each
    object's latent — the paper's Experiment 2 protocol.

    y' ~ N(m(s_l, x), diag v(s_l, x)), the predictive mean and variance (noise included) of
    :func:`core.gp.posterior.predict_model_space`, mapped to raw units by the model's observation
    transform (if any). Each draw is independent; :class:`ModelTrial` draws a trial's touches
    with the model's placement effect.
    """

    model: ManifoldModel

    @property
    def object_names(self) -> tuple[str, ...]:
        """The model's objects."""
        return self.model.object_names

    def observe(
        self,
        object_index: int,
        actions: FloatArray,
        rng: np.random.Generator,
        offset: FloatArray | None = None,
        offset_variance: FloatArray | None = None,
    ) -> FloatArray:
        """One draw at each of ``actions`` (n, dx) for object ``object_index``. Shape (n, dy).

        ``offset``: an offset (dy,) in model space shared by these draws (a placement's b, the
        drift's d, or both); its variance ``offset_variance`` (dy,) (default: the model's
        ``placement_variance``) is then taken out of each draw's noise, so every single draw
        keeps the predictive variance v (docs/calibration.md (C1)).
        """
        model = self.model
        latents = np.repeat(model.latents[object_index][None, :], actions.shape[0], axis=0)
        # Drawn where the GPs' features are independent (the model space y' of a noise model)
        # and mapped to raw units: with correlated noise the raw predictive is not diagonal.
        mean, variance = predict_model_space(model, latents, actions)
        if offset is not None:
            if offset_variance is None:
                offset_variance = model.placement_variance
            if offset_variance is None:
                raise InvalidInputError(
                    "offset: a placement offset needs a model with a placement variance."
                )
            mean, variance = mean + offset, variance - offset_variance
        draw = mean + np.sqrt(variance) * rng.standard_normal(mean.shape)
        if model.transform is not None:
            draw = model.transform.restore_mean(draw)
        return np.asarray(draw, dtype=np.float64)


class ModelTrial:
    """One trial's touches of the learned GP (the evaluation world ``model``), drawn as the
    recogniser models a rig trial.

    Per model-space feature a, y'_ta = f_a(s_l, x_t) + b_a + ε_ta with one offset
    b_a ~ N(0, σ_b,a²) per placement and ε_ta of variance v_a − σ_b,a² (docs/calibration.md
    (C1); σ_b² the model's ``placement_variance``, or the target's own row of
    ``object_placement_variance``). With ``shared_placement`` the trial places its
    object once (the offset is drawn at the first touch and kept), otherwise anew before every
    touch. A model with a drift variance σ_d² also draws one drift offset d ~ N(0, σ_d²) at the
    first touch and keeps it for the trial (:mod:`core.gp.drift_effect`). A model with a shift
    variance σ_δ² draws one shift of the action δ ~ N(0, diag(σ_δ²)) per placement and adds
    J(x_t) δ, the slope of the mean times the shift (:mod:`core.gp.input_shift`). A model with
    none of them draws exactly as ``WorldTouches(ModelSamples(model), target)``.

    Raises:
        InvalidInputError: ``target`` is not an object of the model.
    """

    def __init__(self, model: ManifoldModel, target: str, shared_placement: bool = True) -> None:
        _check_target(model.object_names, target, "model")
        self.samples = ModelSamples(model)
        self.index = model.object_names.index(target)
        self.shared_placement = shared_placement
        self.offset: FloatArray | None = None
        self.drift: FloatArray | None = None
        self.shift: FloatArray | None = None

    def touch(self, action: FloatArray, rng: np.random.Generator) -> Touch:
        """A draw at ``action`` (dx,) for the target."""
        model = self.samples.model
        variance = model.placement_variance
        if model.object_placement_variance is not None:
            variance = model.object_placement_variance[self.index]
        if variance is not None and (self.offset is None or not self.shared_placement):
            self.offset = np.sqrt(variance) * rng.standard_normal(variance.shape)
        drift = model.drift_variance
        if drift is not None and self.drift is None:  # once per trial, whatever the placement
            self.drift = np.sqrt(drift) * rng.standard_normal(drift.shape)
        shift = model.shift_variance
        if shift is not None and (self.shift is None or not self.shared_placement):
            self.shift = np.sqrt(shift) * rng.standard_normal(shift.shape)
        elif self.shift is not None and model.shift_creep_variance is not None:
            # A later touch of the placement: the shift has crept since the last one.
            creep = model.shift_creep_variance
            self.shift = self.shift + np.sqrt(creep) * rng.standard_normal(creep.shape)
        parts = [
            (part, part_variance)
            for part, part_variance in ((self.offset, variance), (self.drift, drift))
            if part is not None and part_variance is not None
        ]
        if self.shift is not None:
            # The action shifted by δ, linearised through the slope of the mean: J δ on top of
            # the draw's own variance (core.gp.input_shift).
            latent = model.latents[self.index][None, :]
            slope = mean_jacobian(model, latent, action[None, :])[0]  # (dy, dx)
            parts.append((slope @ self.shift, np.zeros(slope.shape[0])))
        if not parts:
            observation = self.samples.observe(self.index, action[None, :], rng)[0]
        else:
            offset = np.sum([part for part, _ in parts], axis=0)
            offset_variance = np.sum([part_variance for _, part_variance in parts], axis=0)
            observation = self.samples.observe(
                self.index, action[None, :], rng, offset, offset_variance
            )[0]
        return Touch(
            action=np.asarray(action, dtype=np.float64),
            observation=np.asarray(observation, dtype=np.float64),
        )

    def close(self) -> None:
        """Nothing to release."""


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


def replay_offer(pool_size: int, steps: int, rng: np.random.Generator) -> list[int]:
    """The recorded touches a replay trial may choose from: a random subset of the pool.

    Without it a planner, which scores the pool deterministically, would take the same touches
    in every trial of an object, and an evaluation's "trials" would be copies of one sequence
    (their accuracy moves in steps of one object, their intervals count copies as independent
    draws). Offering each trial its own random half of the pool (at least ``steps`` touches)
    makes trials differ as rig trials do; every policy of a trial gets the same offer (it is
    drawn from the trial's world generator), so their comparison is paired. A trial that may use
    the whole pool is offered it whole.

    Args:
        pool_size: n, the recorded touches of the target.
        steps: T, the touches the trial may take (≤ n).
        rng: The trial's world generator.

    Returns:
        Indices into the pool, ascending.
    """
    size = max(steps, -(-pool_size // 2))
    if size >= pool_size:
        return list(range(pool_size))
    return sorted(int(i) for i in rng.choice(pool_size, size=size, replace=False))


class ReplayTouches:
    """Each touch is an unused recorded touch of the target (without replacement), among the
    touches the trial is offered (:func:`replay_offer`).

    ``score`` (a policy's :attr:`core.recognition.planning.PolicyEntry.replay_score`) picks the
    unused touch with the largest score under the session's planning belief (active: the largest
    mutual information), or, when ``None``, a random unused one (passive); the observation is that
    touch's recorded y.

    Args:
        pool: The target's recorded touches.
        score: How the policy scores them; ``None``: at random.
        steps: T, the touches the trial may take (sizes the offer).
    """

    def __init__(self, pool: ReplayPool, score: ReplayScore | None, steps: int) -> None:
        self.pool = pool
        self.score = score
        self.steps = steps
        self.unused: list[int] | None = None

    def next_touch(
        self,
        session: RecognitionSession,
        policy_rng: np.random.Generator,
        world_rng: np.random.Generator,
    ) -> Touch:
        """The chosen recorded touch (``world_rng`` draws the trial's offer at its first touch;
        the noise is recorded).

        Raises:
            InvalidInputError: Every offered touch has been used.
        """
        if self.unused is None:
            self.unused = replay_offer(self.pool.size, self.steps, world_rng)
        if not self.unused:
            raise InvalidInputError(
                f"replay: all {self.pool.size} recorded touches are used; ask fewer steps."
            )
        if self.score is None:
            chosen = int(policy_rng.integers(len(self.unused)))
        else:
            candidates = self.pool.actions[self.unused]
            belief = session.planning_belief()
            scores = self.score(session.planner, belief, session.probabilities, candidates)
            chosen = int(np.argmax(scores))
        index = self.unused.pop(chosen)
        return Touch(action=self.pool.actions[index], observation=self.pool.observations[index])


# --- evaluation trials ------------------------------------------------------------------------


@dataclass(frozen=True)
class TrialSettings:
    """Stop rule and prior of every trial of an evaluation.

    Attributes:
        steps: T, the largest number of touches.
        tolerance: Stop when the Gaussian mean moves less (normalised latent units; 0 disables).
        stop_confidence: Stop when the object posterior's largest probability reaches it
            (``None``: never).
        prior_variance: Σ0 = prior_variance · I around the mean of the learned latents (the
            paper's); ``None``: the objects' prior
            (:func:`core.recognition.session.default_prior`).
        trial_likelihood: How the object posterior scores a trial's touches
            (:class:`core.recognition.session.RecognitionSettings`): ``"joint"`` or
            ``"independent"``.
        shared_placement: Whether a trial's touches meet one placement of the object.
        plan_under: The belief actions are planned under
            (:class:`core.recognition.session.RecognitionSettings`): ``"objects"`` or
            ``"gaussian"`` (the paper's).
    """

    steps: int
    tolerance: float = 1e-3
    stop_confidence: float | None = None
    prior_variance: float | None = None
    trial_likelihood: TrialLikelihood = "joint"
    shared_placement: bool = True
    plan_under: PlanningBelief = "objects"

    def recognition(self, steps: int | None = None) -> RecognitionSettings:
        """The recognition settings (``steps`` overrides T, e.g. capped by a replay pool)."""
        return RecognitionSettings(
            max_steps=self.steps if steps is None else steps,
            tolerance=self.tolerance,
            confidence_threshold=self.stop_confidence,
            trial_likelihood=self.trial_likelihood,
            shared_placement=self.shared_placement,
            plan_under=self.plan_under,
        )

    def prior(self, model: ManifoldModel) -> GaussianBelief:
        """The initial belief of a trial."""
        return default_prior(model, self.prior_variance)


def _check_target(names: Sequence[str], target: str, where: str) -> None:
    """Raise :class:`InvalidInputError` unless ``target`` is one of ``names`` (of the ``where``)."""
    if target not in names:
        raise InvalidInputError(
            f"target: {target!r} is not an object of the {where} {list(names)}."
        )


def _per_touch(model: ManifoldModel, steps: Sequence[RecognitionStep]) -> dict[str, Any]:
    names = model.object_names
    return {
        "answers": tuple(names[s.answer] for s in steps),
        "probabilities": tuple(tuple(float(p) for p in s.probabilities) for s in steps),
        "actions": tuple(tuple(float(v) for v in s.action) for s in steps),
        "mutual_information": tuple(float(s.mutual_information) for s in steps),
    }


def run_trial(
    model: ManifoldModel,
    planner: Planner,
    *,
    policy: str,
    target: str,
    trial: int,
    seed: tuple[int, ...],
    settings: TrialSettings,
    touches: TouchSource | None = None,
    replay: ReplayPool | None = None,
    steps: int | None = None,
) -> TrialOutcome:
    """One evaluation trial, run to its end by :func:`iter_trial`.

    Exactly one of ``touches`` (the planner chooses each action, ``touches`` answers it) and
    ``replay`` (each touch is an unused recorded touch of the target, chosen by the policy's
    replay score) is given.

    Args:
        model: A conditioned model.
        planner: A planner for ``model`` under ``policy``.
        policy: The policy's name (recorded; a replay looks its replay score up by it).
        target: The object touched (a model object).
        trial: Index of the trial within its (policy, target) cell (recorded).
        seed: The trial's seed tuple (:func:`core.evaluation.records.trial_seed`); the
            planner's and the world's generators are spawned from it.
        settings: Stop rule and prior.
        touches: Where the planned touches happen.
        replay: The target's recorded touches.
        steps: Touches at most (≤ the replay pool's size); ``settings.steps`` when ``None``.

    Returns:
        The trial's record (with why it stopped), or a :class:`RefusedTrial` (with the touches
        performed before it) when ``touches`` refused one (:class:`core.errors.TouchRefused`).

    Raises:
        InvalidInputError: Not exactly one source, a target not in the model, an unknown policy
            (replay), a replay pool of the wrong dimensions, or more steps than recorded touches.
    """
    if (touches is None) == (replay is None):
        raise InvalidInputError("run_trial: give exactly one of touches and replay.")
    _check_target(model.object_names, target, "model")
    limit = settings.steps if steps is None else steps
    source: ObservationSource
    planned: PlannedTouches | None = None
    if replay is not None:
        entry = policy_entry(policy, EVALUATION_POLICIES)
        h = model.hyperparameters
        actual = (replay.actions.shape[1], replay.observations.shape[1])
        if actual != (h.action_dim, h.observation_dim):
            raise InvalidInputError(
                f"replay pool of {target!r}: has dx={actual[0]}, dy={actual[1]}; the model has "
                f"dx={h.action_dim}, dy={h.observation_dim}."
            )
        if limit > replay.size:
            raise InvalidInputError(
                f"steps: {limit} touches asked but {target!r} has only {replay.size} recorded "
                "touches."
            )
        source = ReplayTouches(replay, entry.replay_score, limit)
    else:
        assert touches is not None
        source = planned = PlannedTouches(touches)
    policy_rng, world_rng = trial_generators(seed)
    session = RecognitionSession(model, planner, settings.prior(model), settings.recognition(limit))
    done: list[RecognitionStep] = []
    try:
        for step, _ in iter_trial(session, source, policy_rng, world_rng):
            done.append(step)
    except TouchRefused as refusal:
        assert planned is not None
        assert planned.asked is not None
        return RefusedTrial(
            policy=policy,
            target=target,
            trial=trial,
            seed=tuple(seed),
            touch=len(done) + 1,
            action=tuple(float(v) for v in planned.asked),
            error=refusal.error,
            reason=refusal.reason,
            **_per_touch(model, done),
        )
    per_touch = _per_touch(model, done)
    last = done[-1]
    assert last.stop_reason is not None
    return TrialRecord(
        policy=policy,
        target=target,
        trial=trial,
        seed=tuple(seed),
        touches=len(done),
        stop_reason=last.stop_reason,
        correct=per_touch["answers"][-1] == target,
        nearest=tuple(model.object_names[s.nearest_object] for s in done),
        **per_touch,
    )
