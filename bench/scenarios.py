"""Benchmark problems on the Experiment-2-like world (ds = 2, dx = 6, dy = 5).

``Design.random`` is the paper's collection (a fresh x ~ N(0, I) per touch); ``Design.shared``
applies the same M scrambled-Sobol actions to every object (:mod:`core.evaluation.designs`), which
the Kronecker path exploits.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from core.evaluation import collect, random_design, shared_design
from core.evaluation.worlds import RandomFeatureWorld, random_experiment2_world
from core.gp import Structure, condition
from core.types import GaussianBelief, Hyperparameters, ManifoldModel, TrainingData

DesignName = Literal["random", "shared"]


def world(seed: int, n_objects: int) -> RandomFeatureWorld:
    """An Experiment-2-like world with ``n_objects`` objects."""
    return random_experiment2_world(np.random.default_rng(seed), n_objects=n_objects)


def dataset(
    source: RandomFeatureWorld, design: DesignName, per_object: int, seed: int
) -> TrainingData:
    """``per_object`` touches of every object, random or shared design."""
    rng = np.random.default_rng(seed)
    n_objects = source.latents.shape[0]
    mean, cov = source.action_mean, source.action_cov
    if design == "shared":
        plan = shared_design(n_objects, per_object, mean, cov, rng)
    else:
        plan = random_design(n_objects, per_object, mean, cov, rng)
    return collect(source, plan, rng)


def true_latents(source: RandomFeatureWorld) -> np.ndarray:
    """The world's latents, normalised (centred, RMS spread 1). Shape (L, 2)."""
    latents = source.latents - source.latents.mean(axis=0)
    spread = float(np.sqrt(np.mean(np.sum(latents**2, axis=1))))
    return np.asarray(latents / spread, dtype=np.float64)


def reference_hyperparameters(source: RandomFeatureWorld, data: TrainingData) -> Hyperparameters:
    """Sensible fixed hyperparameters for the world (so timings do not depend on a fit)."""
    latents = source.latents - source.latents.mean(axis=0)
    spread = float(np.sqrt(np.mean(np.sum(latents**2, axis=1))))
    dy, dx = data.observation_dim, data.action_dim
    return Hyperparameters(
        signal_variance=np.var(data.observations, axis=0),
        noise_variance=np.full(dy, float(np.mean(source.noise_std**2))),
        latent_lengthscales=np.full((dy, 2), source.latent_scale / spread),
        action_lengthscales=np.full((dy, dx), source.action_scale),
    )


def reference_model(
    source: RandomFeatureWorld,
    data: TrainingData,
    structure: Structure = "auto",
    n_inducing: int = 512,
) -> ManifoldModel:
    """The model conditioned on the true (normalised) latents and reference hyperparameters."""
    return condition(
        data,
        true_latents(source),
        reference_hyperparameters(source, data),
        structure=structure,
        n_inducing=n_inducing,
    )


def beliefs(model: ManifoldModel, count: int, seed: int) -> list[GaussianBelief]:
    """Beliefs near random learned objects, with random diagonal covariances."""
    rng = np.random.default_rng(seed)
    latents = model.latents
    out = []
    for _ in range(count):
        centre = latents[rng.integers(latents.shape[0])]
        out.append(
            GaussianBelief(
                mean=centre + 0.3 * rng.standard_normal(latents.shape[1]),
                cov=np.diag(rng.uniform(0.05, 5.0, latents.shape[1])),
            )
        )
    return out
