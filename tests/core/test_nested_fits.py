"""Nested warm starts over the latent dimension and the ladder of fits on all the touches
(core/selection/nested_fits.py), and their use in cross-validation, warm folds included
(core/selection/latent_selection.py)."""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Iterator, Sequence

import numpy as np
import pytest

from core.errors import InvalidInputError
from core.evaluation.worlds import random_experiment2_world, sample_dataset
from core.gp.manifold import FitOptions, fit_manifold, refit_warm
from core.gp.posterior import condition
from core.recognition.object_posterior import touch_log_likelihoods
from core.selection.latent_selection import (
    FoldPlan,
    FoldResult,
    FoldTask,
    fold_assignment,
    score_fold,
    score_warm_fold,
    select_latent_dim,
    serial_warm_map,
)
from core.selection.nested_fits import (
    NestedFit,
    RungPlan,
    RungResult,
    RungTask,
    StartedFit,
    appended_starts,
    embed_model,
    fit_rung,
    kept_ladder,
    nested_fits,
    projected_start,
    rung_tasks,
)
from core.types import Hyperparameters, ManifoldModel, TrainingData

Starts = tuple[np.ndarray, ...]
OPTIONS = FitOptions(restarts=0, max_iterations=300)


def small_world(latent_dim: int = 2, seed: int = 3) -> TrainingData:
    rng = np.random.default_rng(seed)
    world = random_experiment2_world(
        rng, n_objects=6, latent_dim=latent_dim, action_dim=1, observation_dim=2
    )
    return sample_dataset(world, rng, touches_per_object=8)


@pytest.mark.parametrize("downward", [False, True])
def test_nested_fits_are_monotone_and_receive_the_nested_starts(downward: bool) -> None:
    data = small_world()
    received: list[tuple[int, Starts, float]] = []

    def fit(train: TrainingData, ds: int, starts: Starts, rng: object) -> ManifoldModel:
        options = dataclasses.replace(OPTIONS, initial_latents=starts)
        model = fit_manifold(train, ds, np.random.default_rng(ds), options)
        received.append((ds, starts, model.log_likelihood))
        return model

    rungs = nested_fits(data, 3, fit, np.random.default_rng(0), downward=downward)
    values = [r.model.log_likelihood for r in rungs]
    assert [r.model.latent_dim for r in rungs] == [1, 2, 3]
    assert all(b >= a - 1e-8 * abs(a) for a, b in itertools.pairwise(values))
    assert [ds for ds, _, _ in received] == ([1, 2, 3, 2, 1] if downward else [1, 2, 3])
    assert received[0][1] == ()
    for ds, starts, _ in received[1:3]:  # upward: one coordinate appended to the rung below
        assert len(starts) in (1, 2)
        assert all(start.shape == (6, ds) for start in starts)
        np.testing.assert_array_equal(starts[0][:, :-1], starts[-1][:, :-1])
    for ds, starts, value in received[3:]:  # downward: one start, projected from above
        assert len(starts) == 1
        assert starts[0].shape == (6, ds)
        kept = rungs[ds - 1]
        assert kept.model.log_likelihood >= value - 1e-8 * abs(value)  # the better one kept
    for rung in rungs:
        if rung.carried_over:
            assert not rung.from_above
        else:
            assert rung.model.log_likelihood == rung.fitted_log_likelihood


def test_a_fit_that_ends_lower_is_replaced_by_the_embedded_optimum_below() -> None:
    data = small_world()
    one = fit_manifold(data, 1, np.random.default_rng(0), OPTIONS)
    bad = Hyperparameters(
        signal_variance=np.full(2, 1.0),
        noise_variance=np.full(2, 1.0),  # everything explained as noise: far lower likelihood
        latent_lengthscales=np.full((2, 2), 1.0),
        action_lengthscales=np.full((2, 1), 1.0),
    )

    def fit(train: TrainingData, ds: int, starts: Starts, rng: object) -> ManifoldModel:
        if ds == 1:
            return one
        return condition(train, np.random.default_rng(1).standard_normal((6, 2)), bad)

    rungs = nested_fits(data, 2, fit, np.random.default_rng(0), downward=False)
    assert rungs[1].carried_over
    assert rungs[1].fitted_log_likelihood < one.log_likelihood
    assert rungs[1].model.latent_dim == 2
    assert rungs[1].model.log_likelihood == pytest.approx(one.log_likelihood, rel=1e-10)


