"""Choose the latent dimension ds by cross-validated held-out predictive likelihood.

Two criteria (``criterion``), both fitting K times per candidate ds with the fit passed in:

``"touches"`` (the default): K-fold cross-validation over touches *within* objects. Each
object's touches are dealt to the folds, a model is fitted on K - 1 folds and the held-out
touches are scored by their log-density under their own object's learned latent
(:func:`core.recognition.object_posterior.touch_log_likelihoods`, raw units, Jacobian included).

``"objects"``: leave-objects-out. The objects are dealt to the folds; a model is fitted on the
objects of the other folds and every held-out object is met as a new one: its touches are split
in two halves, its latent is placed from one half by maximising the likelihood over s with the
model fixed (:func:`core.selection.held_out_objects.place_latent`), and the other half is scored at
that latent (:func:`core.selection.held_out_objects.log_densities_at`); then the halves swap, so
every touch is scored exactly once. It asks whether the manifold generalises to a new object, which
is what recognition needs.

The choice is the **smallest ds whose mean score is within one standard error of the best**
(paired over folds: its fold-by-fold difference to the best, mean ≥ -1 s.e.), the
one-standard-error rule of Hastie, Tibshirani & Friedman (§7.10): a larger latent space must
predict held-out touches better by more than the folds' noise. ``best`` keeps the candidate with
the best mean score, and the explanation names both when they differ.

Measured (docs/noise-model.md, ``bench/latent_dim.py``): on Experiment-2-like worlds whose
response the fit can learn and whose objects span the latent space (L = 12 objects × 30
touches, dx = 6, dy = 5, response length-scales 2 along s and 3 along x, 5 folds) the rule
picks the true ds on 17 of 18 worlds (ds = 1: 6 of 6, ds = 2: 6 of 6, ds = 3: 5 of 6; the best
mean on 16: a ds = 1 world went to 2 by 0.020 ± 0.023 nats per touch); leave-objects-out with
the same rule on 18 of 18 (the best mean on 14). On worlds whose response
the fit cannot learn (length-scale 1.5 along x with 6-D actions: fresh touches predicted 12
nats per touch below the truth) or with few objects (L = 8), ds = 3 was rarely found by any
criterion tried; leave-objects-out leaned large there.

Every fold's candidates are fitted nested by default (:mod:`core.selection.nested_fits`): ds = k
starts from the ds = k - 1 optimum too, so the training log-likelihood is non-decreasing in ds.

**Warm folds** (``refit``, ``"touches"`` only; what ``activetouch fit --latent-dim auto`` and the
server use): every candidate is fitted once on *all* the touches
(:func:`core.selection.nested_fits.fit_rung`: one multi-start fit per ds, independent of
each other, then carried over upward by :func:`core.selection.nested_fits.kept_ladder` so
the log-likelihood is non-decreasing in ds), and each fold's model at that ds is that fit
refitted to the fold's training touches from where it stands (one joint run, e.g.
:func:`core.gp.manifold.refit_warm`). Touch folds keep every object, so the latents carry
over; the refit costs a few dozen evaluations instead of a multi-start fit per fold and
candidate, and the full-data fit at the chosen ds is the final model
(:attr:`LatentSelection.models`). What it gives up: the folds are no longer independent
fits. Their optimisation starts where the held-out touches helped to put it (the basin of the
full-data optimum and the observation transform of all the touches); the refit then moves to
the training touches' own optimum nearby, so the held-out touches do not enter the fold's
likelihood, only its starting point. The measurements are in docs/fitting.md.

The folds are independent (each gets its own generator, spawned from the one passed in):
:func:`score_fold` is one fold's work, a pure function, and ``map`` runs them — one after
another by default, or elsewhere (the app runs them as Dask tasks) with the same result. With
warm folds the fits on all the touches and the refits are one :data:`WarmMap`: a refit of
candidate c needs only the fits of ds ≤ dims[c] (:func:`score_warm_fold`), so a map may start
it while larger candidates are still being fitted (the app's Dask engine does: no worker waits
for the slowest fit on all the touches while refits could run).

Pure maths: the fit is a function argument, randomness comes in as a generator.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from core.errors import InvalidInputError
from core.recognition.object_posterior import touch_log_likelihoods
from core.selection.held_out_objects import (
    held_out_scores,
    object_folds,
    objects_subset,
    split_halves,
)
from core.selection.nested_fits import (
    NestedFit,
    RungPlan,
    RungResult,
    RungTask,
    StartedFit,
    fit_rung,
    kept_ladder,
    nested_fits,
    rung_tasks,
)
from core.types import ManifoldModel, TrainingData
from core.validation import FloatArray, IntArray

#: Largest candidate ds tried by default (candidates 1..min(this, L - 1)).
DEFAULT_MAX_LATENT_DIM = 5
DEFAULT_FOLDS = 5

Criterion = Literal["touches", "objects"]
CRITERIA: tuple[Criterion, ...] = ("touches", "objects")

#: About how many warm fold refits one fit on all the touches costs (their evaluations on
#: ``bench/time_to_model.py``'s data, docs/fitting.md): the weight of a fit in progress fractions.
RUNG_COST_IN_REFITS = 12

#: Refits a model to training touches of its own objects, starting from it (the warm folds,
#: module docstring), e.g. :func:`core.gp.manifold.refit_warm` with the fit's options.
WarmRefit = Callable[[TrainingData, ManifoldModel], ManifoldModel]


@dataclass(frozen=True)
class CandidateScore:
    """Cross-validated score of one latent dimension.

    Attributes:
        latent_dim: ds.
        fold_scores: Mean log-density per held-out touch (nats) of each fold.
        mean: Mean of ``fold_scores``.
        standard_error: Standard error of ``mean`` over the folds.
        difference: Mean over folds of this candidate's score minus the best candidate's.
        difference_standard_error: Standard error of ``difference`` (0 for the best).
        fit_log_likelihoods: Log-likelihood of each fold's training fit (with nested fits
            non-decreasing in ds fold by fold).
        carried_over: Folds in which the ds fit ended below the ds - 1 optimum, which was
            kept instead (:mod:`core.selection.nested_fits`; 0 without nesting).
    """

    latent_dim: int
    fold_scores: tuple[float, ...]
    mean: float
    standard_error: float
    difference: float
    difference_standard_error: float
    fit_log_likelihoods: tuple[float, ...] = ()
    carried_over: int = 0


@dataclass(frozen=True)
class LatentSelection:
    """The outcome of :func:`select_latent_dim`.

    Attributes:
        chosen: The chosen ds: the smallest within one standard error of ``best``.
        best: The ds with the best mean held-out score (≥ ``chosen``).
        n_folds: K.
        candidates: Every candidate's scores, in increasing ds.
        explanation: One sentence saying why ``chosen`` was chosen.
        models: With warm folds, every candidate's model fitted on all the touches, in
            increasing ds (excluded from ``==``); empty otherwise.
    """

    chosen: int
    best: int
    n_folds: int
    candidates: tuple[CandidateScore, ...]
    explanation: str
    models: tuple[ManifoldModel, ...] = field(default=(), compare=False)

    @property
    def chosen_model(self) -> ManifoldModel | None:
        """The model at ``chosen`` fitted on all the touches (warm folds), else ``None``."""
        for c, candidate in enumerate(self.candidates):
            if candidate.latent_dim == self.chosen and c < len(self.models):
                return self.models[c]
        return None


def candidate_dims(n_objects: int, max_latent_dim: int = DEFAULT_MAX_LATENT_DIM) -> tuple[int, ...]:
    """1..min(max_latent_dim, L - 1): L objects are placed exactly by L - 1 dimensions."""
    top = min(int(max_latent_dim), int(n_objects) - 1)
    if top < 1:
        raise InvalidInputError(
            f"latent dimension candidates: need L ≥ 2 objects and max_latent_dim ≥ 1, received "
            f"L={n_objects}, max_latent_dim={max_latent_dim}."
        )
    return tuple(range(1, top + 1))


def fold_assignment(object_index: IntArray, n_folds: int, rng: np.random.Generator) -> IntArray:
    """Fold of every touch: each object's touches shuffled and dealt round-robin to K folds.

    Args:
        object_index: Object of every touch. Shape (N,).
        n_folds: K ≥ 2.
        rng: Random generator (the shuffle).

    Returns:
        Fold of every touch, 0..K-1. Shape (N,).

    Raises:
        InvalidInputError: K < 2, or an object with fewer than K + 2 touches (every fold's
            training set needs at least 2 touches of every object and every fold one held-out
            touch of it).
    """
    index = np.asarray(object_index, dtype=np.int64)
    if int(n_folds) < 2:
        raise InvalidInputError(f"n_folds: need at least 2, received {n_folds}.")
    folds = np.empty(index.shape[0], dtype=np.int64)
    for obj in np.unique(index):
        touches = np.flatnonzero(index == obj)
        if touches.shape[0] < n_folds + 2:
            raise InvalidInputError(
                f"cross-validation with {n_folds} folds: object {int(obj)} has "
                f"{touches.shape[0]} touches, at least {n_folds + 2} are needed."
            )
        folds[rng.permutation(touches)] = np.arange(touches.shape[0]) % n_folds
    return folds


def _subset(data: TrainingData, keep: IntArray) -> TrainingData:
    return TrainingData(
        object_names=data.object_names,
        object_index=data.object_index[keep],
        actions=data.actions[keep],
        observations=data.observations[keep],
    )


@dataclass(frozen=True)
class FoldPlan:
    """What every fold of one cross-validation shares (sent to a worker once).

    Attributes:
        data: Raw training touches.
        folds: Fold of every touch (``"touches"``) or of every object (``"objects"``).
            Shape (N,) or (L,).
        halves: Half (0 or 1) of every touch, for ``"objects"``; ``None`` for ``"touches"``.
            Shape (N,).
        dims: The candidate ds, increasing.
        criterion: ``"touches"`` or ``"objects"``.
        nested: Whether each fold's candidates are fitted nested
            (:mod:`core.selection.nested_fits`).
        fit: The fit (:data:`core.selection.nested_fits.StartedFit`).
        ladder: Warm folds: every candidate's fit on all the touches, in the order of
            ``dims`` (:func:`core.selection.nested_fits.kept_ladder`); empty otherwise (and
            in the plan a :data:`WarmMap` is given, whose tasks bring their rungs).
        refit: Warm folds: refits a ladder model to a fold's training touches.
    """

    data: TrainingData
    folds: IntArray
    halves: IntArray | None
    dims: tuple[int, ...]
    criterion: Criterion
    nested: bool
    fit: StartedFit
    ladder: tuple[NestedFit, ...] = ()
    refit: WarmRefit | None = None


@dataclass(frozen=True)
class FoldTask:
    """One fold's work: its index and its own random generator (folds are independent).

    Attributes:
        fold: The fold's index.
        rng: The fold's generator.
        rows: Warm folds only: the candidates (indices into ``FoldPlan.dims``) this task
            refits and scores, so one fold's candidates can run as separate tasks; ``None``:
            every candidate.
    """

    fold: int
    rng: np.random.Generator
    rows: tuple[int, ...] | None = None


@dataclass(frozen=True)
class FoldResult:
    """The outcome of a fold's candidates (:attr:`rows`, in the order of ``FoldPlan.dims``).

    Attributes:
        fold: The fold's index.
        scores: Mean log-density per held-out touch (nats) of every candidate of ``rows``.
        fit_log_likelihoods: Log-likelihood of each one's training fit.
        carried_over: Whether each one's fit was carried over from ds - 1.
        rows: The candidates (indices into ``FoldPlan.dims``); ``None``: all of them.
    """

    fold: int
    scores: tuple[float, ...]
    fit_log_likelihoods: tuple[float, ...]
    carried_over: tuple[bool, ...]
    rows: tuple[int, ...] | None = None


#: Runs ``score_fold(plan, task)`` for every task, yielding the results in any order (serially
#: by default, :func:`serial_map`; the app supplies one that runs them as Dask tasks).
FoldMap = Callable[[FoldPlan, Sequence[FoldTask]], Iterable[FoldResult]]


def score_fold(plan: FoldPlan, task: FoldTask) -> FoldResult:
    """Fit every candidate (of ``task.rows``, warm folds) on the training part of one fold and
    score its held-out part.

    A pure function of the plan and the task: where it runs does not change its result.

    Raises:
        InvalidInputError: ``task.rows`` without warm folds (nested candidates depend on each
            other), or a row out of range.
    """
    data, k = plan.data, task.fold
    rows = tuple(range(len(plan.dims))) if task.rows is None else task.rows
    if task.rows is not None and not plan.ladder:
        raise InvalidInputError("rows: only warm folds score a fold's candidates separately.")
    if any(not 0 <= row < len(plan.dims) for row in rows):
        raise InvalidInputError(f"rows: expected indices into {len(plan.dims)} candidates.")
    held = np.flatnonzero(plan.folds == k)
    if plan.criterion == "objects":
        train = objects_subset(data, np.flatnonzero(plan.folds != k))
    else:
        train = _subset(data, np.flatnonzero(plan.folds != k))
    scores, fitted, carried = [], [], []
    if plan.ladder:
        assert plan.refit is not None
        models: Iterable[tuple[int, int, ManifoldModel, bool]] = (
            (c, plan.dims[c], plan.refit(train, plan.ladder[c].model), plan.ladder[c].carried_over)
            for c in rows
        )
    else:
        models = _fold_models(train, plan.dims, plan.fit, task.rng, plan.nested)
    for _, _, model, was_carried in models:
        if plan.criterion == "objects":
            assert plan.halves is not None
            values = held_out_scores(model, data, held, plan.halves)
        else:
            values = touch_log_likelihoods(
                model, data.object_index[held], data.actions[held], data.observations[held]
            )
        scores.append(float(values.mean()))
        fitted.append(float(model.log_likelihood))
        carried.append(bool(was_carried))
    return FoldResult(k, tuple(scores), tuple(fitted), tuple(carried), task.rows)


def serial_map(plan: FoldPlan, tasks: Sequence[FoldTask]) -> Iterator[FoldResult]:
    """The folds one after another, in this process."""
    for task in tasks:
        yield score_fold(plan, task)


def score_warm_fold(plan: FoldPlan, task: FoldTask, rungs: Sequence[RungResult]) -> FoldResult:
    """One warm fold's candidate (``task.rows`` = (c,)) from the fits on all the touches of
    ds ≤ dims[c] (``rungs``, in any order): the model kept at dims[c]
    (:func:`core.selection.nested_fits.kept_ladder`) refitted to the fold's training touches
    and scored (:func:`score_fold`). A pure function of its arguments.

    Raises:
        InvalidInputError: ``task.rows`` is not one candidate, or ``rungs`` are not the fits
            of ds = dims[0] … dims[c].
    """
    if task.rows is None or len(task.rows) != 1:
        raise InvalidInputError("rows: a warm fold task scores exactly one candidate.")
    (c,) = task.rows
    ordered = sorted(rungs, key=lambda r: r.latent_dim)
    if [r.latent_dim for r in ordered] != list(plan.dims[: c + 1]):
        raise InvalidInputError(
            f"rungs: expected the fits of ds = {list(plan.dims[: c + 1])}, received "
            f"{[r.latent_dim for r in ordered]}."
        )
    ladder = kept_ladder([r.model for r in ordered])
    return score_fold(dataclasses.replace(plan, ladder=ladder), task)


#: Runs a warm selection's fits on all the touches (``fit_rung(rung_plan, task)`` of every rung
#: task) and its refits (``score_warm_fold(fold_plan, task, rungs)`` of every fold task, with
#: the rung results of ds ≤ its candidate's), yielding every result as it comes, in any order
#: (:func:`serial_warm_map`; the app's runs them as Dask tasks, a refit as soon as its rungs are
#: done). ``fold_plan.ladder`` is empty: the rungs come with the tasks.
WarmMap = Callable[
    [RungPlan, Sequence[RungTask], FoldPlan, Sequence[FoldTask]],
    Iterable[RungResult | FoldResult],
]


def serial_warm_map(
    rung_plan: RungPlan,
    rungs: Sequence[RungTask],
    fold_plan: FoldPlan,
    folds: Sequence[FoldTask],
) -> Iterator[RungResult | FoldResult]:
    """Every fit on all the touches, then every refit, one after another in this process."""
    fitted: list[RungResult] = []
    for task in rungs:
        result = fit_rung(rung_plan, task)
        fitted.append(result)
        yield result
    by_dim = sorted(fitted, key=lambda r: r.latent_dim)
    ladder = kept_ladder([r.model for r in by_dim])
    plan = dataclasses.replace(fold_plan, ladder=ladder)
    for fold_task in folds:
        yield score_fold(plan, fold_task)


def select_latent_dim(
    data: TrainingData,
    fit: StartedFit,
    rng: np.random.Generator,
    candidates: Sequence[int] | None = None,
    n_folds: int = DEFAULT_FOLDS,
    callback: Callable[[int, int, float], None] | None = None,
    criterion: Criterion = "touches",
    nested: bool = True,
    map: FoldMap = serial_map,
    refit: WarmRefit | None = None,
    warm_map: WarmMap = serial_warm_map,
    rung_callback: Callable[[int, float], None] | None = None,
) -> LatentSelection:
    """Choose ds by cross-validation (module docstring).

    Args:
        data: Raw training touches.
        fit: Fits a model to training touches at a latent dimension, with extra starting
            latents (each (L, ds), e.g. passed on as ``FitOptions.initial_latents``) and the
            fold's random generator (raw data in, a model that maps raw observations itself
            out, e.g. with a noise model).
        rng: Random generator (the folds, the halves for ``"objects"``, and one independent
            generator per fold, spawned from it, for the nested starts and the fits).
        candidates: The ds to try; default :func:`candidate_dims` (of the smallest training
            set for ``"objects"``).
        n_folds: K ≥ 2; for ``"objects"`` lowered to L when there are fewer objects.
        callback: Called with (ds, fold, score) for every candidate of a fold when it is
            scored (in the order the tasks finish: a fold at a time, or with warm folds a fold
            and candidate at a time).
        criterion: ``"touches"`` (within objects) or ``"objects"`` (leave-objects-out).
        nested: Fit every fold's ds = 1..max(candidates) nested
            (:func:`core.selection.nested_fits.nested_fits`: each from the one below, then each
            smaller one again from the one above, so the training log-likelihood is non-decreasing
            in ds); ``False``: every candidate on its own, with no extra starts.
        map: Runs the folds (:data:`FoldMap`); the folds are independent, so the result does
            not depend on how or where they run.
        refit: Warm folds (module docstring; ``"touches"`` only): every candidate is fitted
            once on all the touches with ``fit`` and each fold's model is that one refitted by
            ``refit`` to the fold's training touches; ``nested`` is then not used.
        warm_map: Runs the warm folds' fits on all the touches and their refits
            (:data:`WarmMap`; pure functions, so where and in what order they run does not
            change the result).
        rung_callback: Called with (ds, log-likelihood) as each fit on all the touches ends
            (warm folds).

    Returns:
        The scores and the choice. Cost: K · len(candidates) fits (K · (2 max(candidates) - 1)
        when nested; plus, for ``"objects"``, two latent placements per held-out object and
        candidate); with warm folds len(candidates) fits on all the touches and K ·
        len(candidates) refits.

    Raises:
        InvalidInputError: Bad criterion, candidates or folds (too few touches or objects),
            or ``refit`` with ``"objects"``.
    """
    if criterion not in CRITERIA:
        raise InvalidInputError(
            f"criterion: expected one of {', '.join(CRITERIA)}, received {criterion!r}."
        )
    if refit is not None and criterion != "touches":
        raise InvalidInputError(
            "refit: warm folds need every object in every fold's training touches "
            f"(criterion 'touches'), received criterion {criterion!r}."
        )
    halves: IntArray | None = None
    if criterion == "objects":
        n_folds = min(int(n_folds), data.n_objects)
        folds = object_folds(data.n_objects, n_folds, rng)
        halves = split_halves(data.object_index, rng)
        n_models = data.n_objects - int(np.bincount(folds).max())
    else:
        folds = fold_assignment(data.object_index, n_folds, rng)
        n_models = data.n_objects
    dims = tuple(candidates) if candidates is not None else candidate_dims(n_models)
    if not dims or any(int(d) != d or d < 1 for d in dims) or len(set(dims)) != len(dims):
        raise InvalidInputError(
            f"candidates: expected distinct integers ≥ 1, received {list(dims)}."
        )
    dims = tuple(sorted(int(d) for d in dims))
    tasks = [FoldTask(k, fold_rng) for k, fold_rng in enumerate(rng.spawn(n_folds))]
    plan = FoldPlan(data, folds, halves, dims, criterion, nested, fit, (), refit)
    scores = np.full((len(dims), n_folds), np.nan)
    fitted = np.full((len(dims), n_folds), np.nan)
    carried = np.zeros(len(dims), dtype=np.int64)
    results: Iterable[RungResult | FoldResult]
    rung_models: dict[int, ManifoldModel] = {}
    if refit is not None:
        # One task per fold and candidate (the refits are independent): the last tasks of a
        # run are one refit each, not a fold's five, so no worker waits long for the others.
        tasks = [dataclasses.replace(task, rows=(c,)) for task in tasks for c in range(len(dims))]
        results = warm_map(RungPlan(data, fit), rung_tasks(dims, rng), plan, tasks)
    else:
        results = map(plan, tasks)
    for result in results:
        if isinstance(result, RungResult):
            rung_models[result.latent_dim] = result.model
            if rung_callback is not None:
                rung_callback(result.latent_dim, float(result.model.log_likelihood))
            continue
        k = result.fold
        rows = list(range(len(dims))) if result.rows is None else list(result.rows)
        scores[rows, k] = result.scores
        fitted[rows, k] = result.fit_log_likelihoods
        carried[rows] += np.asarray(result.carried_over, dtype=np.int64)
        if callback is not None:
            for c in rows:
                callback(dims[c], k, float(scores[c, k]))
    missing = np.flatnonzero(np.isnan(scores).any(axis=0))
    if missing.size:
        raise InvalidInputError(
            f"map: no result for fold(s) {', '.join(str(int(k)) for k in missing)}."
        )
    ladder: tuple[NestedFit, ...] = ()
    if refit is not None:
        missing_dims = [ds for ds in dims if ds not in rung_models]
        if missing_dims:
            raise InvalidInputError(
                f"warm_map: no fit for ds = {', '.join(str(d) for d in missing_dims)}."
            )
        ladder = kept_ladder([rung_models[ds] for ds in dims])
    selection = _summarise(dims, scores, criterion)
    return dataclasses.replace(
        selection,
        models=tuple(rung.model for rung in ladder),
        candidates=tuple(
            dataclasses.replace(
                r,
                fit_log_likelihoods=tuple(float(v) for v in fitted[c]),
                carried_over=int(carried[c]),
            )
            for c, r in enumerate(selection.candidates)
        ),
    )


def _fold_models(
    train: TrainingData,
    dims: tuple[int, ...],
    fit: StartedFit,
    rng: np.random.Generator,
    nested: bool,
) -> Iterator[tuple[int, int, ManifoldModel, bool]]:
    """(row, ds, model, carried over) of every candidate fitted on ``train``, in order."""
    if not nested:
        for c, ds in enumerate(dims):
            yield c, ds, fit(train, ds, (), rng), False
        return
    rungs = nested_fits(train, max(dims), fit, rng)
    for c, ds in enumerate(dims):
        yield c, ds, rungs[ds - 1].model, rungs[ds - 1].carried_over


def _summarise(dims: tuple[int, ...], scores: FloatArray, criterion: Criterion) -> LatentSelection:
    """Means, standard errors, paired differences and the choice from (candidate, fold) scores."""
    n_folds = scores.shape[1]
    means = scores.mean(axis=1)
    best_row = int(np.argmax(means))
    root_k = np.sqrt(n_folds)
    results = []
    for c, ds in enumerate(dims):
        difference = scores[c] - scores[best_row]
        results.append(
            CandidateScore(
                latent_dim=ds,
                fold_scores=tuple(float(v) for v in scores[c]),
                mean=float(means[c]),
                standard_error=float(scores[c].std(ddof=1) / root_k),
                difference=float(difference.mean()),
                difference_standard_error=float(difference.std(ddof=1) / root_k),
            )
        )
    # The smallest ds within one standard error of the best (paired over folds); exact ties
    # (within round-off) count as within.
    tolerance = 1e-9 * (1.0 + abs(float(means.max())))
    best = results[best_row]
    chosen = next(r for r in results if r.difference >= -r.difference_standard_error - tolerance)
    what = (
        "held-out objects' touches, each object placed from half its touches and scored on "
        "the other half"
        if criterion == "objects"
        else "held-out touches"
    )
    if chosen is best:
        explanation = (
            f"ds = {chosen.latent_dim}: the best mean log-likelihood of {what} "
            f"({chosen.mean:.3f} ± {chosen.standard_error:.3f} nats per touch over {n_folds} "
            "folds)"
        )
        if chosen.latent_dim > dims[0]:
            explanation += (
                "; every smaller ds is worse by more than one standard error (paired over folds)."
            )
        else:
            explanation += "; every larger ds predicts held-out touches worse."
    else:
        explanation = (
            f"ds = {chosen.latent_dim}: the smallest ds within one standard error of the best, "
            f"ds = {best.latent_dim} (log-likelihood of {what} {-chosen.difference:.3f} ± "
            f"{chosen.difference_standard_error:.3f} nats per touch below it, paired over "
            f"{n_folds} folds); the larger latent space does not predict better by more than "
            "the folds' noise."
        )
    return LatentSelection(
        chosen=chosen.latent_dim,
        best=results[best_row].latent_dim,
        n_folds=int(n_folds),
        candidates=tuple(results),
        explanation=explanation,
    )
