"""An adaptive training design: the next round of collection touches, chosen from a model.

A random design's touches lie near its centre, while the planners' touches in a trial lie where
the objects' predictions differ most, often far out (docs/diagnosis.md: active's touches 1.6-1.7
training spreads out on the cushions), where the GP extrapolates. After an initial random design
and a fit, a round touches every object at the actions the planners would choose from the
current model, so the next fit has data where the trials go; the rounds replace part of the
random design's budget, not add to it.

The planners' choices are scored on one scrambled Sobol candidate set in the planners' own box
(:meth:`core.recognition.planning.ActionBox.from_model`), for the situations a trial meets:

- ``active`` at the first touch: the mutual information (M4) under the trial's initial belief
  (:func:`core.recognition.session.default_prior`);
- ``discriminative`` at the first touch: the information about the object's identity under
  uniform object probabilities;
- ``discriminative`` late in a trial, torn between two objects l and m: the same with
  p_l = p_m = ½, for every pair.

The situations take turns, each taking its best candidate not yet taken, until the round has
its actions; every object is touched with every one of them (a shared round).
"""

from __future__ import annotations

from itertools import combinations

import numpy as np

from core.errors import InvalidInputError
from core.evaluation.designs import CollectionDesign
from core.recognition.moments import (
    action_statistics,
    belief_terms,
    moments_from_terms,
    mutual_information,
)
from core.recognition.object_information import label_information_mc, object_predictives
from core.recognition.planning import ActionBox, DiscriminativePolicy, sobol_candidates
from core.recognition.session import default_prior
from core.types import ManifoldModel
from core.validation import FloatArray, as_float_array


def situation_scores(model: ManifoldModel, candidates: FloatArray) -> FloatArray:
    """How much each planner situation wants each candidate. Shape (S, C).

    Rows: active's mutual information under :func:`~core.recognition.session.default_prior`, then
    the discriminative information about the object under uniform probabilities, then under
    p = ½ on each pair (l, m), l < m, in lexicographic order (S = 2 + L(L − 1)/2).

    Args:
        model: A conditioned model.
        candidates: Candidate actions. Shape (C, dx).
    """
    dx, dy = model.hyperparameters.action_dim, model.hyperparameters.observation_dim
    candidates = as_float_array(candidates, "candidates", (None, dx))
    stats = action_statistics(model, candidates)
    belief = default_prior(model)
    rows = [
        mutual_information(moments_from_terms(model, belief_terms(model, belief), stats), belief)
    ]
    # The discriminative planner's estimate, with its common random numbers.
    mean, variance = object_predictives(model, stats)
    draws = np.random.default_rng(0).standard_normal((DiscriminativePolicy().n_draws, dy))
    n_objects = model.data.n_objects
    rows.append(label_information_mc(np.full(n_objects, 1.0 / n_objects), mean, variance, draws))
    for a, b in combinations(range(n_objects), 2):
        p = np.zeros(n_objects)
        p[[a, b]] = 0.5
        rows.append(label_information_mc(p, mean, variance, draws))
    return np.asarray(np.vstack(rows), dtype=np.float64)


def take_in_turns(scores: FloatArray, n_actions: int) -> list[int]:
    """Candidates chosen by letting each situation take its best untaken one in turn.

    Args:
        scores: Score of every candidate in every situation. Shape (S, C).
        n_actions: How many to choose (≤ C).

    Returns:
        ``n_actions`` distinct candidate indices, in the order they were taken.
    """
    scores = as_float_array(scores, "scores", (None, None))
    n_situations, n_candidates = scores.shape
    if not 1 <= n_actions <= n_candidates:
        raise InvalidInputError(
            f"n_actions: must be between 1 and the {n_candidates} candidates, received {n_actions}."
        )
    orders = [list(np.argsort(-row, kind="stable")) for row in scores]
    taken: list[int] = []
    chosen: set[int] = set()
    situation = 0
    while len(taken) < n_actions:
        order = orders[situation % n_situations]
        while order and order[0] in chosen:
            order.pop(0)
        if order:
            index = int(order.pop(0))
            taken.append(index)
            chosen.add(index)
        situation += 1
    return taken


def planner_round(
    model: ManifoldModel,
    n_actions: int,
    rng: np.random.Generator,
    n_candidates: int = 512,
) -> CollectionDesign:
    """The next round: ``n_actions`` planner-chosen actions, each on every object.

    Args:
        model: The model fitted to the touches so far.
        n_actions: Actions of the round (each object is touched once with each).
        rng: Seeds the candidate set's scrambling (a new set every round).
        n_candidates: Sobol candidates scored in the planners' box.

    Returns:
        A shared design: object l's touches are rows ``l·n_actions … (l + 1)·n_actions − 1``.
    """
    if n_candidates < n_actions:
        raise InvalidInputError(
            f"n_candidates: must be ≥ n_actions ({n_actions}), received {n_candidates}."
        )
    box = ActionBox.from_model(model)
    candidates = sobol_candidates(box, n_candidates, int(rng.integers(2**31)))
    chosen = candidates[take_in_turns(situation_scores(model, candidates), n_actions)]
    n_objects = model.data.n_objects
    return CollectionDesign(
        object_index=np.repeat(np.arange(n_objects, dtype=np.int64), n_actions),
        actions=np.tile(chosen, (n_objects, 1)),
        shared=True,
    )


def round_sizes(touches: int, initial: int, rounds: int) -> list[int]:
    """Touches per object of each adaptive round: ``touches − initial`` split as evenly as can be.

    Raises:
        InvalidInputError: ``initial`` not in [2, touches), or fewer than one touch per round.
    """
    if not 2 <= initial < touches:
        raise InvalidInputError(
            f"initial: the random design needs 2 touches per object or more and fewer than "
            f"the {touches} in all, received {initial}."
        )
    rest = touches - initial
    if not 1 <= rounds <= rest:
        raise InvalidInputError(
            f"rounds: must be between 1 and the {rest} touches per object left after the "
            f"initial design, received {rounds}."
        )
    return [rest // rounds + (1 if k < rest % rounds else 0) for k in range(rounds)]