@pytest.mark.parametrize("noise_model", [None, "correlated"])
def test_embedding_keeps_predictions_and_likelihood(noise_model: str | None) -> None:
    data = small_world(seed=4)
    model = fit_manifold(data, 2, np.random.default_rng(0), OPTIONS, noise_model=noise_model)  # type: ignore[arg-type]
    embedded = embed_model(model)
    assert embedded.latent_dim == 3
    np.testing.assert_array_equal(embedded.latents[:, 2], 0.0)
    assert embedded.log_likelihood == pytest.approx(model.log_likelihood, rel=1e-10, abs=1e-8)
    assert embedded.transform is model.transform
    before = touch_log_likelihoods(model, data.object_index, data.actions, data.observations)
    after = touch_log_likelihoods(embedded, data.object_index, data.actions, data.observations)
    np.testing.assert_allclose(after, before, rtol=1e-9, atol=1e-9)


def test_appended_coordinates_are_small_random_and_the_unexplained_direction() -> None:
    data = small_world(latent_dim=2)
    one = fit_manifold(data, 1, np.random.default_rng(0), OPTIONS)
    starts = appended_starts(one, np.random.default_rng(5))
    assert len(starts) == 2
    random_column, residual_column = starts[0][:, 1], starts[1][:, 1]
    assert np.sqrt(np.mean(random_column**2)) == pytest.approx(0.1, rel=1e-12)
    assert random_column.mean() == pytest.approx(0.0, abs=1e-12)
    # The residual direction is uncorrelated with the latents it extends (least-squares residual).
    assert residual_column.mean() == pytest.approx(0.0, abs=1e-10)
    assert float(residual_column @ one.latents[:, 0]) == pytest.approx(0.0, abs=1e-10)
    assert np.sqrt(np.mean(residual_column**2)) >= 0.1 - 1e-12
    with pytest.raises(InvalidInputError, match="top_dim"):
        nested_fits(data, 0, lambda t, d, s, r: one, np.random.default_rng(0))


def test_cross_validation_fits_are_nested_in_every_fold() -> None:
    data = small_world()

    def fit(train: TrainingData, ds: int, starts: Starts, rng: object) -> ManifoldModel:
        options = dataclasses.replace(OPTIONS, initial_latents=starts)
        return fit_manifold(train, ds, np.random.default_rng(0), options)

    selection = select_latent_dim(data, fit, np.random.default_rng(1), (1, 2, 3), n_folds=3)
    fitted = np.array([c.fit_log_likelihoods for c in selection.candidates])  # (ds, fold)
    assert fitted.shape == (3, 3)
    assert np.all(np.diff(fitted, axis=0) >= -1e-8 * np.abs(fitted[:-1]))
    assert all(c.carried_over >= 0 for c in selection.candidates)
    assert selection.candidates[0].carried_over == 0


def test_projected_start_keeps_the_leading_directions() -> None:
    data = small_world()
    two = fit_manifold(data, 2, np.random.default_rng(0), OPTIONS)
    start = projected_start(two, 1)
    centred = two.latents - two.latents.mean(axis=0)
    # The projection onto the leading direction keeps the largest share of the spread.
    assert start.shape == (6, 1)
    best = max(
        float(np.sum((centred @ np.array([np.cos(a), np.sin(a)])) ** 2))
        for a in np.linspace(0, np.pi, 721)
    )
    assert float(np.sum(start**2)) == pytest.approx(best, rel=1e-4)


