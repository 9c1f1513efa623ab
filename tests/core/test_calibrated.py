"""core.recognition.calibrate: the post-fit steps, in order, and only those asked for."""

from __future__ import annotations

import numpy as np

from core.evaluation.reference_model import experiment1_at_true_latents
from core.gp import FitOptions
from core.gp.posterior import condition
from core.recognition import calibrate, fit_tempering, with_latent_uncertainty


def test_calibrate_is_the_steps_it_names() -> None:
    model = experiment1_at_true_latents(seed=0, touches_per_object=8)
    calibrated, found = calibrate(model, FitOptions(), np.random.default_rng(3))
    # No placements or times recorded: only the latent uncertainty applies.
    assert (found.placement, found.drift, found.shift, found.tempering) == (None,) * 4
    expected, laplace = with_latent_uncertainty(model)
    assert found.laplace is not None
    np.testing.assert_array_equal(found.laplace.covariance, laplace.covariance)
    np.testing.assert_array_equal(calibrated.latent_covariance, expected.latent_covariance)
    assert calibrated.tempering is None

    plain, nothing = calibrate(
        model, FitOptions(), np.random.default_rng(3), latent_uncertainty=False
    )
    assert plain.latent_covariance is None
    assert nothing.laplace is None

    tempered, found = calibrate(
        model, FitOptions(), np.random.default_rng(3), latent_uncertainty=False, tempering=True
    )
    assert found.tempering is not None
    assert tempered.tempering == fit_tempering(model, np.random.default_rng(3)).exponent


def test_a_sparse_model_keeps_point_latents_and_says_so() -> None:
    reference = experiment1_at_true_latents(seed=0, touches_per_object=8)
    sparse = condition(
        reference.data,
        reference.latents,
        reference.hyperparameters,
        structure="sparse",
        n_inducing=8,
    )
    calibrated, found = calibrate(sparse, FitOptions(), np.random.default_rng(0))
    assert calibrated.latent_covariance is None
    assert found.laplace is None
    assert len(found.notes) == 1
    assert "sparse model (32 touches)" in found.notes[0]
