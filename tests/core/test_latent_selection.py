"""Choosing the latent dimension by cross-validation (core/latent_selection.py)."""

from __future__ import annotations

import numpy as np
import pytest

from core.errors import InvalidInputError
from core.latent_selection import candidate_dims, fold_assignment, select_latent_dim
from core.manifold import FitOptions, fit_manifold
from core.object_posterior import touch_log_likelihoods
from core.posterior import condition
from core.types import Hyperparameters, ManifoldModel, TrainingData
from core.worlds import EXPERIMENT1_THETAS, sample_experiment1

THETA = np.asarray(EXPERIMENT1_THETAS)[:, None]


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

    def fit(train: TrainingData, ds: int) -> ManifoldModel:
        model = condition(train, np.hstack([THETA, np.zeros((4, ds - 1))]), hyper(ds))
        models.append((train, model))
        return model

    selection = select_latent_dim(data, fit, np.random.default_rng(2), (1, 2), n_folds=4)
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

    def fit(train: TrainingData, ds: int) -> ManifoldModel:
        latents = scrambled if ds == 1 else np.hstack([scrambled, THETA])
        return condition(train, latents, hyper(ds))

    selection = select_latent_dim(data, fit, np.random.default_rng(4), (1, 2), n_folds=4)
    assert selection.best == 2
    assert selection.chosen == 2
    assert selection.candidates[0].difference < -selection.candidates[0].difference_standard_error


def test_experiment1_picks_one_latent_dimension() -> None:
    """A small real selection: Experiment 1 (θ is one number) from fitted models.

    With 10 touches per object the 1-D fit can stop in a local optimum (METHOD.md M2), which
    the random restarts guard against; bench/latent_dim.py measures the choice over seeds.
    """
    data = sample_experiment1(np.random.default_rng(5), touches_per_object=10)
    options = FitOptions(restarts=2)

    def fit(train: TrainingData, ds: int) -> ManifoldModel:
        return fit_manifold(train, ds, np.random.default_rng(0), options, noise_model="independent")

    selection = select_latent_dim(data, fit, np.random.default_rng(6), (1, 2), n_folds=3)
    assert selection.chosen == 1
    assert [c.latent_dim for c in selection.candidates] == [1, 2]
    assert all(len(c.fold_scores) == 3 for c in selection.candidates)


def test_bad_candidates_are_rejected() -> None:
    data = sample_experiment1(np.random.default_rng(7), touches_per_object=8)
    with pytest.raises(InvalidInputError, match="candidates"):
        select_latent_dim(data, lambda t, d: None, np.random.default_rng(0), (0, 1))  # type: ignore[arg-type,return-value]