def _ladder(
    data: TrainingData,
    dims: tuple[int, ...],
    fit: StartedFit,
    rng: np.random.Generator,
    seen: list[tuple[int, float]] | None = None,
) -> tuple[NestedFit, ...]:
    """The ladder as a warm selection fits it: one task per ds, each fitted on its own, then
    the optima kept upward."""
    results = [fit_rung(RungPlan(data, fit), task) for task in rung_tasks(dims, rng)]
    if seen is not None:
        seen.extend((r.latent_dim, float(r.model.log_likelihood)) for r in results)
    return kept_ladder([r.model for r in results])


def test_ladder_fits_every_ds_on_its_own_and_carries_lower_optima_over() -> None:
    data = small_world()
    calls: list[tuple[int, Starts, int]] = []

    def fit(
        train: TrainingData, ds: int, starts: Starts, rng: np.random.Generator
    ) -> ManifoldModel:
        calls.append((ds, starts, int(rng.integers(2**31))))
        if ds == 2:  # stopped after one iteration: ends below the ds = 1 optimum
            return fit_manifold(train, ds, rng, dataclasses.replace(OPTIONS, max_iterations=1))
        return fit_manifold(train, ds, rng, OPTIONS)

    seen: list[tuple[int, float]] = []
    rungs = _ladder(data, (3, 1, 2), fit, np.random.default_rng(0), seen)
    assert [ds for ds, _, _ in calls] == [1, 2, 3]  # in increasing ds
    assert all(starts == () for _, starts, _ in calls)  # no fit starts from another
    assert len({draw for _, _, draw in calls}) == 3  # each its own generator
    assert [ds for ds, _ in seen] == [1, 2, 3]
    assert [r.model.latent_dim for r in rungs] == [1, 2, 3]
    assert rungs[1].carried_over
    assert rungs[1].fitted_log_likelihood == seen[1][1] < rungs[0].model.log_likelihood
    assert rungs[1].model.log_likelihood == pytest.approx(rungs[0].model.log_likelihood, rel=1e-10)
    values = [r.model.log_likelihood for r in rungs]
    assert all(b >= a - 1e-8 * abs(a) for a, b in itertools.pairwise(values))
    # The same generator gives the same fits, whatever runs them.
    again = _ladder(data, (1, 2, 3), fit, np.random.default_rng(0))
    assert [r.model.log_likelihood for r in again] == values
    with pytest.raises(InvalidInputError, match="dims"):
        _ladder(data, (0, 1), fit, np.random.default_rng(0))


def test_a_gap_in_the_candidates_is_embedded_once_per_missing_dimension() -> None:
    data = small_world()
    one = fit_manifold(data, 1, np.random.default_rng(0), OPTIONS)
    bad = Hyperparameters(
        signal_variance=np.full(2, 1.0),
        noise_variance=np.full(2, 1.0),  # everything explained as noise: far lower likelihood
        latent_lengthscales=np.full((2, 3), 1.0),
        action_lengthscales=np.full((2, 1), 1.0),
    )

    def fit(train: TrainingData, ds: int, starts: Starts, rng: object) -> ManifoldModel:
        if ds == 1:
            return one
        return condition(train, np.random.default_rng(1).standard_normal((6, 3)), bad)

    rungs = _ladder(data, (1, 3), fit, np.random.default_rng(0))
    assert rungs[1].carried_over
    assert rungs[1].model.latent_dim == 3
    np.testing.assert_array_equal(rungs[1].model.latents[:, 1:], 0.0)
    assert rungs[1].model.log_likelihood == pytest.approx(one.log_likelihood, rel=1e-10)


