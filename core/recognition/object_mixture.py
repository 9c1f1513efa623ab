"""The belief over the latent as a mixture over the learned objects, and its predictive moments.

A recognition assumes the touched object is one of the L learned ones, so its latent is near one
of the learned points s_l. The object posterior p_l says which; the belief over s it implies is

    s ~ Σ_l p_l N(s_l, c·I),

not the single Gaussian of the paper. A single Gaussian moment-matched to that mixture covers the
space between the objects too, where no object lies, and on a manifold whose latent length-scales
are short against the objects' spacing the information (M4) under it is mostly about where s lies
in those empty regions (docs/method.md, "The belief the active policy plans under").

(M3)'s moments are integrals over the belief, so under the mixture they are the mixture of the
components' moments (m_l, S_l, C_l each from (M3) at N(s_l, c·I)):

    m = Σ_l p_l m_l
    S = Σ_l p_l (S_l + (m_l - m)(m_l - m)ᵀ)
    C = Cov(s, y) = Σ_l p_l (C_l + (s_l - s̄)(m_l - m)ᵀ),    s̄ = Σ_l p_l s_l

and the moment-matched joint of (s, y) under the mixture gives U1 as in (M4), with Σ the
mixture's covariance c·I + Σ_l p_l (s_l - s̄)(s_l - s̄)ᵀ.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from core.errors import InvalidInputError
from core.recognition.moments import (
    ActionStatistics,
    BeliefTerms,
    PredictiveMoments,
    belief_terms,
    moments_from_terms,
    mutual_information,
)
from core.types import GaussianBelief, ManifoldModel
from core.validation import FloatArray, as_float_array

#: Components whose weight is below this fraction of the largest are left out (and the rest
#: renormalised): their share of every moment is below it, and each component costs one (M3).
WEIGHT_FLOOR = 1e-9


@dataclass(frozen=True)
class ObjectMixture:
    """Belief s ~ Σ_l p_l N(s_l, cov) over the learned objects' latents.

    Attributes:
        means: The learned latents s_l. Shape (L, ds).
        weights: p_l, non-negative, summing to 1. Shape (L,).
        cov: Every component's covariance, symmetric positive definite. Shape (ds, ds).
    """

    means: FloatArray
    weights: FloatArray
    cov: FloatArray

    def __post_init__(self) -> None:
        means = as_float_array(self.means, "mixture means", (None, None))
        n_objects, ds = means.shape
        weights = as_float_array(self.weights, "mixture weights", (n_objects,))
        cov = as_float_array(self.cov, "mixture cov", (ds, ds))
        if np.any(weights < 0) or not np.isclose(weights.sum(), 1.0, rtol=0, atol=1e-9):
            raise InvalidInputError(
                f"mixture weights: must be ≥ 0 and sum to 1, received sum {weights.sum()!r} "
                f"and smallest {weights.min()!r}."
            )
        if not np.allclose(cov, cov.T, rtol=1e-8, atol=1e-12) or np.linalg.eigvalsh(cov)[0] <= 0:
            raise InvalidInputError("mixture cov: must be symmetric positive definite.")
        object.__setattr__(self, "means", means)
        object.__setattr__(self, "weights", weights)
        object.__setattr__(self, "cov", cov)

    @property
    def dim(self) -> int:
        """ds."""
        return int(self.means.shape[1])

    def moment_matched(self) -> GaussianBelief:
        """The Gaussian with the mixture's mean and covariance."""
        centre = self.weights @ self.means
        spread = self.means - centre
        cov = self.cov + (spread * self.weights[:, None]).T @ spread
        return GaussianBelief(mean=centre, cov=0.5 * (cov + cov.T))


def _kept_components(mixture: ObjectMixture) -> tuple[np.ndarray, FloatArray]:
    """Indices of the components above :data:`WEIGHT_FLOOR` and their renormalised weights."""
    weights = mixture.weights
    kept = np.flatnonzero(weights >= WEIGHT_FLOOR * weights.max())
    return kept, weights[kept] / weights[kept].sum()


def component_terms(model: ManifoldModel, mixture: ObjectMixture) -> tuple[BeliefTerms, ...]:
    """The belief-only terms of (M3) of every component, whatever its weight
    (:func:`core.recognition.moments.belief_terms`). They depend on the components' means and
    covariance only, which are the same at every step of a trial (the objects' latents), so a
    caller that keeps them (:meth:`core.recognition.planning.Planner.mixture_terms`) pays the
    O(L · dy² L² ds) once instead of at every plan and update."""
    return tuple(belief_terms(model, GaussianBelief(mean, mixture.cov)) for mean in mixture.means)


def mixture_moments(
    model: ManifoldModel,
    mixture: ObjectMixture,
    stats: ActionStatistics,
    terms: Sequence[BeliefTerms] | None = None,
) -> PredictiveMoments:
    """m, S (with noise) and C = Cov(s, y) of every candidate under the mixture (see the module).

    Cost: one (M3) per component above :data:`WEIGHT_FLOOR` (its belief terms too, unless
    ``terms`` are given).

    Args:
        model: The model the statistics were computed with.
        mixture: The belief; its ds must be the model's.
        stats: Action statistics of C candidates for this model.
        terms: :func:`component_terms` of this mixture's components (for this model), or
            ``None`` to compute those needed.

    Returns:
        Moments with mean (C, dy), cov (C, dy, dy) and cross_cov (C, ds, dy), the latter about
        the mixture's mean.

    Raises:
        InvalidInputError: The mixture's dimension is not the model's.
    """
    if mixture.dim != model.latent_dim:
        raise InvalidInputError(
            f"mixture: has ds={mixture.dim}, the model has ds={model.latent_dim}."
        )
    if terms is not None and len(terms) != mixture.means.shape[0]:
        raise InvalidInputError(
            f"terms: expected one per component ({mixture.means.shape[0]}), received {len(terms)}."
        )
    kept, weights = _kept_components(mixture)
    centre = weights @ mixture.means[kept]
    components = [
        moments_from_terms(
            model,
            terms[k]
            if terms is not None
            else belief_terms(model, GaussianBelief(mixture.means[k], mixture.cov)),
            stats,
        )
        for k in kept
    ]
    mean = sum(w * c.mean for w, c in zip(weights, components, strict=True))
    cov = np.zeros_like(components[0].cov)
    cross = np.zeros_like(components[0].cross_cov)
    for w, k, component in zip(weights, kept, components, strict=True):
        deviation = component.mean - mean  # (C, dy)
        cov += w * (component.cov + deviation[:, :, None] * deviation[:, None, :])
        offset = mixture.means[k] - centre  # (ds,)
        cross += w * (component.cross_cov + offset[None, :, None] * deviation[:, None, :])
    return PredictiveMoments(
        mean=np.asarray(mean, dtype=np.float64),
        cov=0.5 * (cov + np.swapaxes(cov, 1, 2)),
        cross_cov=cross,
        actions=stats.actions,
    )


def mixture_information(
    model: ManifoldModel,
    mixture: ObjectMixture,
    stats: ActionStatistics,
    terms: Sequence[BeliefTerms] | None = None,
) -> FloatArray:
    """U1 of every candidate under the mixture (the moment-matched joint's (M4)); ``terms`` as
    in :func:`mixture_moments`. Shape (C,)."""
    moments = mixture_moments(model, mixture, stats, terms)
    return mutual_information(moments, mixture.moment_matched())
