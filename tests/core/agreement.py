"""Checks that a fast path agrees with its reference: the Kronecker likelihood with the dense
one, the structured predictive moments with the direct appendix formula (docs/method.md)."""

from __future__ import annotations

import numpy as np

from bench.reference_moments import direct_moments_batch
from core.gp.kronecker import KroneckerLikelihood
from core.gp.likelihood import ManifoldLikelihood
from core.recognition.moments import (
    PredictiveMoments,
    action_statistics,
    mutual_information,
    predictive_moments,
)
from core.types import GaussianBelief, Hyperparameters, ManifoldModel, TrainingData

KRONECKER_TOLERANCE = 1e-8
MOMENTS_TOLERANCE = 1e-9


def relative(value: np.ndarray, reference: np.ndarray) -> float:
    """Largest absolute difference over the largest entry of ``reference``."""
    return float(np.max(np.abs(value - reference)) / max(np.max(np.abs(reference)), 1e-300))


def assert_kronecker_matches_dense(
    data: TrainingData, latent_dim: int, latents: np.ndarray, hyper: Hyperparameters
) -> tuple[KroneckerLikelihood, np.ndarray, float]:
    """The Kronecker log-likelihood and gradient at (latents, hyper) agree with the dense path
    to :data:`KRONECKER_TOLERANCE`; returns the Kronecker likelihood, the parameter vector and
    its value."""
    dense = ManifoldLikelihood(data, latent_dim)
    kron = KroneckerLikelihood(data, latent_dim)
    vector = dense.layout.pack(latents, hyper)
    value_d, grad_d = dense.value_and_gradient(vector)
    value_k, grad_k = kron.value_and_gradient(vector)
    assert abs(value_k - value_d) <= KRONECKER_TOLERANCE * abs(value_d)
    assert relative(grad_k, grad_d) <= KRONECKER_TOLERANCE
    return kron, vector, value_k


def assert_moments_match_direct(
    model: ManifoldModel, belief: GaussianBelief, actions: np.ndarray
) -> tuple[PredictiveMoments, np.ndarray]:
    """The structured batched moments (M3) and mutual information (M4) of ``actions`` (N, dx)
    agree with the direct appendix formula to :data:`MOMENTS_TOLERANCE`; returns both."""
    moments = predictive_moments(model, belief, action_statistics(model, actions))
    information = mutual_information(moments, belief)
    mean, cov, cross, direct_information = direct_moments_batch(model, belief, actions)
    assert relative(moments.mean, mean) < MOMENTS_TOLERANCE
    assert relative(moments.cov, cov) < MOMENTS_TOLERANCE
    assert relative(moments.cross_cov, cross) < MOMENTS_TOLERANCE
    assert relative(information, direct_information) < MOMENTS_TOLERANCE
    return moments, information