def test_warm_folds_refit_the_fit_on_all_the_touches_to_each_fold() -> None:
    data = small_world()
    fits: list[ManifoldModel] = []

    def fit(
        train: TrainingData, ds: int, starts: Starts, rng: np.random.Generator
    ) -> ManifoldModel:
        model = fit_manifold(train, ds, rng, OPTIONS, noise_model="independent")
        fits.append(model)
        return model

    refits: list[tuple[TrainingData, ManifoldModel, ManifoldModel]] = []

    def refit(train: TrainingData, model: ManifoldModel) -> ManifoldModel:
        refitted = refit_warm(train, model, OPTIONS)
        refits.append((train, model, refitted))
        return refitted

    selection = select_latent_dim(
        data, fit, np.random.default_rng(1), (1, 2), n_folds=3, refit=refit
    )
    assert [f.data.n_touches for f in fits] == [data.n_touches] * 2  # one fit per ds, all touches
    assert [m.latent_dim for m in selection.models] == [1, 2]
    assert selection.chosen_model is selection.models[selection.chosen - 1]
    assert len(refits) == 3 * 2
    folds = fold_assignment(data.object_index, 3, np.random.default_rng(1))
    by_fold = {}
    for train, start, refitted in refits:
        # Every fold's model starts from the fit on all the touches at its ds ...
        assert any(start is m for m in selection.models)
        assert train.n_objects == data.n_objects
        # ... and is fitted to the fold's training touches only.
        k = next(
            k
            for k in range(3)
            if train.n_touches == int(np.sum(folds != k))
            and np.array_equal(train.actions, data.actions[folds != k])
        )
        by_fold.setdefault(k, []).append(refitted)
    for c, candidate in enumerate(selection.candidates):
        for k in range(3):
            held = folds == k
            model = by_fold[k][c]
            expected = touch_log_likelihoods(
                model, data.object_index[held], data.actions[held], data.observations[held]
            ).mean()
            assert candidate.fold_scores[k] == pytest.approx(expected, rel=1e-12)
            assert candidate.fit_log_likelihoods[k] == model.log_likelihood
    with pytest.raises(InvalidInputError, match="touches"):
        select_latent_dim(
            data, fit, np.random.default_rng(1), (1, 2), n_folds=3, refit=refit, criterion="objects"
        )


def _independent_fit(
    train: TrainingData, ds: int, starts: Starts, rng: np.random.Generator
) -> ManifoldModel:
    """A fold's fit at ds with the independent noise model (no extra starts used)."""
    return fit_manifold(train, ds, rng, OPTIONS, noise_model="independent")


def _warm_refit(train: TrainingData, model: ManifoldModel) -> ManifoldModel:
    """A warm refit with the tests' options."""
    return refit_warm(train, model, OPTIONS)


def test_warm_folds_run_one_task_per_fold_and_candidate_with_the_whole_folds_scores() -> None:
    data = small_world()

    seen: list[FoldTask] = []
    plans: list[FoldPlan] = []
    rung_results: list[RungResult] = []

    def recording_map(
        rung_plan: RungPlan,
        rungs: Sequence[RungTask],
        plan: FoldPlan,
        tasks: Sequence[FoldTask],
    ) -> list[RungResult | FoldResult]:
        plans.append(plan)
        seen.extend(tasks)
        results = list(serial_warm_map(rung_plan, rungs, plan, tasks))
        rung_results.extend(r for r in results if isinstance(r, RungResult))
        return results[::-1]  # in any order

    selection = select_latent_dim(
        data,
        _independent_fit,
        np.random.default_rng(1),
        (1, 2),
        n_folds=3,
        refit=_warm_refit,
        warm_map=recording_map,
    )
    assert sorted((t.fold, t.rows) for t in seen) == [(k, (c,)) for k in range(3) for c in range(2)]
    # The same generator for a fold's tasks; each fold its own.
    assert len({id(t.rng) for t in seen}) == 3
    [plan] = plans
    assert plan.ladder == ()  # the rungs come with the tasks
    ordered = sorted(rung_results, key=lambda r: r.latent_dim)
    plan = dataclasses.replace(plan, ladder=kept_ladder([r.model for r in ordered]))
    for k in range(3):
        whole = score_fold(plan, FoldTask(k, np.random.default_rng(0)))
        assert whole.rows is None
        for c, candidate in enumerate(selection.candidates):
            assert candidate.fold_scores[k] == whole.scores[c]
            assert candidate.fit_log_likelihoods[k] == whole.fit_log_likelihoods[c]
            # A refit needs only the fits of ds up to its candidate's.
            alone = score_warm_fold(
                plans[0], FoldTask(k, np.random.default_rng(0), (c,)), ordered[: c + 1][::-1]
            )
            assert alone.scores == (whole.scores[c],)
    with pytest.raises(InvalidInputError, match="rows: expected indices"):
        score_fold(plan, FoldTask(0, np.random.default_rng(0), (2,)))
    cold = dataclasses.replace(plan, ladder=(), refit=None)
    with pytest.raises(InvalidInputError, match="only warm folds"):
        score_fold(cold, FoldTask(0, np.random.default_rng(0), (0,)))
    with pytest.raises(InvalidInputError, match="rungs: expected the fits of ds = \\[1, 2\\]"):
        score_warm_fold(plans[0], FoldTask(0, np.random.default_rng(0), (1,)), ordered[1:])
    with pytest.raises(InvalidInputError, match="exactly one candidate"):
        score_warm_fold(plans[0], FoldTask(0, np.random.default_rng(0)), ordered)


