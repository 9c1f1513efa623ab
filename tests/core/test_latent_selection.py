"""Choosing the latent dimension by cross-validation (core/selection/latent_selection.py)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from core.errors import InvalidInputError
from core.evaluation.worlds import EXPERIMENT1_THETAS, sample_experiment1
from core.gp.manifold import FitOptions, fit_manifold
from core.gp.posterior import condition
from core.recognition.object_posterior import touch_log_likelihoods
from core.selection.held_out_objects import (
    held_out_scores,
    log_densities_at,
    object_folds,
    place_latent,
    split_halves,
)
from core.selection.latent_selection import (
    _summarise,
    candidate_dims,
    fold_assignment,
    select_latent_dim,
)
from core.types import Hyperparameters, ManifoldModel, TrainingData

THETA = np.asarray(EXPERIMENT1_THETAS)[:, None]
Starts = tuple[np.ndarray, ...]


def hyper(ds: int) -> Hyperparameters:
    return Hyperparameters(
        signal_variance=np.full(3, 0.5),
        noise_variance=np.full(3, 0.01),
        latent_lengthscales=np.full((3, ds), 0.5),
        action_lengthscales=np.full((3, 1), 0.8),
    )


def test_candidates_and_folds() -> None:
    assert candidate_dims(4) == (1, 2, 3)
    assert candidate_dims(20) == (1, 2, 3, 4, 5)
    with pytest.raises(InvalidInputError):
        candidate_dims(1)
    index = np.repeat(np.arange(3), [7, 9, 12])
    folds = fold_assignment(index, 5, np.random.default_rng(0))
    for obj in range(3):
        counts = np.bincount(folds[index == obj], minlength=5)
        assert counts.max() - counts.min() <= 1  # every object spread evenly over the folds
    with pytest.raises(InvalidInputError, match="object 0 has 7 touches, at least 8"):
        fold_assignment(index, 6, np.random.default_rng(0))


def test_scores_are_the_held_out_log_likelihoods_of_the_folds() -> None:
    data = sample_experiment1(np.random.default_rng(1), touches_per_object=8)
    models: list[tuple[TrainingData, ManifoldModel]] = []

    def fit(train: TrainingData, ds: int, starts: Starts = (), rng: object = None) -> ManifoldModel:
        model = condition(train, np.hstack([THETA, np.zeros((4, ds - 1))]), hyper(ds))
        models.append((train, model))
        return model

    # Fixed models, one call per candidate and fold (nesting adds refits: its own tests).
    selection = select_latent_dim(
        data, fit, np.random.default_rng(2), (1, 2), n_folds=4, nested=False
    )
    folds = fold_assignment(data.object_index, 4, np.random.default_rng(2))
    for k in range(4):
        held = folds == k
        train, model = models[2 * k]  # ds = 1 of fold k
        assert train.n_touches == int((~held).sum())
        expected = touch_log_likelihoods(
            model, data.object_index[held], data.actions[held], data.observations[held]
        ).mean()
        assert selection.candidates[0].fold_scores[k] == pytest.approx(expected, rel=1e-12)
    # The extra latent column is constant: ds = 2 predicts exactly as ds = 1, so the smaller wins.
    assert selection.candidates[1].difference == pytest.approx(0.0, abs=1e-9)
    assert selection.chosen == 1
    assert "ds = 1" in selection.explanation


def test_a_clearly_better_larger_dimension_is_chosen() -> None:
    data = sample_experiment1(np.random.default_rng(3), touches_per_object=8)
    scrambled = np.array([[0.0], [0.0], [1.0], [1.0]])  # ds = 1 cannot tell two pairs apart

    def fit(train: TrainingData, ds: int, starts: Starts = (), rng: object = None) -> ManifoldModel:
        latents = scrambled if ds == 1 else np.hstack([scrambled, THETA])
        return condition(train, latents, hyper(ds))

    # Fixed models, not fits: without nesting (which would keep the better-fitting ds = 1).
    selection = select_latent_dim(
        data, fit, np.random.default_rng(4), (1, 2), n_folds=4, nested=False
    )
    assert selection.best == 2
    assert selection.chosen == 2
    assert selection.candidates[0].difference < -selection.candidates[0].difference_standard_error


def test_the_smallest_ds_within_one_standard_error_of_the_best_is_chosen() -> None:
    # ds = 2 has the best mean (1.03 vs 1.00) but its edge over ds = 1, paired over the four
    # folds (-0.03 ± 0.031), is within one standard error: ds = 1 is chosen, ds = 2 is best.
    scores = np.array([[1.0, 1.1, 0.9, 1.0], [1.1, 1.05, 0.95, 1.02], [0.8, 0.9, 0.7, 0.8]])
    selection = _summarise((1, 2, 3), scores, "touches")
    assert (selection.best, selection.chosen) == (2, 1)
    assert "smallest ds within one standard error of the best, ds = 2" in selection.explanation
    # The rule, on random score tables: the chosen ds is within one s.e. of the best, no smaller
    # one is, and it never exceeds the best.
    rng = np.random.default_rng(0)
    for _ in range(200):
        table = rng.normal(0.0, 1.0, (1, 5)) + rng.normal(0.0, 0.3, (4, 5))
        result = _summarise((1, 2, 3, 4), table, "touches")
        within = [
            c.latent_dim
            for c in result.candidates
            if c.difference >= -c.difference_standard_error - 1e-9
        ]
        assert result.chosen == min(within) <= result.best
        assert result.best == 1 + int(np.argmax(table.mean(axis=1)))


def test_experiment1_picks_one_latent_dimension() -> None:
    """A small real selection: Experiment 1 (θ is one number) from fitted models.

    With 10 touches per object the 1-D fit can stop in a local optimum (docs/method.md M2), which
    the random restarts guard against; bench/latent_dim.py measures the choice over seeds.
    """
    data = sample_experiment1(np.random.default_rng(5), touches_per_object=10)
    options = FitOptions(restarts=2)

    def fit(train: TrainingData, ds: int, starts: Starts = (), rng: object = None) -> ManifoldModel:
        started = dataclasses.replace(options, initial_latents=starts)
        return fit_manifold(train, ds, np.random.default_rng(0), started, noise_model="independent")

    selection = select_latent_dim(data, fit, np.random.default_rng(6), (1, 2), n_folds=3)
    assert selection.chosen == 1
    assert [c.latent_dim for c in selection.candidates] == [1, 2]
    assert all(len(c.fold_scores) == 3 for c in selection.candidates)


def test_bad_candidates_are_rejected() -> None:
    data = sample_experiment1(np.random.default_rng(7), touches_per_object=8)
    with pytest.raises(InvalidInputError, match="candidates"):
        select_latent_dim(data, lambda t, d, s, r: None, np.random.default_rng(0), (0, 1))  # type: ignore[arg-type,return-value]


# Leave-objects-out (criterion="objects").

SCRAMBLED = {"O1": 0.0, "O2": 0.0, "O3": 1.0, "O4": 1.0}  # ds = 1 cannot tell two pairs apart


def true_latents(train: TrainingData, ds: int, scrambled: bool = False) -> np.ndarray:
    """θ of the training objects (Experiment 1 names O1..O4), padded with zero columns."""
    rows = [int(name[1:]) - 1 for name in train.object_names]
    theta = THETA[rows]
    if scrambled:
        first = np.array([[SCRAMBLED[name]] for name in train.object_names])
        theta = first if ds == 1 else np.hstack([first, theta, np.zeros((len(rows), ds - 2))])
        return theta
    return np.hstack([theta, np.zeros((len(rows), ds - 1))])


def test_object_folds_and_halves_hold_everything_out_exactly_once() -> None:
    folds = object_folds(10, 4, np.random.default_rng(0))
    assert folds.shape == (10,)
    assert sorted(np.bincount(folds, minlength=4).tolist()) == [2, 2, 3, 3]
    with pytest.raises(InvalidInputError, match="2 ≤ K ≤ L"):
        object_folds(3, 4, np.random.default_rng(0))
    with pytest.raises(InvalidInputError, match="1 training object"):
        object_folds(3, 2, np.random.default_rng(0))
    index = np.repeat(np.arange(3), [2, 7, 10])
    halves = split_halves(index, np.random.default_rng(1))
    for obj in range(3):
        counts = np.bincount(halves[index == obj], minlength=2)
        assert abs(int(counts[0]) - int(counts[1])) <= 1
        assert counts.min() >= 1
    with pytest.raises(InvalidInputError, match="at least 2"):
        split_halves(np.array([0, 0, 1]), np.random.default_rng(0))


def test_log_densities_at_the_learned_latent_equal_touch_log_likelihoods() -> None:
    data = sample_experiment1(np.random.default_rng(8), touches_per_object=6)
    model = condition(data, true_latents(data, 2), hyper(2))
    obj = 2
    rows = data.object_index == obj
    direct = touch_log_likelihoods(
        model, data.object_index[rows], data.actions[rows], data.observations[rows]
    )
    at = log_densities_at(model, model.latents[obj], data.actions[rows], data.observations[rows])
    np.testing.assert_allclose(at, direct, rtol=1e-12)


def test_place_latent_maximises_the_likelihood_and_finds_a_known_object() -> None:
    data = sample_experiment1(np.random.default_rng(9), touches_per_object=12)
    model = condition(data, true_latents(data, 1), hyper(1))
    rows = data.object_index == 1
    s = place_latent(model, data.actions[rows], data.observations[rows])
    assert s == pytest.approx(model.latents[1], abs=0.1)

    def total(v: float) -> float:
        return float(
            log_densities_at(
                model, np.array([v]), data.actions[rows], data.observations[rows]
            ).sum()
        )

    for step in (-1e-3, 1e-3):  # a maximum: no better value nearby
        assert total(float(s[0]) + step) <= total(float(s[0])) + 1e-9


def test_objects_scores_are_the_direct_held_out_computation() -> None:
    data = sample_experiment1(np.random.default_rng(10), touches_per_object=8)
    models: list[tuple[TrainingData, ManifoldModel]] = []

    def fit(train: TrainingData, ds: int, starts: Starts = (), rng: object = None) -> ManifoldModel:
        model = condition(train, true_latents(train, ds), hyper(ds))
        models.append((train, model))
        return model

    selection = select_latent_dim(
        data, fit, np.random.default_rng(11), (1, 2), n_folds=4, criterion="objects", nested=False
    )
    rng = np.random.default_rng(11)
    folds = object_folds(4, 4, rng)
    halves = split_halves(data.object_index, rng)
    assert selection.n_folds == 4
    for k in range(4):
        train, model = models[2 * k]  # ds = 1 of fold k
        (held,) = np.flatnonzero(folds == k)
        assert data.object_names[held] not in train.object_names  # the object is new to the fit
        assert train.n_objects == 3
        # Direct: place from each half, score the other; every touch scored once.
        rows = np.flatnonzero(data.object_index == held)
        values = []
        for half in (0, 1):
            place, score = rows[halves[rows] == half], rows[halves[rows] != half]
            s = place_latent(model, data.actions[place], data.observations[place])
            values.extend(log_densities_at(model, s, data.actions[score], data.observations[score]))
        assert len(values) == rows.shape[0]
        scores = held_out_scores(model, data, np.array([held]), halves)
        assert scores.shape == (rows.shape[0],)
        assert selection.candidates[0].fold_scores[k] == pytest.approx(np.mean(values), rel=1e-10)
        assert float(scores.mean()) == pytest.approx(np.mean(values), rel=1e-10)


def test_objects_criterion_scores_the_needed_dimension_best() -> None:
    """A new object is placed well only when the manifold holds θ: ds = 2 here, not ds = 1.

    With four folds of one object each the gain varies from object to object (one is placed
    worse at ds = 2), so it stays within one standard error and the rule keeps ds = 1.
    """
    data = sample_experiment1(np.random.default_rng(12), touches_per_object=8)

    def fit(train: TrainingData, ds: int, starts: Starts = (), rng: object = None) -> ManifoldModel:
        return condition(train, true_latents(train, ds, scrambled=True), hyper(ds))

    selection = select_latent_dim(
        data, fit, np.random.default_rng(13), (1, 2), n_folds=4, criterion="objects", nested=False
    )
    assert selection.best == 2
    first = selection.candidates[0]
    assert first.difference < -0.3  # nats per touch, 4 folds of one object
    assert first.difference >= -first.difference_standard_error
    assert selection.chosen == 1
    assert "held-out objects" in selection.explanation


def test_bad_criterion_is_rejected() -> None:
    data = sample_experiment1(np.random.default_rng(7), touches_per_object=8)
    with pytest.raises(InvalidInputError, match="criterion"):
        select_latent_dim(data, lambda t, d, s, r: None, np.random.default_rng(0), criterion="bic")  # type: ignore[arg-type,return-value]
