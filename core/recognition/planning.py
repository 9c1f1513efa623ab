"""Choosing the next touch: maximise the mutual information over a bounded action box (M4).

The active planner scores a fixed, scrambled Sobol set of candidate actions spread over the box
(their action statistics are computed once per model and reused at every touch, docs/method.md
"Structure that makes it fast"), then refines the best few with L-BFGS-B inside the box using the
analytic gradient of the mutual information. The discriminative policy scores the same
candidates (and the same cached statistics) by the information the touch would give about *which
object* it is, under the current object probabilities (:mod:`core.recognition.object_information`).
The passive policy draws from the action prior and the fixed policy repeats one action; every policy
reports the mutual information of its action under the belief it was given.

:data:`POLICIES` is the one registry of policies by name (CLI, API, evaluations, benchmarks): how a
policy plans (its :class:`Policy`) and how it picks among recorded touches in a replay trial. A new
policy is one entry there.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import scipy.optimize
from scipy.stats import qmc

from core.errors import InvalidInputError
from core.recognition.information_gradient import GradientCache, mutual_information_and_gradient
from core.recognition.moments import (
    ActionStatistics,
    BeliefTerms,
    action_statistics,
    belief_terms,
    moments_from_terms,
    mutual_information,
    predictive_moments,
)
from core.recognition.object_information import label_information_mc, object_predictives
from core.recognition.object_mixture import ObjectMixture, component_terms, mixture_information
from core.types import GaussianBelief, ManifoldModel
from core.validation import FloatArray, as_float_array

PolicyName = Literal["active", "passive", "fixed", "discriminative"]

#: Every policy name, in the order user interfaces list them (the keys of :data:`POLICIES`).
POLICY_NAMES: tuple[PolicyName, ...] = ("active", "discriminative", "passive", "fixed")


#: Default half-width of the planning box in standard deviations of the training actions.
DEFAULT_SPREAD_STD = 2.0


@dataclass(frozen=True)
class ActionBox:
    """Allowed actions: lower ≤ x ≤ upper, element-wise.

    Attributes:
        lower: Shape (dx,).
        upper: Shape (dx,), ≥ ``lower``.
    """

    lower: FloatArray
    upper: FloatArray

    def __post_init__(self) -> None:
        lower = as_float_array(self.lower, "box lower", (None,)).copy()
        upper = as_float_array(self.upper, "box upper", (lower.shape[0],)).copy()
        if np.any(upper < lower):
            raise InvalidInputError(
                f"box: every upper bound must be ≥ its lower bound, received lower={lower} and "
                f"upper={upper}."
            )
        lower.flags.writeable = False
        upper.flags.writeable = False
        object.__setattr__(self, "lower", lower)
        object.__setattr__(self, "upper", upper)

    @property
    def dim(self) -> int:
        """dx."""
        return int(self.lower.shape[0])

    def clip(self, actions: FloatArray) -> FloatArray:
        """Clip actions (…, dx) into the box."""
        return np.asarray(np.clip(actions, self.lower, self.upper), dtype=np.float64)

    def contains(self, actions: FloatArray) -> bool:
        """Whether every action (…, dx) lies in the box."""
        return bool(np.all((actions >= self.lower) & (actions <= self.upper)))

    @classmethod
    def from_model(
        cls, model: ManifoldModel, spread_std: float | None = DEFAULT_SPREAD_STD
    ) -> ActionBox:
        """Where the GP has seen enough data: the training actions' mean ± ``spread_std``
        standard deviations per dimension, within their range (``None``: the whole range).

        The range of a random design reaches ~2.5-3 std, where a few touches per object are
        all the GP has; its predictions there shrink toward the mean (measured on the
        ``cushions`` table, docs/simulation.md: at 2 std along the deep-press direction the
        predicted pressure of the cork cushion was 20 % low, nearer the wooden one's than its
        own), and an active policy that seeks the largest predicted differences goes there.
        """
        actions = model.data.actions
        lower, upper = actions.min(axis=0), actions.max(axis=0)
        if spread_std is not None:
            if not spread_std > 0:
                raise InvalidInputError(f"spread_std: must be > 0, received {spread_std}.")
            mean, std = actions.mean(axis=0), actions.std(axis=0)
            lower = np.maximum(lower, mean - spread_std * std)
            upper = np.minimum(upper, mean + spread_std * std)
        return cls(lower=lower, upper=upper)


@dataclass(frozen=True)
class ActionPrior:
    """The distribution passive actions are drawn from: x ~ N(mean, cov), clipped to the box.

    Attributes:
        mean: Shape (dx,).
        cov: Symmetric positive semi-definite. Shape (dx, dx).
    """

    mean: FloatArray
    cov: FloatArray

    def __post_init__(self) -> None:
        mean = as_float_array(self.mean, "action prior mean", (None,)).copy()
        cov = as_float_array(self.cov, "action prior cov", (mean.shape[0], mean.shape[0])).copy()
        if not np.allclose(cov, cov.T, rtol=1e-8, atol=1e-12):
            raise InvalidInputError("action prior cov: must be symmetric.")
        if np.linalg.eigvalsh(cov).min() < -1e-10 * max(1.0, float(np.abs(cov).max())):
            raise InvalidInputError("action prior cov: must be positive semi-definite.")
        mean.flags.writeable = False
        cov.flags.writeable = False
        object.__setattr__(self, "mean", mean)
        object.__setattr__(self, "cov", cov)

    @classmethod
    def from_model(cls, model: ManifoldModel) -> ActionPrior:
        """Mean and covariance of the training actions (the design the data was collected with)."""
        actions = model.data.actions
        cov = np.atleast_2d(np.cov(actions, rowvar=False))
        return cls(mean=actions.mean(axis=0), cov=0.5 * (cov + cov.T))

    def sample(self, rng: np.random.Generator) -> FloatArray:
        """One draw. Shape (dx,)."""
        return np.asarray(
            rng.multivariate_normal(self.mean, self.cov, method="eigh"), dtype=np.float64
        )


@dataclass(frozen=True)
class ActivePolicy:
    """Maximise the mutual information between the object latent and the next observation."""

    name: PolicyName = field(default="active", init=False)


@dataclass(frozen=True)
class PassivePolicy:
    """Random actions from the action prior, clipped to the box."""

    name: PolicyName = field(default="passive", init=False)


@dataclass(frozen=True)
class FixedPolicy:
    """Always the same action (e.g. the teaching action).

    Attributes:
        action: Shape (dx,).
    """

    action: FloatArray
    name: PolicyName = field(default="fixed", init=False)

    def __post_init__(self) -> None:
        action = as_float_array(self.action, "fixed action", (None,)).copy()
        action.flags.writeable = False
        object.__setattr__(self, "action", action)


@dataclass(frozen=True)
class DiscriminativePolicy:
    """Maximise the information of the next observation about which object it is.

    The score of an action x is I(l; y | x) under the current object probabilities p_l, each
    object's observation predicted by the GP at its learned latent s_l
    (:mod:`core.recognition.object_information`), estimated by Monte Carlo with ``n_draws`` common
    random numbers (fixed per planner, so the choice is deterministic).

    Attributes:
        n_draws: Monte Carlo draws per object and candidate.
    """

    n_draws: int = 128
    name: PolicyName = field(default="discriminative", init=False)

    def __post_init__(self) -> None:
        if isinstance(self.n_draws, bool) or not isinstance(self.n_draws, int):
            raise InvalidInputError(f"n_draws: expected an integer, received {self.n_draws!r}.")
        if self.n_draws < 2:
            raise InvalidInputError(f"n_draws: must be ≥ 2, received {self.n_draws}.")


Policy = ActivePolicy | PassivePolicy | FixedPolicy | DiscriminativePolicy


@dataclass(frozen=True)
class PlannedAction:
    """The action a policy chose.

    Attributes:
        action: Shape (dx,).
        mutual_information: U1 of ``action`` under the belief it was planned for, in nats
            (reported for every policy).
        policy: Name of the policy that chose it.
        object_information: The estimated information about the object's identity, in nats
            (discriminative policy only).
    """

    action: FloatArray
    mutual_information: float
    policy: PolicyName
    object_information: float | None = None


def sobol_candidates(box: ActionBox, n_candidates: int, seed: int) -> FloatArray:
    """A scrambled Sobol set mapped into the box. Shape (n_candidates, dx).

    The first ``n_candidates`` points of a base-2 sequence of the next power of two.
    """
    if n_candidates < 1:
        raise InvalidInputError(f"n_candidates: must be ≥ 1, received {n_candidates}.")
    m = int(np.ceil(np.log2(n_candidates)))
    unit = qmc.Sobol(box.dim, scramble=True, rng=np.random.default_rng(seed)).random_base2(m)
    return np.asarray(box.lower + unit[:n_candidates] * (box.upper - box.lower), dtype=np.float64)


#: Distinct mixtures (means and covariance) whose component terms a planner keeps.
MIXTURE_TERMS_KEPT = 4


class Planner:
    """Chooses actions for a model under a policy.

    The candidate set and its action statistics are built once, on the first active plan (or at
    construction for the active policy), and reused for every belief.

    Args:
        model: A conditioned model.
        policy: :class:`ActivePolicy`, :class:`PassivePolicy` or :class:`FixedPolicy`.
        box: Allowed actions; the range of the training actions when ``None``.
        prior: Distribution of passive actions; mean/cov of the training actions when ``None``.
        n_candidates: Size of the Sobol candidate set (active policy).
        n_refine: How many of the best candidates are refined by L-BFGS-B (0 = no refinement).
        refine_iterations: L-BFGS-B iteration cap per refinement.
        candidate_seed: Seed of the Sobol scrambling (fixed, so a model's candidate set and its
            cached statistics do not depend on the trial's random stream).

    Raises:
        InvalidInputError: Box, prior or fixed action of the wrong dimension, or bad settings.
    """

    def __init__(
        self,
        model: ManifoldModel,
        policy: Policy,
        box: ActionBox | None = None,
        prior: ActionPrior | None = None,
        n_candidates: int = 256,
        n_refine: int = 1,
        refine_iterations: int = 30,
        candidate_seed: int = 0,
    ) -> None:
        dx = model.hyperparameters.action_dim
        self.model = model
        self.policy = policy
        self.box = box if box is not None else ActionBox.from_model(model)
        self.prior = prior if prior is not None else ActionPrior.from_model(model)
        if self.box.dim != dx:
            raise InvalidInputError(f"box: has dx={self.box.dim}, the model has dx={dx}.")
        if self.prior.mean.shape[0] != dx:
            raise InvalidInputError(
                f"prior: has dx={self.prior.mean.shape[0]}, the model has dx={dx}."
            )
        if isinstance(policy, FixedPolicy) and policy.action.shape[0] != dx:
            raise InvalidInputError(
                f"policy: the fixed action has dx={policy.action.shape[0]}, the model has dx={dx}."
            )
        if n_refine < 0 or refine_iterations < 0:
            raise InvalidInputError(
                f"n_refine and refine_iterations: must be ≥ 0, received {n_refine} and "
                f"{refine_iterations}."
            )
        self.n_candidates = int(n_candidates)
        self.n_refine = int(n_refine)
        self.refine_iterations = int(refine_iterations)
        self.candidate_seed = int(candidate_seed)
        self._statistics: ActionStatistics | None = None
        self._mixture_terms: dict[bytes, tuple[BeliefTerms, ...]] = {}
        self._gradient_cache: GradientCache | None = None
        self._predictives: tuple[FloatArray, FloatArray] | None = None
        self._draws: FloatArray | None = None
        if self.n_candidates < 1:
            raise InvalidInputError(f"n_candidates: must be ≥ 1, received {n_candidates}.")
        if isinstance(policy, ActivePolicy | DiscriminativePolicy):
            self._statistics = self.candidate_statistics

    @property
    def candidate_statistics(self) -> ActionStatistics:
        """Action statistics of the Sobol candidate set (computed once, then cached)."""
        if self._statistics is None:
            candidates = sobol_candidates(self.box, self.n_candidates, self.candidate_seed)
            self._statistics = action_statistics(self.model, candidates)
        return self._statistics

    def mixture_terms(self, mixture: ObjectMixture) -> tuple[BeliefTerms, ...]:
        """The belief terms of every component of ``mixture``
        (:func:`core.recognition.object_mixture.component_terms`), kept for the components'
        means and covariance: a trial's mixtures differ only in their weights."""
        key = mixture.means.tobytes() + mixture.cov.tobytes()
        terms = self._mixture_terms.get(key)
        if terms is None:
            if len(self._mixture_terms) >= MIXTURE_TERMS_KEPT:
                self._mixture_terms.clear()
            terms = component_terms(self.model, mixture)
            self._mixture_terms[key] = terms
        return terms

    def mutual_information(
        self, belief: GaussianBelief | ObjectMixture, actions: FloatArray
    ) -> FloatArray:
        """U1 of arbitrary actions (C, dx) under ``belief``. Shape (C,)."""
        stats = action_statistics(self.model, actions)
        if isinstance(belief, ObjectMixture):
            return mixture_information(self.model, belief, stats, self.mixture_terms(belief))
        return mutual_information(predictive_moments(self.model, belief, stats), belief)

    def plan(
        self,
        belief: GaussianBelief | ObjectMixture,
        rng: np.random.Generator,
        probabilities: FloatArray | None = None,
    ) -> PlannedAction:
        """Choose the next action under ``belief``.

        Args:
            belief: The belief over s to plan for: the Gaussian s ~ N(μ, Σ), or the mixture
                over the learned objects (:mod:`core.recognition.object_mixture`).
            rng: Source of randomness (passive draws).
            probabilities: The current object posterior p_l (discriminative policy; uniform when
                ``None``). Shape (L,).
        """
        policy = self.policy
        if isinstance(policy, ActivePolicy):
            return self._plan_active(belief)
        if isinstance(policy, DiscriminativePolicy):
            return self._plan_discriminative(belief, policy, probabilities)
        if isinstance(policy, PassivePolicy):
            action = self.box.clip(self.prior.sample(rng))
        else:
            action = np.array(policy.action, dtype=np.float64)
        value = float(self.mutual_information(belief, action[None, :])[0])
        return PlannedAction(action=action, mutual_information=value, policy=policy.name)

    def object_information(self, probabilities: FloatArray | None = None) -> FloatArray:
        """Estimated I(l; y | x) of every candidate under ``probabilities``. Shape (C,).

        Uses the candidate statistics and the objects' predictives (both computed once per
        planner) and the planner's fixed standard-normal draws (common random numbers).
        """
        n_objects = self.model.data.n_objects
        if probabilities is None:
            p = np.full(n_objects, 1.0 / n_objects)
        else:
            p = as_float_array(probabilities, "probabilities", (n_objects,))
        if self._predictives is None:
            self._predictives = object_predictives(self.model, self.candidate_statistics)
        if self._draws is None:
            n_draws = (
                self.policy.n_draws
                if isinstance(self.policy, DiscriminativePolicy)
                else DiscriminativePolicy().n_draws
            )
            draws_rng = np.random.default_rng(self.candidate_seed)
            self._draws = draws_rng.standard_normal(
                (n_draws, self.model.hyperparameters.observation_dim)
            )
        mean, variance = self._predictives
        return label_information_mc(p, mean, variance, self._draws)

    def _plan_discriminative(
        self,
        belief: GaussianBelief | ObjectMixture,
        policy: DiscriminativePolicy,
        probabilities: FloatArray | None,
    ) -> PlannedAction:
        scores = self.object_information(probabilities)
        best = int(np.argmax(scores))
        action = self.candidate_statistics.actions[best].copy()
        value = float(self.mutual_information(belief, action[None, :])[0])
        return PlannedAction(
            action=action,
            mutual_information=value,
            policy=policy.name,
            object_information=float(scores[best]),
        )

    def _plan_active(self, belief: GaussianBelief | ObjectMixture) -> PlannedAction:
        stats = self.candidate_statistics
        if isinstance(belief, ObjectMixture):
            # The candidates only: the analytic gradient of U1 is the single Gaussian's.
            mixture_scores = mixture_information(
                self.model, belief, stats, self.mixture_terms(belief)
            )
            chosen = int(np.argmax(mixture_scores))
            return PlannedAction(
                action=stats.actions[chosen].copy(),
                mutual_information=float(mixture_scores[chosen]),
                policy="active",
            )
        terms = belief_terms(self.model, belief)
        scores = mutual_information(moments_from_terms(self.model, terms, stats), belief)
        order = np.argsort(-scores)
        best = int(order[0])
        best_action = stats.actions[best].copy()
        best_value = float(scores[best])
        bounds = list(zip(self.box.lower, self.box.upper, strict=True))
        if self._gradient_cache is None:
            self._gradient_cache = GradientCache(self.model)
        cache = self._gradient_cache

        def negative(x: FloatArray) -> tuple[float, FloatArray]:
            value, gradient = mutual_information_and_gradient(self.model, belief, x, terms, cache)
            return -value, -gradient

        for index in order[: self.n_refine]:
            if self.refine_iterations == 0:
                break
            result = scipy.optimize.minimize(
                negative,
                stats.actions[index],
                jac=True,
                method="L-BFGS-B",
                bounds=bounds,
                # MI changes below ~1e-6 nats do not matter for the choice of action.
                options={"maxiter": self.refine_iterations, "ftol": 1e-6, "gtol": 1e-4},
            )
            value = -float(result.fun)
            if np.isfinite(value) and value > best_value:
                best_value = value
                best_action = self.box.clip(np.asarray(result.x, dtype=np.float64))
        return PlannedAction(action=best_action, mutual_information=best_value, policy="active")


# --- the policy registry ----------------------------------------------------------------------

#: How a policy scores the unused recorded actions (C, dx) of a replay trial, given the planner,
#: the belief to plan under and the current object posterior (L,); the largest score is touched
#: next. Shape (C,).
ReplayScore = Callable[
    [Planner, GaussianBelief | ObjectMixture, FloatArray, FloatArray], FloatArray
]


def information_score(
    planner: Planner,
    belief: GaussianBelief | ObjectMixture,
    probabilities: FloatArray,
    actions: FloatArray,
) -> FloatArray:
    """U1 of each recorded action under the belief (docs/method.md (M4)); posterior unused."""
    return planner.mutual_information(belief, actions)


def label_information_score(
    planner: Planner,
    belief: GaussianBelief | ObjectMixture,
    probabilities: FloatArray,
    actions: FloatArray,
) -> FloatArray:
    """Estimated I(l; y | x) of each recorded action under the object posterior.

    The discriminative policy's score (:mod:`core.recognition.object_information`), evaluated at the
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


def _fixed_policy(action: FloatArray | None) -> Policy:
    if action is None or np.asarray(action).size == 0:
        raise InvalidInputError(
            "policy 'fixed': needs the fixed action to repeat, dx numbers "
            "(--action on the command line, fixed_action in the API)."
        )
    return FixedPolicy(np.asarray(action, dtype=np.float64))


@dataclass(frozen=True)
class PolicyEntry:
    """How a policy is run, by name.

    Attributes:
        build: Builds the planner's policy from the policy's action parameter (the fixed
            action; ``None`` for the policies that take none).
        replay_score: Scores unused recorded touches in a replay trial (largest first);
            ``None`` picks one at random (from the trial's policy generator).
        needs_action: Whether the policy needs an action parameter (the fixed policy). Such a
            policy cannot be named in an evaluation, which gives none.
    """

    build: Callable[[FloatArray | None], Policy]
    replay_score: ReplayScore | None
    needs_action: bool = False

    def make(self, action: FloatArray | None = None) -> Policy:
        """The planner's policy (``action``: the fixed policy's action, shape (dx,))."""
        return self.build(action)


#: Every policy by name, in the order user interfaces list them. Add a policy here, in one line.
POLICIES: dict[PolicyName, PolicyEntry] = {
    "active": PolicyEntry(lambda _: ActivePolicy(), information_score),
    "discriminative": PolicyEntry(lambda _: DiscriminativePolicy(), label_information_score),
    "passive": PolicyEntry(lambda _: PassivePolicy(), None),
    "fixed": PolicyEntry(_fixed_policy, None, needs_action=True),
}

#: The policies an evaluation (and a benchmark) may name: those that need no parameter.
EVALUATION_POLICIES: tuple[PolicyName, ...] = tuple(
    name for name, entry in POLICIES.items() if not entry.needs_action
)


def policy_entry(name: str, allowed: tuple[str, ...] = POLICY_NAMES) -> PolicyEntry:
    """The registry entry of a policy name.

    Args:
        name: The policy's name.
        allowed: The names the caller accepts (e.g. :data:`EVALUATION_POLICIES`).

    Raises:
        InvalidInputError: Unknown or not allowed name (the message lists the allowed ones).
    """
    for known, entry in POLICIES.items():
        if known == name and name in allowed:
            return entry
    raise InvalidInputError(f"policy: {name!r} is not a policy; choose from {sorted(allowed)}.")


def make_policy(name: str, fixed_action: FloatArray | None = None) -> Policy:
    """The policy called ``name`` (one of :data:`POLICY_NAMES`).

    Args:
        name: ``"active"``, ``"discriminative"``, ``"passive"`` or ``"fixed"``.
        fixed_action: The action of ``"fixed"``. Shape (dx,).

    Raises:
        InvalidInputError: Unknown name, or ``"fixed"`` without an action.
    """
    if name not in POLICY_NAMES:
        raise InvalidInputError(
            f"policy: expected one of {', '.join(POLICY_NAMES)}, received {name!r}."
        )
    return policy_entry(name).make(fixed_action)