def test_a_warm_map_that_refits_before_every_fit_is_done_gives_the_same_selection() -> None:
    """Refits of a small candidate may run while larger ones are still fitted (as the app's
    Dask engine runs them): the selection is the serial one."""
    data = small_world()

    order: list[str] = []

    def pipelined(
        rung_plan: RungPlan,
        rungs: Sequence[RungTask],
        plan: FoldPlan,
        tasks: Sequence[FoldTask],
    ) -> Iterator[RungResult | FoldResult]:
        done: list[RungResult] = []
        for rung in rungs:  # increasing ds
            done.append(fit_rung(rung_plan, rung))
            order.append(f"fit {rung.latent_dim}")
            yield done[-1]
            c = len(done) - 1
            for task in tasks:
                if task.rows == (c,):
                    order.append(f"refit {c}")
                    yield score_warm_fold(plan, task, done)

    rng, dims = np.random.default_rng(2), (1, 2)
    serial = select_latent_dim(data, _independent_fit, rng, dims, n_folds=3, refit=_warm_refit)
    rng = np.random.default_rng(2)
    piped = select_latent_dim(
        data, _independent_fit, rng, dims, n_folds=3, refit=_warm_refit, warm_map=pipelined
    )
    assert order.index("refit 0") < order.index("fit 2")
    assert piped == serial
    for ours, theirs in zip(piped.models, serial.models, strict=True):
        np.testing.assert_array_equal(ours.latents, theirs.latents)


def test_a_warm_refit_starts_where_the_model_stands_and_keeps_its_transform() -> None:
    data = small_world(seed=4)
    model = fit_manifold(data, 2, np.random.default_rng(0), OPTIONS, noise_model="correlated")
    assert model.transform is not None
    # On the model's own touches the refit starts at its optimum: nothing to gain, nothing lost.
    same = refit_warm(data, model, OPTIONS)
    assert same.transform is model.transform
    assert same.log_likelihood >= model.log_likelihood - 1e-6 * abs(model.log_likelihood)
    assert same.log_likelihood <= model.log_likelihood + 1.0
    # One iteration from it on part of the touches stays next to its latents.
    keep = np.flatnonzero(np.arange(data.n_touches) % 4 != 0)
    part = TrainingData(
        data.object_names, data.object_index[keep], data.actions[keep], data.observations[keep]
    )
    step = refit_warm(part, model, dataclasses.replace(OPTIONS, max_iterations=1))
    assert step.data.n_touches == keep.size
    assert step.transform is model.transform
    assert np.max(np.abs(step.latents - model.latents)) < 0.2
    other = dataclasses.replace(part, object_names=tuple(f"x{i}" for i in range(6)))
    with pytest.raises(InvalidInputError, match="objects"):
        refit_warm(other, model, OPTIONS)
