"""Recognising an object by touch: plan, touch, update, decide (docs/method.md (M4)–(M5)).

Two beliefs are carried side by side:

* the **Gaussian belief** s ~ N(μ, Σ) over the object latent (the paper's), updated by moment
  matching after every touch;
* the **object posterior** p(l | D_t) over the L learned objects
  (:mod:`core.recognition.object_posterior`), the exact GP likelihood of all touches so far under
  each object, by default jointly (the touches share one uncertain function f and, when the model
  has a placement effect, one placement: docs/calibration.md eq. (C3));
  ``trial_likelihood="independent"`` multiplies them.

Actions are planned by default under the mixture Σ_l p_l N(s_l, c·I) that the object posterior
implies (:mod:`core.recognition.object_mixture`); ``plan_under="gaussian"`` plans under the
Gaussian, as the paper does.

The Gaussian is a local approximation and can settle near the wrong object; planned under it, the
most informative actions under that wrong belief need not dislodge it (docs/method.md, "A known
failure mode").
The session therefore watches for disagreement: the Gaussian's nearest object is much less
probable under the posterior than the posterior's best object. By default it then re-centres the
Gaussian on the evidence, replacing it by the Gaussian that moment-matches the posterior mixture
Σ_l p_l N(s_l, Σ): the competing objects come back inside the belief, so the next action is planned
to discriminate between them and the next update starts from where the evidence points. (Planning
alone under the mixture, keeping the Gaussian as updated, is the ``"replan"`` option; it left the
Gaussian's nearest object wrong in some trials where the posterior was right.) The answer defaults
to the posterior's best object (see :class:`RecognitionSettings`).

:class:`RecognitionSession` is a step-wise state machine: a scripted trial (the caller owns the
robot) drives it one observation at a time; :func:`core.evaluation.trial_engine.iter_trial` is the
one loop around it for every other trial.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from core.errors import CoreError, InvalidInputError
from core.recognition.moments import (
    action_statistics,
    mutual_information,
    predictive_moments,
    update_belief,
)
from core.recognition.object_mixture import ObjectMixture
from core.recognition.object_posterior import (
    TrialLikelihood,
    check_trial_likelihood,
    normalise_log_probabilities,
    object_log_likelihoods,
)
from core.recognition.planning import PlannedAction, Planner
from core.types import GaussianBelief, ManifoldModel
from core.validation import FloatArray, as_float_array

Decision = Literal["posterior", "nearest"]
DisagreementRule = Literal["recentre", "replan", "ignore"]
PlanningBelief = Literal["objects", "gaussian"]
PLANNING_BELIEFS: tuple[PlanningBelief, ...] = ("objects", "gaussian")
StopReason = Literal["max_steps", "converged", "confident"]

#: The Gaussian and the posterior "disagree" when the posterior probability of the Gaussian's
#: nearest object is below this fraction of the posterior's largest probability.
DISAGREEMENT_RATIO = 0.5


class RecognitionFinishedError(CoreError):
    """A touch was suggested or observed after the session had stopped."""


@dataclass(frozen=True)
class RecognitionSettings:
    """When to stop and how to answer.

    Attributes:
        max_steps: T, the largest number of touches.
        tolerance: Stop when the Gaussian mean moves less than this after a touch, ‖μ' - μ‖ <
            tolerance, measured in normalised latent units (the learned latents are centred with
            RMS distance 1 from their centre, so objects are O(1) apart). 0 disables it. Unless
            ``on_disagreement="ignore"``, this stop is not taken while the Gaussian and the object
            posterior disagree (a Gaussian that stopped moving near an object the evidence rejects
            has not converged on the answer).
        confidence_threshold: Stop when the object posterior's largest probability reaches it;
            ``None`` disables it.
        decision: ``"posterior"`` (default): answer the object with the largest posterior
            probability. ``"nearest"``: the paper's rule, the learned latent nearest (Euclidean,
            normalised units) to the Gaussian mean. The default is the posterior because it uses
            the exact likelihood of every touch, while the Gaussian is a moment-matched
            linearisation that can lock onto the wrong object (docs/method.md, "A known failure
            mode"; the reference found the posterior right in every case where the Gaussian failed).
        on_disagreement: What to do when, after an update, the posterior probability of the
            Gaussian's nearest object is below ``DISAGREEMENT_RATIO`` (½) times the largest one.
            ``"recentre"`` (default): replace the Gaussian by the moment-matched posterior mixture
            Σ_l p_l N(s_l, Σ') (mean Σ_l p_l s_l, covariance Σ' + the spread of the s_l); the step
            reports ``recentred=True`` and its belief is the re-centred one. ``"replan"``: keep
            the Gaussian as updated, but plan the next action under that mixture-matched belief.
            ``"ignore"``: the paper, always the Gaussian.
        plan_under: The belief over s the next action is planned under (the active policy's
            U1, and the U1 every step reports). ``"objects"`` (default): the mixture
            Σ_l p_l N(s_l, c·I) over the learned latents weighted by the object posterior
            (:mod:`core.recognition.object_mixture`; c = :data:`OBJECT_COMPONENT_VARIANCE`):
            the object is one of the learned ones, so the information worth having is about
            which. ``"gaussian"``: the paper, the Gaussian belief (as ``on_disagreement`` leaves
            it). The Gaussian is updated by (M5) either way.
        trial_likelihood: How the object posterior scores the trial's touches
            (:func:`core.recognition.object_posterior.object_log_likelihoods`). ``"joint"``
            (default): one Gaussian over all of them with the GP's full covariance of f (and the
            placement variance σ_b², if the model has one and ``shared_placement``): the GP's
            uncertainty at repeated or nearby actions counts once, not once per touch
            (docs/calibration.md, "Fix 2"). ``"independent"``: the product of per-touch densities
            (the base model).
        shared_placement: Whether the trial's touches meet one placement of the object (a rig
            trial that places it once). ``False`` for touches that each met their own placement
            (a replay of a collection's touches, a rig trial placing before every touch): σ_b²
            is then left out; V still applies (the touches are of one object under the GP).
    """

    max_steps: int = 10
    tolerance: float = 1e-3
    confidence_threshold: float | None = None
    decision: Decision = "posterior"
    on_disagreement: DisagreementRule = "recentre"
    trial_likelihood: TrialLikelihood = "joint"
    shared_placement: bool = True
    plan_under: PlanningBelief = "objects"

    def __post_init__(self) -> None:
        if isinstance(self.max_steps, bool) or int(self.max_steps) != self.max_steps:
            raise InvalidInputError(f"max_steps: expected an integer, got {self.max_steps!r}.")
        if self.max_steps < 1:
            raise InvalidInputError(f"max_steps: must be ≥ 1, received {self.max_steps}.")
        if not np.isfinite(self.tolerance) or self.tolerance < 0:
            raise InvalidInputError(
                f"tolerance: must be finite and ≥ 0 (normalised latent units), received "
                f"{self.tolerance}."
            )
        threshold = self.confidence_threshold
        if threshold is not None and not 0.0 < threshold <= 1.0:
            raise InvalidInputError(
                f"confidence_threshold: must lie in (0, 1] or be None, received {threshold}."
            )
        if self.decision not in ("posterior", "nearest"):
            raise InvalidInputError(
                f"decision: expected 'posterior' or 'nearest', received {self.decision!r}."
            )
        if self.on_disagreement not in ("recentre", "replan", "ignore"):
            raise InvalidInputError(
                f"on_disagreement: expected 'recentre', 'replan' or 'ignore', received "
                f"{self.on_disagreement!r}."
            )
        check_trial_likelihood(self.trial_likelihood)
        if self.plan_under not in PLANNING_BELIEFS:
            raise InvalidInputError(
                f"plan_under: expected one of {list(PLANNING_BELIEFS)}, received "
                f"{self.plan_under!r}."
            )


@dataclass(frozen=True)
class RecognitionStep:
    """The state after one touch.

    Attributes:
        step: 1 for the first touch.
        action: The action performed. Shape (dx,).
        observation: What was observed. Shape (dy,).
        mutual_information: U1 of the performed action under the belief it was planned under
            (``settings.plan_under``) before the update, in nats.
        belief: The Gaussian belief after the update (M5).
        probabilities: The object posterior after this touch. Shape (L,).
        nearest_object: Index of the learned latent nearest the Gaussian mean.
        answer: The recognised object by ``settings.decision``.
        done: Whether the session stopped after this touch.
        stop_reason: ``"confident"``, ``"converged"`` or ``"max_steps"`` when done, else ``None``.
        mean_shift: ‖μ' - μ‖ of this step (update and any re-centring), normalised latent units.
        recentred: Whether the Gaussian was re-centred on the object posterior after the update
            (``on_disagreement="recentre"``).
    """

    step: int
    action: FloatArray
    observation: FloatArray
    mutual_information: float
    belief: GaussianBelief
    probabilities: FloatArray
    nearest_object: int
    answer: int
    done: bool
    stop_reason: StopReason | None
    mean_shift: float
    recentred: bool = False


#: Variance (normalised latent units, per dimension) of each object's component in the objects'
#: prior: small against the objects' spacing (O(1)), so the prior's spread is the objects' own.
OBJECT_COMPONENT_VARIANCE = 0.05


def default_prior(model: ManifoldModel, variance: float | None = None) -> GaussianBelief:
    """The initial belief of a recognition.

    By default (``variance=None``) **the objects' prior**: the Gaussian with the moments of the
    uniform mixture (1/L) Σ_l N(s_l, c·I) over the learned latents (c =
    :data:`OBJECT_COMPONENT_VARIANCE`), i.e. every known object equally likely: mean the
    latents' centre, covariance their spread plus c·I (docs/method.md, "Recommended
    defaults"). With ``variance`` the paper's belief: μ0 = mean of the learned latents, Σ0 =
    variance · I (the paper's Σ0 = 5; the paper's experiments use it).

    The paper's Σ0 = 5·I, in the normalised units where the objects lie about 1 from their
    centre, puts most of its mass where no object is; on a manifold whose latent length-scales
    are shorter than that, the mutual information under it (M4) is about where the latent lies
    among those empty regions, and the active policy chose nearly uninformative touches
    (docs/calibration.md, "The objects' prior").

    Args:
        model: A conditioned model (latents normalised: centred, RMS spread 1).
        variance: Prior variance per latent dimension, in normalised latent units; ``None``:
            the objects' prior.
    """
    if variance is None:
        return objects_belief(model).moment_matched()
    if not np.isfinite(variance) or variance <= 0:
        raise InvalidInputError(f"variance: must be finite and > 0, received {variance}.")
    ds = model.latent_dim
    return GaussianBelief(mean=model.latents.mean(axis=0), cov=variance * np.eye(ds))


def objects_belief(model: ManifoldModel, probabilities: FloatArray | None = None) -> ObjectMixture:
    """The belief Σ_l p_l N(s_l, c·I) over the learned latents (c =
    :data:`OBJECT_COMPONENT_VARIANCE`) that actions are planned under by default.

    Args:
        model: A conditioned model.
        probabilities: p_l, the object posterior; uniform (before any touch) when ``None``.
            Shape (L,).
    """
    n_objects, ds = model.latents.shape
    if probabilities is None:
        probabilities = np.full(n_objects, 1.0 / n_objects)
    return ObjectMixture(model.latents, probabilities, OBJECT_COMPONENT_VARIANCE * np.eye(ds))


def nearest_object(model: ManifoldModel, point: FloatArray) -> int:
    """Index of the learned latent nearest (Euclidean) to ``point`` (ds,)."""
    distances = np.sum((model.latents - point[None, :]) ** 2, axis=1)
    return int(np.argmin(distances))


def mixture_belief(
    model: ManifoldModel, probabilities: FloatArray, cov: FloatArray
) -> GaussianBelief:
    """The Gaussian with the moments of Σ_l p_l N(s_l, cov).

    Mean Σ_l p_l s_l; covariance cov + Σ_l p_l (s_l - s̄)(s_l - s̄)ᵀ.
    """
    return ObjectMixture(model.latents, probabilities, cov).moment_matched()


class RecognitionSession:
    """A step-wise recognition trial: ask for an action, report what was observed, repeat.

    The suggestion is advice: :meth:`observe` accepts whatever action was actually performed
    (clipped by the robot, or replayed from recorded data), with or without a prior
    :meth:`suggest`. :meth:`observe` is deterministic, so a session can be rebuilt exactly by
    replaying its (action, observation) pairs into a new one.

    Args:
        model: A conditioned model.
        planner: A :class:`core.recognition.planning.Planner` built for ``model``.
        prior: Initial Gaussian belief; :func:`default_prior` when ``None``.
        settings: Stopping and decision rules.

    Raises:
        InvalidInputError: The planner or the prior does not match the model.
    """

    def __init__(
        self,
        model: ManifoldModel,
        planner: Planner,
        prior: GaussianBelief | None = None,
        settings: RecognitionSettings | None = None,
    ) -> None:
        if planner.model is not model:
            raise InvalidInputError("planner: was built for a different model than the session.")
        prior = prior if prior is not None else default_prior(model)
        if prior.dim != model.latent_dim:
            raise InvalidInputError(
                f"prior: has ds={prior.dim}, the model has latent_dim={model.latent_dim}."
            )
        self.model = model
        self.planner = planner
        self.settings = settings if settings is not None else RecognitionSettings()
        self._belief = prior
        self._log_likelihoods = np.zeros(model.data.n_objects)
        self._steps: list[RecognitionStep] = []

    @property
    def belief(self) -> GaussianBelief:
        """The current Gaussian belief."""
        return self._belief

    @property
    def probabilities(self) -> FloatArray:
        """The current object posterior (uniform before the first touch). Shape (L,)."""
        return normalise_log_probabilities(self._log_likelihoods)

    @property
    def steps(self) -> tuple[RecognitionStep, ...]:
        """Every step so far."""
        return tuple(self._steps)

    @property
    def done(self) -> bool:
        """Whether the session has stopped."""
        return bool(self._steps) and self._steps[-1].done

    def disagrees(self) -> bool:
        """Whether the Gaussian's nearest object is much less probable than the posterior's best.

        True when p(nearest) < DISAGREEMENT_RATIO · max_l p(l).
        """
        probabilities = self.probabilities
        nearest = nearest_object(self.model, self._belief.mean)
        return bool(probabilities[nearest] < DISAGREEMENT_RATIO * probabilities.max())

    def planning_belief(self) -> GaussianBelief | ObjectMixture:
        """The belief the next action is planned under (see :class:`RecognitionSettings`)."""
        if self.settings.plan_under == "objects":
            return objects_belief(self.model, self.probabilities)
        if self.settings.on_disagreement == "replan" and self.disagrees():
            return mixture_belief(self.model, self.probabilities, self._belief.cov)
        return self._belief

    def suggest(self, rng: np.random.Generator) -> PlannedAction:
        """The planner's choice for the next touch (given the Gaussian belief to plan under and
        the current object probabilities, which the discriminative policy plans for).

        Raises:
            RecognitionFinishedError: The session has stopped.
        """
        self._check_running()
        return self.planner.plan(self.planning_belief(), rng, self.probabilities)

    def observe(self, action: FloatArray, observation: FloatArray) -> RecognitionStep:
        """Update both beliefs with a touch and decide whether to stop.

        Args:
            action: The action actually performed. Shape (dx,).
            observation: What was observed, in raw units. Shape (dy,).

        Raises:
            InvalidInputError: Wrong shape or non-finite action/observation.
            RecognitionFinishedError: The session has stopped.
        """
        self._check_running()
        h = self.model.hyperparameters
        x = as_float_array(action, "action", (h.action_dim,)).copy()
        y = as_float_array(observation, "observation", (h.observation_dim,)).copy()
        before = self._belief
        planned_under = self.planning_belief()
        stats = action_statistics(self.model, x[None, :])
        moments = predictive_moments(self.model, before, stats)
        if isinstance(planned_under, ObjectMixture):
            information = float(self.planner.mutual_information(planned_under, x[None, :])[0])
        else:
            information = float(mutual_information(moments, before)[0])
        # The moments are in the model's space y' = M (y - c): map the raw observation there
        # (the object posterior below takes it raw and maps it itself).
        y_model = self.model.to_model_space(y[None, :])[0]
        after = update_belief(before, moments, 0, y_model)  # docs/method.md eq. (M5)
        self._belief = after
        settings = self.settings
        if settings.trial_likelihood == "joint":
            # One joint Gaussian over every touch so far, recomputed (exact; T is small, so the
            # joint Gaussian is recomputed rather than extended).
            touched = [(s.action, s.observation) for s in self._steps] + [(x, y)]
            self._log_likelihoods = object_log_likelihoods(
                self.model,
                np.stack([a for a, _ in touched]),
                np.stack([o for _, o in touched]),
                "joint",
                settings.shared_placement,
            )
        else:
            self._log_likelihoods = self._log_likelihoods + object_log_likelihoods(
                self.model, x[None, :], y[None, :], "independent"
            )
        probabilities = self.probabilities
        recentred = self.settings.on_disagreement == "recentre" and self.disagrees()
        if recentred:
            after = mixture_belief(self.model, probabilities, after.cov)
            self._belief = after
        nearest = nearest_object(self.model, after.mean)
        best = int(np.argmax(probabilities))
        answer = best if self.settings.decision == "posterior" else nearest
        shift = float(np.linalg.norm(after.mean - before.mean))
        for array in (x, y, probabilities):
            array.flags.writeable = False
        step = len(self._steps) + 1
        reason = self._stop_reason(step, shift, probabilities)
        result = RecognitionStep(
            step=step,
            action=x,
            observation=y,
            mutual_information=information,
            belief=after,
            probabilities=probabilities,
            nearest_object=nearest,
            answer=answer,
            done=reason is not None,
            stop_reason=reason,
            mean_shift=shift,
            recentred=recentred,
        )
        self._steps.append(result)
        return result

    def _stop_reason(self, step: int, shift: float, probabilities: FloatArray) -> StopReason | None:
        settings = self.settings
        threshold = settings.confidence_threshold
        if threshold is not None and probabilities.max() >= threshold:
            return "confident"
        if shift < settings.tolerance and (
            settings.on_disagreement == "ignore" or not self.disagrees()
        ):
            return "converged"
        if step >= settings.max_steps:
            return "max_steps"
        return None

    def _check_running(self) -> None:
        if self.done:
            reason = self._steps[-1].stop_reason
            raise RecognitionFinishedError(
                f"The session stopped after step {len(self._steps)} ({reason}); start a new one."
            )
