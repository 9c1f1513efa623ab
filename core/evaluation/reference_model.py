"""Experiment 1's model without the fit: the true θ as latents, fixed hyperparameters.

For tests, benchmarks and demos that need a real, recognising model fast. Pure maths.
"""

from __future__ import annotations

import numpy as np

from core.evaluation.worlds import EXPERIMENT1_THETAS, sample_experiment1
from core.gp.posterior import condition
from core.types import Hyperparameters, ManifoldModel


def experiment1_at_true_latents(seed: int = 0, touches_per_object: int = 25) -> ManifoldModel:
    """Experiment 1's training touches conditioned at the true θ, without fitting.

    Latents are the true θ, normalised (centred, RMS 1) as a fit returns them; the
    hyperparameters are those ``core.gp.manifold.fit_hyperparameters`` finds for these latents on
    this data (seed 0, 25 touches per object), rounded. Recognition with it is a real GP
    computation; only the (slow) fit is skipped.

    Args:
        seed: Seed of the training touches (:func:`core.evaluation.worlds.sample_experiment1`).
        touches_per_object: Training touches per object.
    """
    data = sample_experiment1(np.random.default_rng(seed), touches_per_object=touches_per_object)
    thetas = np.asarray(EXPERIMENT1_THETAS)[:, None]
    centred = thetas - thetas.mean()
    latents = centred / np.sqrt(np.mean(np.sum(centred**2, axis=1)))
    hyper = Hyperparameters(
        signal_variance=np.array([0.18, 0.2, 0.27]),
        noise_variance=np.array([0.0094, 0.016, 0.011]),
        latent_lengthscales=np.array([[1.9], [100.0], [8.0]]),
        action_lengthscales=np.array([[0.84], [0.88], [0.92]]),
    )
    return condition(data, latents, hyper)
