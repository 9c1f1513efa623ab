"""Posterior tempering fitted on the training touches (a last resort): the log-loss, the choice of
β, the leave-touches-out pseudo-trials and the tempered posterior."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from core.errors import InvalidInputError
from core.evaluation.reference_model import experiment1_at_true_latents
from core.recognition.object_posterior import object_log_likelihoods, object_posterior
from core.recognition.tempering import (
    check_exponent,
    choose_exponent,
    fit_tempering,
    held_out_log_likelihoods,
    tempered_log_loss,
)
from core.types import ManifoldModel


@pytest.fixture(scope="module")
def model() -> ManifoldModel:
    return experiment1_at_true_latents(seed=0, touches_per_object=12)


def test_log_loss_by_hand() -> None:
    log_likelihoods = np.array([[0.0, -1.0], [-2.0, 0.0]])
    truth = np.array([0, 0])
    # answer 1: p_true = 1/(1+e^-1); answer 2: p_true = e^-2/(e^-2+1)
    expected = -0.5 * (np.log(1 / (1 + np.exp(-1.0))) + np.log(np.exp(-2.0) / (np.exp(-2.0) + 1)))
    assert tempered_log_loss(log_likelihoods, truth, 1.0) == pytest.approx(expected, rel=1e-12)
    # β halves every log odds
    half = -0.5 * (np.log(1 / (1 + np.exp(-0.5))) + np.log(np.exp(-1.0) / (np.exp(-1.0) + 1)))
    assert tempered_log_loss(log_likelihoods, truth, 0.5) == pytest.approx(half, rel=1e-12)


def test_the_chosen_exponent_matches_the_closed_form() -> None:
    """Two objects, every answer with log odds ±c, a share q right: the best β solves
    sigmoid(β c) = q, i.e. β = logit(q) / c."""
    c, q, n = 8.0, 0.8, 1000
    right = int(q * n)
    log_likelihoods = np.zeros((n, 2))
    log_likelihoods[:, 0] = c
    truth = np.concatenate([np.zeros(right, dtype=np.int64), np.ones(n - right, dtype=np.int64)])
    fit = choose_exponent(log_likelihoods, truth)
    assert fit.exponent == pytest.approx(np.log(q / (1 - q)) / c, rel=1e-3)
    assert fit.log_loss < fit.log_loss_untempered
    honest = choose_exponent(log_likelihoods[:right], truth[:right])
    assert honest.exponent == 1.0  # always right: tempering never sharpens


def test_held_out_trials_cover_every_touch_once(model: ManifoldModel) -> None:
    log_likelihoods, truth = held_out_log_likelihoods(model, 3, 4, np.random.default_rng(0))
    assert log_likelihoods.shape == (model.data.n_touches, model.data.n_objects)
    np.testing.assert_array_equal(
        np.bincount(truth), np.bincount(model.data.object_index, minlength=model.data.n_objects)
    )
    # The held-out touches are recognised well above chance (1/4), single touches included.
    assert np.mean(np.argmax(log_likelihoods, axis=1) == truth) > 0.5
    fit = fit_tempering(model, np.random.default_rng(0), folds=3, trial_length=4)
    assert 1e-3 <= fit.exponent <= 1.0
    assert fit.answers == model.data.n_touches


def test_tempered_model_scales_the_log_likelihood(model: ManifoldModel) -> None:
    rng = np.random.default_rng(4)
    x = rng.normal(size=(3, 1))
    y = model.data.observations[:3]
    tempered = dataclasses.replace(model, tempering=0.25)
    np.testing.assert_allclose(
        object_log_likelihoods(tempered, x, y), 0.25 * object_log_likelihoods(model, x, y)
    )
    sharp, soft = object_posterior(model, x, y), object_posterior(tempered, x, y)
    assert soft.max() <= sharp.max()


def test_bad_input_is_refused(model: ManifoldModel) -> None:
    with pytest.raises(InvalidInputError, match="tempering exponent"):
        check_exponent(1.5)
    with pytest.raises(InvalidInputError, match="folds"):
        held_out_log_likelihoods(model, 1, 6, np.random.default_rng(0))
    with pytest.raises(InvalidInputError, match="trial_length"):
        held_out_log_likelihoods(model, 2, 0, np.random.default_rng(0))
    with pytest.raises(InvalidInputError, match="at least 50 touches"):
        held_out_log_likelihoods(model, 50, 6, np.random.default_rng(0))
