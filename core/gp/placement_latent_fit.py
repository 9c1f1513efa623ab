"""Fitting a latent coordinate per placement, warm from a fitted manifold
(:mod:`core.gp.placement_latent`; docs/calibration.md, "A latent per placement, measured").

The objects' arrangement found without the placements carries over: the fit starts from the
fitted latents S and hyperparameters, adds one latent length-scale ℓ^u per feature (long: the
placements start nearly alike) and random u_p of unit spread, and runs one joint L-BFGS-B run on
:class:`core.gp.placement_latent.PlacementLatentLikelihood`. Random, because u_p all equal
would be a stationary point: the kernel depends on u only through differences.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.optimize

from core.errors import InvalidInputError
from core.gp.parameters import parameter_bounds
from core.gp.placement_groups import checked_placement_variance
from core.gp.placement_latent import PlacementLatentLikelihood, Placements, pseudo_latents
from core.types import Hyperparameters, TrainingData
from core.validation import FloatArray, as_float_array

#: Starting ℓ^u per feature, in units of the u's spread: placements start nearly alike.
START_OFFSET_LENGTHSCALE = 2.0

#: |v_p| bound (their spread is pinned near 1).
OFFSET_BOUND = 6.0

#: |s| bound (the fitted latents have unit spread).
LATENT_BOUND = 10.0


@dataclass(frozen=True)
class PlacementLatentFit:
    """A fitted latent per placement.

    Attributes:
        placements: The touches as one pseudo-object per placement.
        latents: s_l of every object. Shape (L, ds).
        offsets: u_p of every placement (zero mean, unit spread). Shape (P,).
        hyperparameters: With ds + 1 latent length-scales, the last ℓ^u.
        negative_log_posterior: -log p(Y | S, u, X, γ) (+ ½ (log σ_v)², ~0) at the end.
        iterations: L-BFGS-B iterations.
        message: L-BFGS-B's reason for stopping.
        placement_variance: σ_b,a² held fixed in the fit, or ``None``; ``hyperparameters``'
            noise variance is then the within-placement one. Shape (dy,).
    """

    placements: Placements
    latents: FloatArray
    offsets: FloatArray
    hyperparameters: Hyperparameters
    negative_log_posterior: float
    iterations: int
    message: str
    placement_variance: FloatArray | None = None

    @property
    def pseudo_latents(self) -> FloatArray:
        """[s_l(p), u_p] of every placement. Shape (P, ds + 1)."""
        return pseudo_latents(self.latents, self.placements.placement_object, self.offsets)


def fit_placement_latents(
    data: TrainingData,
    latents: FloatArray,
    hyperparameters: Hyperparameters,
    seed: int = 0,
    max_iterations: int = 1000,
    threads: int = 1,
    noise_floor: FloatArray | None = None,
    placement_variance: FloatArray | None = None,
) -> PlacementLatentFit:
    """Fit S, u and the hyperparameters jointly, starting from a fit without placements.

    Args:
        data: Training touches (in the space the GPs model) that record their placements.
        latents: The fitted S. Shape (L, ds).
        hyperparameters: The fitted hyperparameters (ds latent length-scales).
        seed: Seed of the starting u_p.
        max_iterations: L-BFGS-B iteration limit.
        threads: Feature threads of each evaluation.
        noise_floor: The least σ_n,a² per feature, e.g. the within-placement noise that
            repeated touches of one placement show; ``None``: the data-relative bound.
            Shape (dy,).
        placement_variance: σ_b,a², an offset a placement's touches share beside u, held
            fixed (:class:`PlacementLatentLikelihood`); the fitted noise variance is then the
            within-placement σ_w,a², starting from ``hyperparameters``' σ_n,a² − σ_b,a².
            Shape (dy,).

    Raises:
        InvalidInputError: No recorded placements, or shapes that disagree.
    """
    h = hyperparameters
    latents = as_float_array(latents, "latents", (data.n_objects, h.latent_dim))
    if isinstance(max_iterations, bool) or int(max_iterations) < 1:
        raise InvalidInputError(f"max_iterations: must be ≥ 1, received {max_iterations!r}.")
    dy = h.observation_dim
    noise = h.noise_variance
    shared = None
    if placement_variance is not None:
        shared = checked_placement_variance(placement_variance, h.noise_variance, dy)
        noise = h.noise_variance - shared
    likelihood = PlacementLatentLikelihood(
        data, h.latent_dim, threads=threads, placement_variance=shared
    )
    layout = likelihood.layout
    start_h = Hyperparameters(
        signal_variance=h.signal_variance,
        noise_variance=noise,
        latent_lengthscales=np.column_stack(
            [h.latent_lengthscales, np.full(dy, START_OFFSET_LENGTHSCALE)]
        ),
        action_lengthscales=h.action_lengthscales,
    )
    offsets = np.random.default_rng(seed).standard_normal(layout.n_placements)
    start = layout.pack(latents, offsets, start_h)
    lower_h, upper_h = parameter_bounds(likelihood.placements.data, layout.pseudo, 1.0)
    hyper = layout.pseudo.hyperparameters
    n_fixed = layout.size - (hyper.stop - hyper.start)
    n_latent = data.n_objects * h.latent_dim
    lower = np.concatenate(
        [
            np.full(n_latent, -LATENT_BOUND),
            np.full(n_fixed - n_latent, -OFFSET_BOUND),
            lower_h[hyper],
        ]
    )
    upper = np.concatenate(
        [np.full(n_latent, LATENT_BOUND), np.full(n_fixed - n_latent, OFFSET_BOUND), upper_h[hyper]]
    )
    if noise_floor is not None:
        floor = as_float_array(noise_floor, "noise_floor", (dy,))
        if np.any(floor <= 0.0):
            raise InvalidInputError(f"noise_floor: must be > 0, received {floor.tolist()}.")
        noise_slice = slice(
            n_fixed + layout.pseudo.log_noise_variance.start - hyper.start,
            n_fixed + layout.pseudo.log_noise_variance.stop - hyper.start,
        )
        lower[noise_slice] = np.maximum(lower[noise_slice], np.log(floor))
        upper[noise_slice] = np.maximum(upper[noise_slice], lower[noise_slice])
    start = np.clip(start, lower, upper)
    result = scipy.optimize.minimize(
        likelihood.value_and_gradient,
        start,
        jac=True,
        method="L-BFGS-B",
        bounds=list(zip(lower, upper, strict=True)),
        options={"maxiter": int(max_iterations)},
    )
    fitted_latents, fitted_offsets, fitted_h = layout.unpack(result.x)
    return PlacementLatentFit(
        placements=likelihood.placements,
        latents=fitted_latents,
        offsets=fitted_offsets,
        hyperparameters=fitted_h,
        negative_log_posterior=float(result.fun),
        iterations=int(result.nit),
        message=str(result.message),
        placement_variance=shared,
    )
