"""Helpers shared by the core tests."""

from __future__ import annotations

import numpy as np

from core.posterior import condition
from core.types import Hyperparameters, ManifoldModel
from core.worlds import EXPERIMENT1_THETAS, sample_experiment1


def experiment1_at_true_latents() -> ManifoldModel:
    """Experiment 1 conditioned at the true θ (normalised) with fixed hyperparameters."""
    data = sample_experiment1(np.random.default_rng(0), touches_per_object=25)
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
