"""Fixed hyperparameters, latents and Experiment-1 data sets shared by the tests of how a model
records and rebuilds its posterior (documents, the model store, the migrations)."""

from __future__ import annotations

import numpy as np

from core.evaluation.designs import collect, shared_design
from core.evaluation.worlds import Experiment1World, sample_experiment1
from core.types import Hyperparameters, TrainingData

TOLERANCE = 1e-10
HYPER = Hyperparameters(
    signal_variance=np.array([0.5, 0.4, 0.3]),
    noise_variance=np.array([0.01, 0.02, 0.03]),
    latent_lengthscales=np.array([[1.0], [2.0], [3.0]]),
    action_lengthscales=np.array([[0.7], [0.8], [0.9]]),
)
LATENTS = np.array([[-1.2], [-0.1], [0.3], [1.0]])
QUERY_S = np.linspace(-1.5, 1.5, 7)[:, None]
QUERY_X = np.linspace(-2.0, 2.0, 7)[:, None]


def random_data() -> TrainingData:
    """Experiment 1, a fresh action per touch (no shared design): 4 objects x 15 touches."""
    return sample_experiment1(np.random.default_rng(3), touches_per_object=15)


def shared_data() -> TrainingData:
    """Experiment 1 on a shared design: every object touched with the same 8 actions."""
    rng = np.random.default_rng(4)
    design = shared_design(4, 8, np.zeros(1), np.eye(1), rng)
    return collect(Experiment1World(noise_std=0.1), design, rng)
