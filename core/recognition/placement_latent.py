"""Scoring a trial under a manifold with a latent per placement (:mod:`core.gp.placement_latent`).

The GP is conditioned on the training touches as pseudo-objects, placement p of object l at the
latent [s_l, u_p]. A new trial is a new placement: its touches share one u ~ N(0, 1), unknown,
so under object l their latent input is [s, u] ~ N([s_l, 0], diag(Σ_l, 1)) (Σ_l = 0 when the
object's latent is taken as known) and the touches' joint distribution is matched by the exact
Gaussian-input moments of docs/method.md (L2) over all of them at once
(:func:`core.recognition.latent_uncertainty.trial_moments_given`). The shared u is what
makes the touches of one placement agree with each other more than with the training touches.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from core.errors import InvalidInputError
from core.gp.linalg import gaussian_log_density
from core.gp.placement_latent_fit import PlacementLatentFit
from core.gp.posterior import condition
from core.recognition.latent_uncertainty import (
    trial_action_terms,
    trial_moments_given,
    trial_noise,
)
from core.recognition.moments import BeliefTerms, belief_terms
from core.types import GaussianBelief, ManifoldModel
from core.validation import FloatArray, as_float_array

#: The variance standing for "known" of an object's latent (a belief's covariance must be
#: positive definite), normalised latent units: 10⁻¹⁰ of the objects' spread.
KNOWN_LATENT_VARIANCE = 1e-10


@dataclass(frozen=True)
class PlacementLatentModel:
    """A manifold with a latent per placement, ready to score trials.

    Attributes:
        conditioned: The GP conditioned on the pseudo-objects (latent dimension ds + 1), with
            the observation transform of the model it was fitted from.
        latents: s_l of every object. Shape (L, ds).
        latent_covariance: Σ_l of every object's latent, or ``None`` (known points).
            Shape (L, ds, ds).
        shared_variance: The variance of an offset every touch of a trial shares beyond u
            (the drift), per model-space feature. Shape (dy,).
        beliefs: The belief-only terms of every object's input [s, u] ~ N([s_l, 0],
            diag(Σ_l, 1)) (:func:`core.recognition.moments.belief_terms`), computed once.
    """

    conditioned: ManifoldModel
    latents: FloatArray
    latent_covariance: FloatArray | None
    shared_variance: FloatArray
    beliefs: tuple[BeliefTerms, ...]

    @property
    def n_objects(self) -> int:
        """L."""
        return int(self.latents.shape[0])


def placement_latent_model(
    model: ManifoldModel,
    fit: PlacementLatentFit,
    latent_covariance: FloatArray | None = None,
    shared_variance: FloatArray | None = None,
) -> PlacementLatentModel:
    """Condition the GP on the fitted pseudo-objects.

    Args:
        model: The model ``fit`` started from (its transform maps raw observations).
        fit: The fitted latents per placement.
        latent_covariance: Σ_l per object, or ``None``. Shape (L, ds, ds).
        shared_variance: An offset's variance shared by a trial's touches (the drift), below
            each feature's fitted noise variance; ``None``: none. A fit with a placement
            variance adds its σ_b² to it (a trial meets one placement). Shape (dy,).

    Raises:
        InvalidInputError: A shape disagrees, or a shared variance is not below the noise.
    """
    h = fit.hyperparameters
    dy, ds = h.observation_dim, fit.latents.shape[1]
    shared = (
        np.zeros(dy)
        if shared_variance is None
        else as_float_array(shared_variance, "shared_variance", (dy,))
    )
    if np.any(shared < 0.0) or np.any(shared >= h.noise_variance):
        raise InvalidInputError(
            f"shared_variance: every value must lie in [0, σ_n²) = [0, "
            f"{h.noise_variance.tolist()}), received {shared.tolist()}."
        )
    covariance = None
    if latent_covariance is not None:
        covariance = as_float_array(
            latent_covariance, "latent_covariance", (fit.latents.shape[0], ds, ds)
        )
    if fit.placement_variance is None:
        conditioned = condition(fit.placements.data, fit.pseudo_latents, h, structure="dense")
    else:
        # The fit's noise is the within-placement one; a touch's whole noise adds σ_b².
        whole = dataclasses.replace(h, noise_variance=h.noise_variance + fit.placement_variance)
        conditioned = condition(
            fit.placements.data,
            fit.pseudo_latents,
            whole,
            structure="dense",
            placement_variance=fit.placement_variance,
        )
        shared = shared + fit.placement_variance
    conditioned = dataclasses.replace(conditioned, transform=model.transform)
    beliefs = []
    for obj in range(fit.latents.shape[0]):
        latent_cov = KNOWN_LATENT_VARIANCE * np.eye(ds) if covariance is None else covariance[obj]
        belief = GaussianBelief(
            mean=np.append(fit.latents[obj], 0.0),
            cov=scipy.linalg.block_diag(latent_cov, np.ones((1, 1))),
        )
        beliefs.append(belief_terms(conditioned, belief))
    return PlacementLatentModel(
        conditioned=conditioned,
        latents=fit.latents,
        latent_covariance=covariance,
        shared_variance=shared,
        beliefs=tuple(beliefs),
    )


def trial_log_likelihoods(
    model: PlacementLatentModel, actions: FloatArray, observations: FloatArray
) -> FloatArray:
    """log p(y_1..y_T | l) of one trial's touches (one new placement) under every object.

    Args:
        model: A :class:`PlacementLatentModel`.
        actions: The trial's actions. Shape (T, dx).
        observations: Their raw observations. Shape (T, dy).

    Returns:
        Shape (L,).
    """
    conditioned = model.conditioned
    h = conditioned.hyperparameters
    x = as_float_array(actions, "actions", (None, h.action_dim))
    y = as_float_array(observations, "observations", (x.shape[0], h.observation_dim))
    t = x.shape[0]
    if t == 0:
        return np.zeros(model.n_objects)
    target = conditioned.to_model_space(y).T.reshape(-1)  # feature-major
    noise = trial_noise(h.noise_variance, model.shared_variance, t)
    transform = conditioned.transform
    jacobian = 0.0 if transform is None else transform.log_jacobian
    terms = trial_action_terms(conditioned, x)
    out = np.empty(model.n_objects)
    for obj, belief in enumerate(model.beliefs):
        mean, cov = trial_moments_given(conditioned, belief, x, *terms)
        residual = target - mean.T.reshape(-1)
        out[obj] = gaussian_log_density(residual, cov + noise, "trial covariance") + t * jacobian
    return out
