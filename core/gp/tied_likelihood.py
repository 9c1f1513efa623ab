"""The manifold likelihood with tied kernels: one eigendecomposition serves every feature.

With tied kernels (``FitOptions.kernels = "tied"``, docs/fitting.md "Tied kernels") the features
share their length-scales ℓ^s and ℓ^x (they share the latents S anyway) and keep their own
σ_f,a² and σ_n,a², so every feature's Gram matrix of docs/method.md (M1) is

    K_a = σ_f,a² K + σ_n,a² I,   K = K^s[obj, obj] ∘ K^x   (unit variance, one for all features).

One eigendecomposition K = Q Λ Qᵀ (λ_i clipped at 0: K is positive semi-definite, rounding can
leave its smallest eigenvalues a hair below) then diagonalises every K_a, with eigenvalues
d_ai = σ_f,a² λ_i + σ_n,a². With z_a = Qᵀ y_a (y_a centred as in :mod:`core.gp.likelihood`) and
α̃_a = z_a / d_a, the terms of (M2) are

    log det K_a = Σ_i log d_ai,   y_aᵀ K_a⁻¹ y_a = Σ_i z_ai² / d_ai,

and, with W_a = K_a⁻¹ − α_a α_aᵀ (α_a = Q α̃_a),

    ∂(-log p)/∂log σ_f,a² = ½ σ_f,a² tr(W_a K) = ½ σ_f,a² Σ_i λ_i (1/d_ai − α̃_ai²),
    ∂(-log p)/∂log σ_n,a² = ½ σ_n,a² tr W_a    = ½ σ_n,a² Σ_i (1/d_ai − α̃_ai²).

Everything inside K (S, ℓ^s, ℓ^x) sees ∂(-log p)/∂K = ½ Σ_a σ_f,a² W_a = ½ W̄ with

    W̄ = Q diag(c) Qᵀ − A Aᵀ,   c_i = Σ_a σ_f,a² / d_ai,   A = Q [σ_f,a α̃_a]_a  (N × dy),

formed as two symmetric rank-k updates (``dsyrk``: one of rank N, one of rank dy), one triangle
only. Then M = W̄ ∘ K is the M of a single feature of :mod:`core.gp.likelihood`, and its sums
(:meth:`~core.gp.likelihood.ManifoldLikelihood.kernel_gradient`) give the latent and length-scale
gradients. An evaluation costs one ``eigh`` and one rank-N update of N × N matrices whatever dy
is, instead of dy Cholesky factors and inverses (the crossover in dy is measured in
docs/results.md). The value and gradient equal the per-feature likelihood's at equal
length-scales, with the length-scale gradients summed over the features
(tests/core/test_tied_likelihood.py).

No placement effect (σ_b² Z Zᵀ would break the shared eigenbasis) and no Kronecker or sparse
structure (:func:`tied_structure`).
"""

from __future__ import annotations

from typing import Literal

import numpy as np
import scipy.linalg
import scipy.linalg.blas

from core.errors import InvalidInputError, NotPositiveDefiniteError
from core.gp.likelihood import ManifoldLikelihood
from core.gp.parameters import ParameterLayout
from core.types import TrainingData
from core.validation import FloatArray

_LOG_2PI = float(np.log(2.0 * np.pi))

#: What ``FitOptions.kernels`` may be: every feature its own length-scales (docs/method.md
#: (M1)), or length-scales shared by the features (this module).
Kernels = Literal["per_feature", "tied"]
KERNELS: tuple[str, ...] = ("per_feature", "tied")

#: The structure a tied fit evaluates its likelihood with (its own fast path is dense).
TIED_STRUCTURE = "dense"


def refuse_structured(structure: str) -> None:
    """Refuse tied kernels with an explicit ``"kronecker"`` or ``"sparse"`` structure.

    Raises:
        InvalidInputError: ``structure`` is one of those.
    """
    if structure in ("kronecker", "sparse"):
        raise InvalidInputError(
            f"kernels: 'tied' shares one eigendecomposition of the dense Gram matrix and cannot "
            f"use the {structure!r} structure; ask for structure 'dense' or 'auto', or for "
            f"kernels 'per_feature'."
        )


def tied_structure(data: TrainingData, structure: str, dense_limit: int) -> str:
    """The structure of a fit with tied kernels: always ``"dense"``.

    ``"auto"`` means dense here even on a shared design (its Kronecker path is per feature),
    up to ``dense_limit`` touches.

    Args:
        data: Training touches.
        structure: The requested structure (``FitOptions.structure``).
        dense_limit: Most touches ``"auto"`` fits densely (above it, it would pick sparse).

    Raises:
        InvalidInputError: ``"kronecker"`` or ``"sparse"`` asked for, or ``"auto"`` on more
            than ``dense_limit`` touches.
    """
    refuse_structured(structure)
    if structure == "auto" and data.n_touches > dense_limit:
        raise InvalidInputError(
            f"kernels: 'tied' is a dense fit, and {data.n_touches} touches are more than "
            f"structure 'auto' fits densely ({dense_limit}); ask for structure 'dense' to tie "
            f"anyway, or for kernels 'per_feature'."
        )
    return TIED_STRUCTURE


