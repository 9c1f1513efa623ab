"""Scoring recognition: simulated trials against a world, accuracy against touch count.

A world (``core.worlds.World``) produces the observations; the model only knows object names,
so targets and answers are matched by name.

Evaluations (``activetouch evaluate``, ``paper exp1``, the server's jobs) run on
:mod:`core.evaluation_trial` (one ``SeedSequence`` per trial, records by name) and
:mod:`core.evaluation_summary`. Here remain :func:`iter_simulated_trial` (``activetouch
recognize``) and the older sequential loop :func:`evaluate` (one generator shared by every
trial, so a trial cannot be re-run alone), which only ``tests/e2e/test_experiment1.py`` still uses.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np

from core.errors import InvalidInputError
from core.planning import Planner
from core.recognition import RecognitionSettings, RecognitionStep, iter_recognize
from core.types import GaussianBelief, ManifoldModel
from core.validation import FloatArray, IntArray
from core.worlds import World


@dataclass(frozen=True)
class TrialOutcome:
    """One simulated recognition trial.

    Attributes:
        target: Index (in the model's objects) of the object that was touched.
        answers: The answer after each touch 1..T; after an early stop the last answer is
            carried forward. Shape (T,).
        nearest: The object nearest the Gaussian mean after each touch, carried forward the
            same way (the paper's rule). Shape (T,).
        steps: Touches actually performed.
        stop_reason: Why the trial stopped.
    """

    target: int
    answers: IntArray
    nearest: IntArray
    steps: int
    stop_reason: str

    @property
    def correct(self) -> bool:
        """Whether the final answer is the target."""
        return bool(self.answers[-1] == self.target)


def target_indices(model: ManifoldModel, world: World) -> tuple[int, ...]:
    """For each model object, its index in the world (matched by name).

    Raises:
        InvalidInputError: A model object does not exist in the world.
    """
    missing = [n for n in model.object_names if n not in world.object_names]
    if missing:
        raise InvalidInputError(
            f"the model's objects {missing} are not in the world (it has "
            f"{list(world.object_names)})."
        )
    return tuple(world.object_names.index(n) for n in model.object_names)


def iter_simulated_trial(
    model: ManifoldModel,
    world: World,
    target: int,
    planner: Planner,
    prior: GaussianBelief | None,
    settings: RecognitionSettings,
    rng: np.random.Generator,
) -> Iterator[RecognitionStep]:
    """Recognise model object ``target`` with observations drawn from ``world``.

    Yields:
        Every :class:`RecognitionStep`.
    """
    if not 0 <= target < len(model.object_names):
        raise InvalidInputError(
            f"target: expected 0..{len(model.object_names) - 1}, received {target}."
        )
    world_index = target_indices(model, world)[target]

    def observe(action: FloatArray) -> FloatArray:
        return np.asarray(world.observe(world_index, action[None, :], rng)[0], dtype=np.float64)

    yield from iter_recognize(model, observe, planner, prior, settings, rng)


def simulate_trial(
    model: ManifoldModel,
    world: World,
    target: int,
    planner: Planner,
    prior: GaussianBelief | None,
    settings: RecognitionSettings,
    rng: np.random.Generator,
) -> TrialOutcome:
    """Run one simulated trial to the end and summarise it."""
    steps = list(iter_simulated_trial(model, world, target, planner, prior, settings, rng))
    answers = np.full(settings.max_steps, steps[-1].answer, dtype=np.int64)
    nearest = np.full(settings.max_steps, steps[-1].nearest_object, dtype=np.int64)
    for i, step in enumerate(steps):
        answers[i] = step.answer
        nearest[i] = step.nearest_object
    return TrialOutcome(
        target=target,
        answers=answers,
        nearest=nearest,
        steps=len(steps),
        stop_reason=str(steps[-1].stop_reason),
    )


def evaluate(
    model: ManifoldModel,
    world: World,
    planner: Planner,
    settings: RecognitionSettings,
    trials_per_object: int,
    rng: np.random.Generator,
    prior: GaussianBelief | None = None,
    callback: Callable[[TrialOutcome], None] | None = None,
) -> list[TrialOutcome]:
    """``trials_per_object`` simulated trials for every object of the model.

    Args:
        callback: Called after each trial (progress reporting).
    """
    if trials_per_object < 1:
        raise InvalidInputError(f"trials_per_object: must be ≥ 1, received {trials_per_object}.")
    outcomes = []
    for target in range(len(model.object_names)):
        for _ in range(trials_per_object):
            outcome = simulate_trial(model, world, target, planner, prior, settings, rng)
            outcomes.append(outcome)
            if callback is not None:
                callback(outcome)
    return outcomes


def accuracy_by_touch(outcomes: list[TrialOutcome], rule: str = "answer") -> FloatArray:
    """Fraction of trials whose answer after touch t is the target, t = 1..T.

    Args:
        outcomes: Trials with the same T.
        rule: ``"answer"`` (the session's decision rule) or ``"nearest"`` (nearest latent).

    Returns:
        Shape (T,).
    """
    if not outcomes:
        raise InvalidInputError("outcomes: need at least one trial.")
    if rule not in ("answer", "nearest"):
        raise InvalidInputError(f"rule: expected 'answer' or 'nearest', received {rule!r}.")
    table = np.stack([o.answers if rule == "answer" else o.nearest for o in outcomes])
    targets = np.array([o.target for o in outcomes])[:, None]
    return np.asarray((table == targets).mean(axis=0), dtype=np.float64)


def accuracy_per_object(outcomes: list[TrialOutcome], n_objects: int) -> FloatArray:
    """Final accuracy of each target object (the failure mode of METHOD.md is per object).

    Returns:
        Shape (L,); NaN for objects without trials.
    """
    result = np.full(n_objects, np.nan)
    for obj in range(n_objects):
        mine = [o.correct for o in outcomes if o.target == obj]
        if mine:
            result[obj] = float(np.mean(mine))
    return result
