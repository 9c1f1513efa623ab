"""What an evaluation is asked to do, and the checks that name what is wrong before it starts."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal, cast, get_args

from app.errors import BadInputError
from core.evaluation import TrialSettings
from core.evaluation import WorldName as SyntheticWorld
from core.recognition import (
    EVALUATION_POLICIES,
    PLANNING_BELIEFS,
    TRIAL_LIKELIHOODS,
    PlanningBelief,
    TrialLikelihood,
)
from core.types import ManifoldModel, TrainingData

if TYPE_CHECKING:
    from hardware.sim.materials import Table

#: The synthetic worlds of :func:`core.evaluation.worlds.make_world` (``exp1``, ``exp2``), the
#: simulated rig, the learned GP's samples and a replay of recorded touches.
WorldName = Literal[SyntheticWorld, "rig", "model", "replay"]
Placement = Literal["trial", "touch"]

#: How often a ``rig`` trial places its object anew.
PLACEMENTS: tuple[str, ...] = get_args(Placement)

#: Every world an evaluation can run against.
WORLDS: tuple[str, ...] = get_args(WorldName)


@dataclass(frozen=True)
class EvaluationSpec:
    """An evaluation: world, policies, targets, trials, T, stop rule and seed.

    Attributes:
        world: ``exp1`` (the paper's Experiment 1), ``exp2`` (a random Experiment-2-like world
            drawn from ``world_seed``), ``rig`` (the simulated rig, in process, virtual time),
            ``model`` (samples of the learned GP at the target's latent), ``replay`` (recorded
            held-out touches, without replacement).
        policies: Policy names (see :data:`core.recognition.planning.EVALUATION_POLICIES`).
        trials_per_target: Trials per (policy, target).
        steps: T, touches per trial at most (capped by the replay pool).
        confidence: Threshold of "touches to confidence" and of the compared accuracy level.
        seed: Entropy of every trial's ``SeedSequence``.
        targets: Objects to recognise (model objects); every model object when ``None``.
        table: Simulated rig table (``rig``): a name, or a table read from a file
            (:mod:`hardware.sim.table_file`); the default table when ``None``.
        world_seed: Seed that draws the ``exp2`` world (as the server's simulated trials do).
        noise_std: Observation noise of ``exp1``/``exp2`` (their
            :data:`core.evaluation.worlds.DEFAULT_NOISE_STD` when ``None``).
        tolerance: Stop when the belief mean moves less (normalised latent units; 0 disables).
        stop_at_confidence: Also stop a trial when the answer's probability reaches
            ``confidence`` (answers are carried forward to T).
        prior_variance: Σ0 = prior_variance · I (the paper's); ``None``: the objects' prior
            (:func:`core.recognition.session.default_prior`).
        placement: ``rig`` and ``model``: ``"trial"`` places the object once per trial (the
            table stays at it between touches; the model world draws one placement offset per
            trial); ``"touch"`` turns the table away and back before every touch, as a
            collection does, so every touch meets a fresh placement.
        trial_likelihood: How the object posterior scores a trial's touches: ``"joint"``
            (default; one Gaussian with the GP's full covariance, docs/calibration.md (C3)) or
            ``"independent"`` (the product of per-touch densities). A model's placement
            variance σ_b² enters only on the rig and the model world with
            ``placement="trial"``, the worlds whose trial touches share a placement (a
            replay's touches each met their own).
        plan_under: The belief actions are planned under: ``"objects"`` (default; the mixture
            over the learned objects the object posterior implies) or ``"gaussian"`` (the
            paper's Gaussian belief; the paper's experiments use it).
    """

    world: WorldName
    trials_per_target: int
    steps: int
    policies: tuple[str, ...] = ("active", "passive")
    confidence: float = 0.95
    seed: int = 0
    targets: tuple[str, ...] | None = None
    table: str | Table | None = None
    world_seed: int = 0
    noise_std: float | None = None
    tolerance: float = 1e-3
    stop_at_confidence: bool = False
    prior_variance: float | None = None
    placement: Placement = "trial"
    trial_likelihood: TrialLikelihood = "joint"
    plan_under: PlanningBelief = "objects"

    def target_names(self, model: ManifoldModel) -> tuple[str, ...]:
        """The targets, in the model's object order."""
        if self.targets is None:
            return model.object_names
        return tuple(n for n in model.object_names if n in self.targets)

    def trial_settings(self) -> TrialSettings:
        """Stop rule and prior of the trials."""
        return TrialSettings(
            steps=self.steps,
            tolerance=self.tolerance,
            stop_confidence=self.confidence if self.stop_at_confidence else None,
            prior_variance=self.prior_variance,
            trial_likelihood=self.trial_likelihood,
            shared_placement=self.world in ("rig", "model") and self.placement == "trial",
            plan_under=self.plan_under,
        )

    def steps_used(self, model: ManifoldModel, replay: TrainingData | None) -> int:
        """T actually run: ``steps``, or for a replay at most the smallest target pool."""
        if self.world != "replay" or replay is None:
            return self.steps
        counts = replay.touches_per_object()
        pools = [int(counts[replay.object_names.index(n)]) for n in self.target_names(model)]
        return min([self.steps, *pools])

    def check(self, model: ManifoldModel, replay: TrainingData | None = None) -> None:
        """Raise :class:`BadInputError` naming the field if this evaluation cannot run.

        Checks the world and policy names (listing the allowed ones), the counts, the targets,
        the world's dimensions against the model's and, for a replay, that its objects and
        dimensions match the model's.
        """
        if self.world not in WORLDS:
            raise BadInputError(
                f"world: {self.world!r} is not a world; choose from {list(WORLDS)}.",
                field="world",
            )
        if not self.policies:
            raise BadInputError(
                f"policies: name at least one of {sorted(EVALUATION_POLICIES)}.", field="policies"
            )
        unknown = [p for p in self.policies if p not in EVALUATION_POLICIES]
        if unknown or len(set(self.policies)) != len(self.policies):
            allowed = sorted(EVALUATION_POLICIES)
            raise BadInputError(
                f"policies: {unknown or list(self.policies)} "
                f"{'unknown' if unknown else 'repeated'}; choose from {allowed}.",
                field="policies",
            )
        for name, value in (("trials_per_target", self.trials_per_target), ("steps", self.steps)):
            if isinstance(value, bool) or int(value) != value or value < 1:
                raise BadInputError(
                    f"{name}: must be an integer ≥ 1, received {value}.", field=name
                )
        if not 0.0 < self.confidence <= 1.0:
            raise BadInputError(
                f"confidence: must lie in (0, 1], received {self.confidence}.", field="confidence"
            )
        if self.placement not in PLACEMENTS:
            raise BadInputError(
                f"placement: {self.placement!r} is not a placement; choose from "
                f"{list(PLACEMENTS)}.",
                field="placement",
            )
        if self.trial_likelihood not in TRIAL_LIKELIHOODS:
            raise BadInputError(
                f"trial_likelihood: {self.trial_likelihood!r} is not one of "
                f"{list(TRIAL_LIKELIHOODS)}.",
                field="trial_likelihood",
            )
        if self.plan_under not in PLANNING_BELIEFS:
            raise BadInputError(
                f"plan_under: {self.plan_under!r} is not one of {list(PLANNING_BELIEFS)}.",
                field="plan_under",
            )
        if self.seed < 0:
            raise BadInputError(f"seed: must be ≥ 0, received {self.seed}.", field="seed")
        if self.targets is not None:
            missing = [t for t in self.targets if t not in model.object_names]
            if missing or not self.targets:
                raise BadInputError(
                    f"targets: {missing} are not objects of the model; choose from "
                    f"{list(model.object_names)}.",
                    field="targets",
                )
        from app.evaluation.worlds import check_world

        check_world(self, model, replay)


def world_name(value: str) -> WorldName:
    """``value`` as a world name.

    Raises:
        BadInputError: Not a world (the message lists them).
    """
    if value not in WORLDS:
        raise BadInputError(
            f"world: {value!r} is not a world; choose from {list(WORLDS)}.", field="world"
        )
    return cast(WorldName, value)