class TiedLikelihood(ManifoldLikelihood):
    """-log p(Y | S, X, γ) with tied kernels (module docstring) and its gradient, at packed
    vectors of a tied :class:`~core.gp.parameters.ParameterLayout` (shared length-scales).

    The touches are sorted by object as in :class:`~core.gp.likelihood.ManifoldLikelihood`,
    whose Gram construction and gradient sums it reuses. One evaluation is one ``eigh`` (on the
    BLAS threads the process allows; ``threads`` of the per-feature likelihood does not apply).

    Args:
        data: Training touches.
        latent_dim: ds ≥ 1.
    """

    def __init__(self, data: TrainingData, latent_dim: int) -> None:
        super().__init__(data, latent_dim)
        self.layout = ParameterLayout.for_data(data, int(latent_dim), tied=True)

    def _spectrum(
        self, vector: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
        """K (1, N, N), its eigenvalues λ (N,) clipped at 0 and eigenvectors Q (N, N),
        z = Qᵀ Y (dy, N), d = σ_f² λ + σ_n² (dy, N) and σ_f² (dy,)."""
        latents, log_sf, log_sn, log_ls, log_lx = self.layout.split(vector)
        gram = self.gram_rows(latents, np.zeros(1), log_ls, log_lx)
        try:
            eigenvalues, eigenvectors = scipy.linalg.eigh(
                gram[0], overwrite_a=False, check_finite=False, driver="evd"
            )
        except (np.linalg.LinAlgError, ValueError) as error:
            raise NotPositiveDefiniteError(
                f"the tied Gram matrix has no eigendecomposition ({error})."
            ) from None
        eigenvalues = np.maximum(eigenvalues, 0.0)
        projected = self._centred @ eigenvectors  # (dy, N): row a is (Qᵀ y_a)ᵀ
        signal = np.exp(log_sf)
        variances = signal[:, None] * eigenvalues[None, :] + np.exp(log_sn)[:, None]
        return gram, eigenvalues, eigenvectors, projected, variances, signal

    def value(self, vector: FloatArray) -> float:
        """-log p at a packed (tied) vector: one ``eigh``."""
        self.evaluations += 1
        _, _, _, projected, variances, _ = self._spectrum(vector)
        return self._value(projected, variances)

    def _value(self, projected: FloatArray, variances: FloatArray) -> float:
        # docs/method.md eq. (M2), every feature in the shared eigenbasis; summed in feature order
        n = self.data.n_touches
        terms = 0.5 * np.sum(projected**2 / variances + np.log(variances), axis=1)
        total = 0.0
        for term in terms:
            total += float(term) + 0.5 * n * _LOG_2PI
        return total

    def value_and_gradient(self, vector: FloatArray) -> tuple[float, FloatArray]:
        """-log p and its gradient with respect to the packed (tied) vector (module docstring)."""
        self.evaluations += 1
        latents, _, log_sn, log_ls, log_lx = self.layout.split(vector)
        gram, eigenvalues, eigenvectors, projected, variances, signal = self._spectrum(vector)
        total = self._value(projected, variances)
        weights = projected / variances  # α̃_a = z_a / d_a, (dy, N)
        residual = 1.0 / variances - weights**2  # diagonal of Qᵀ W_a Q, (dy, N)
        g_sf = 0.5 * signal * (residual @ eigenvalues)
        g_sn = 0.5 * np.exp(log_sn) * residual.sum(axis=1)
        # W̄ = (Q √c)(Q √c)ᵀ − A Aᵀ, upper triangle (Fortran) by two rank-k updates.
        shared = np.sum(signal[:, None] / variances, axis=0)  # c, (N,)
        scaled = eigenvectors * np.sqrt(shared)[None, :]
        rank_dy = eigenvectors @ (weights.T * np.sqrt(signal)[None, :])  # A, (N, dy)
        combined = scipy.linalg.blas.dsyrk(1.0, scaled.T, trans=1, lower=0)
        combined = scipy.linalg.blas.dsyrk(
            -1.0, rank_dy.T, beta=1.0, c=combined, trans=1, lower=0, overwrite_c=1
        )
        # Its C-ordered transpose holds W̄ in the lower triangle, zeros above: X = tril(W̄) ∘ K.
        gram[0] *= combined.T
        inv_ls2 = np.exp(-2.0 * log_ls)  # (1, ds)
        inv_lx2 = np.exp(-2.0 * log_lx)  # (1, dx)
        g_latents, _, g_ls, g_lx = self.kernel_gradient(gram, latents, inv_ls2, inv_lx2)
        return total, self.layout.join(g_latents, g_sf, g_sn, g_ls, g_lx)
