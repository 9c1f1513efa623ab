"""Caller-given starting latents of a manifold fit (``FitOptions.initial_latents``)."""

from __future__ import annotations

import numpy as np
import pytest

from core.errors import InvalidInputError
from core.evaluation.worlds import RandomFeatureWorld, random_experiment2_world, sample_dataset
from core.gp.fit_options import FitOptions
from core.gp.fit_run import FitRun
from core.gp.initialisation import data_driven_starts
from core.gp.manifold import fit_hyperparameters, fit_manifold
from core.types import TrainingData


def _world(touches: int) -> tuple[RandomFeatureWorld, TrainingData]:
    rng = np.random.default_rng(7)
    world = random_experiment2_world(
        rng, n_objects=5, latent_dim=2, action_dim=2, observation_dim=2
    )
    return world, sample_dataset(world, rng, touches_per_object=touches)


@pytest.mark.parametrize("touches", [10, 30])  # 30 > 25: screened on a subsample, then polished
def test_a_fit_from_the_true_latents_ends_at_least_as_high_as_they_start(touches: int) -> None:
    world, data = _world(touches)
    truth = np.asarray(world.latents)
    # The start's value: the true latents with their hyperparameters fitted (S frozen).
    at_truth = fit_hyperparameters(data, truth).log_likelihood
    options = FitOptions(restarts=0, initial_latents=(truth,))
    model = fit_manifold(data, 2, np.random.default_rng(0), options)
    n_data = len(data_driven_starts(data, 2, np.random.default_rng(0)))
    diagnostics = model.diagnostics
    assert diagnostics is not None
    # The given start is one more data-driven start, after the PCA/Isomap ones.
    assert len(diagnostics.starts_log_likelihood) == n_data + 1
    assert model.log_likelihood >= at_truth - 1e-6
    # And the fit moved the latents little: they stay a near-affine image of the truth.
    design = np.hstack([model.latents, np.ones((5, 1))])
    fitted, *_ = np.linalg.lstsq(design, truth - truth.mean(axis=0), rcond=None)
    residual = truth - truth.mean(axis=0) - design @ fitted
    assert np.sum(residual**2) < 0.05 * np.sum((truth - truth.mean(axis=0)) ** 2)


def test_the_given_start_is_normalised_like_the_data_driven_ones() -> None:
    _, data = _world(10)
    given = np.arange(10.0).reshape(5, 2) * 7.0 + 3.0
    run = FitRun(
        data, 2, np.random.default_rng(0), FitOptions(restarts=0, initial_latents=(given,))
    )
    events = run.events()
    next(events)  # the starts are built before the first event
    events.close()
    start = run.starts[-1]
    assert start.kind == "data"
    latents, _ = run.layout.unpack(start.vector)
    centred = given - given.mean(axis=0)
    expected = centred / np.sqrt(np.mean(np.sum(centred**2, axis=1)))
    np.testing.assert_allclose(latents, expected, atol=1e-12)


def test_bad_initial_latents_are_refused_with_what_was_received() -> None:
    with pytest.raises(InvalidInputError, match=r"initial_latents\[0\]: expected shape \(L, ds\)"):
        FitOptions(initial_latents=(np.zeros(5),))
    with pytest.raises(InvalidInputError, match=r"initial_latents\[1\]: expected finite values"):
        FitOptions(initial_latents=(np.zeros((5, 2)), np.full((5, 2), np.nan)))
    with pytest.raises(InvalidInputError, match="expected a tuple of"):
        FitOptions(initial_latents=np.zeros((5, 2)))  # type: ignore[arg-type]
    with pytest.raises(InvalidInputError, match=r"initial_latents\[0\]: expected an \(L, ds\)"):
        FitOptions(initial_latents=("abc",))  # type: ignore[arg-type]
    _, data = _world(10)
    options = FitOptions(initial_latents=(np.zeros((4, 2)),))
    with pytest.raises(
        InvalidInputError, match=r"expected shape \(L, ds\) = \(5, 2\), received \(4, 2\)"
    ):
        FitRun(data, 2, np.random.default_rng(0), options)
    with pytest.raises(InvalidInputError, match=r"= \(5, 3\), received \(5, 2\)"):
        fit_manifold(
            data, 3, np.random.default_rng(0), FitOptions(initial_latents=(np.zeros((5, 2)),))
        )


def test_options_stay_comparable_and_the_copies_read_only() -> None:
    given = np.zeros((5, 2))
    options = FitOptions(initial_latents=(given,))
    assert options == FitOptions()  # excluded from == (documented)
    given[0, 0] = 1.0
    assert options.initial_latents[0][0, 0] == 0.0
    with pytest.raises(ValueError, match="read-only"):
        options.initial_latents[0][0, 0] = 1.0
