"""The exact Kronecker path for shared action designs (docs/method.md, "Shared action designs").

When every object was touched with the same M actions (N = L·M; natural on a turntable: run
each action on every object), order the touches object-major, touch (l, m) at grid position
l·M + m. The noisy Gram matrix of feature a is then

    K_a = σ_f,a² K^s_a ⊗ K^x_a + σ_n,a² I                                    docs/method.md (M1)

with K^s_a the L × L latent kernel and K^x_a the M × M action kernel. With the
eigendecompositions K^s_a = U_s Λ_s U_sᵀ and K^x_a = U_x Λ_x U_xᵀ,

    K_a = (U_s ⊗ U_x) diag(D_a) (U_s ⊗ U_x)ᵀ,   D_a[j, k] = σ_f,a² Λ_s[j] Λ_x[k] + σ_n,a²,

so with Y_a the centred observations as an L × M matrix and Ỹ = U_sᵀ Y_a U_x:

* log det K_a = Σ log D_a;  y_aᵀ K_a⁻¹ y_a = Σ Ỹ² / D_a;  β_a = U_s (Ỹ / D_a) U_xᵀ (L × M);
* the gradient of -log p needs only the block sums of W ∘ K_f of the dense path
  (:mod:`core.gp.likelihood`), which factor too. With B = β_a as an L × M matrix,
  w_s = (1/D) Λ_x and w_x = Λ_sᵀ (1/D):

      Σ_{m,m'} (W ∘ K_f)[(l,m), (l',m')] = σ_f² K^s[l,l'] · (U_s diag(w_s) U_sᵀ - B K^x Bᵀ)[l,l']
      Σ_{l,l'} (W ∘ K_f)[(l,m), (l',m')] = σ_f² K^x[m,m'] · (U_x diag(w_x) U_xᵀ - Bᵀ K^s B)[m,m']

  which give the latent and latent-length-scale gradients (the first, an L × L matrix) and the
  action-length-scale gradients (the second, M × M); σ_n² needs tr W = Σ 1/D - ‖B‖².
  Implemented without B: with C̃ = Ỹ / D, B K^x Bᵀ = P_s Λ_x P_sᵀ for P_s = U_s C̃ and
  Bᵀ K^s B = P_x Λ_s P_xᵀ for P_x = U_x C̃ᵀ, each bracket one triangle from symmetric rank-k
  updates (:func:`core.gp.linalg.weighted_gram_difference`), and ‖B‖ = ‖C̃‖. The two
  eigendecompositions dominate (at L = 400, M = 100 about two thirds of an evaluation).
  For a few objects on many actions (L ≤ 4, M ≥ 50) the value and gradient come instead from
  L Cholesky blocks of order M after rotating by U_s alone (:mod:`core.gp.kronecker_blocks`):
  the same numbers, 1.1-1.9x faster per evaluation.

Everything is O(dy (L³ + M³ + L·M·(L + M))) time and O(dy (L² + M² + L·M)) memory, against
O(dy (L·M)³) and O(dy (L·M)²) for the dense path: exact, not an approximation (tests match the
dense path to 1e-8).

The moment-matching statistics of docs/method.md's structured (M3) factor the same way: a new action
x has e_a(x) = 1_L ⊗ e^x_a(x) over the grid (e^x_a(x)[m] = k^x_a(x, x_m)), so

    u_a(x) = B e^x_a(x)                                       (L,)
    T_a(x) = U_s diag(t_a(x)) U_sᵀ,   t_a(x)[j] = Σ_k (U_xᵀ e^x_a(x))_k² / D_a[j, k]

and tr(G_aa T_a) = Σ_j t_a[j] (U_sᵀ G_aa U_s)_jj: the action statistics are the L-vectors u and
t (the "trace spectrum") plus the per-model basis U_s, O(dy (M² + L·M)) per candidate.

**Missing touches.** The structure needs the complete grid. When some object lacks some of the
design actions (or has extra touches), :func:`find_shared_design` returns ``None`` and callers
fall back to the dense path (:mod:`core.gp.likelihood`, :func:`core.gp.posterior.condition`), or to
the sparse path (:mod:`core.gp.sparse`) when the data are too large for it; the result is then exact
(dense) or approximate (sparse), never a Kronecker result on an incomplete grid.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from core.errors import InvalidInputError, NotPositiveDefiniteError
from core.gp.kernels import feature_action_kernels
from core.gp.kronecker_blocks import BlockSums, block_sums, block_value, use_blocks
from core.gp.linalg import JITTER_LADDER, weighted_gram_difference
from core.gp.parameters import ParameterLayout, check_conditioning
from core.types import (
    FitDiagnostics,
    GPPosterior,
    Hyperparameters,
    KroneckerFactors,
    ManifoldModel,
    TrainingData,
)
from core.validation import FloatArray, IntArray, as_float_array

_LOG_2PI = float(np.log(2.0 * np.pi))
#: Smallest eigenvalue of K_a (relative to its mean diagonal) accepted without jitter.
_SPECTRUM_FLOOR = 1e-14


@dataclass(frozen=True)
class SharedDesign:
    """A complete shared action design: every object touched once with each of M actions.

    Attributes:
        actions: The design actions, in grid order. Shape (M, dx).
        grid_index: Grid position l·M + m of every touch (data order). Shape (N,).
    """

    actions: FloatArray
    grid_index: IntArray

    @property
    def size(self) -> int:
        """M."""
        return int(self.actions.shape[0])


def _sorted_rows(actions: FloatArray) -> IntArray:
    """Row order that sorts actions lexicographically (first column first)."""
    return np.lexsort(actions.T[::-1]).astype(np.int64)


def _design_mismatch(data: TrainingData) -> tuple[SharedDesign | None, str]:
    """The shared design of ``data``, or ``None`` and the reason there is none."""
    counts = data.touches_per_object()
    names = data.object_names
    if np.any(counts != counts[0]):
        values, frequency = np.unique(counts, return_counts=True)
        usual = int(values[np.argmax(frequency)])
        odd = [f"{names[i]!r} ({counts[i]})" for i in np.flatnonzero(counts != usual)[:5]]
        return None, (
            f"most objects have {usual} touches but {', '.join(odd)} differ: a shared design "
            f"needs the same M actions on every object (missing touches fall back to the "
            f"dense or sparse path)."
        )
    m = int(counts[0])
    order = np.argsort(data.object_index, kind="stable")
    grouped = data.actions[order].reshape(data.n_objects, m, data.action_dim)
    reference_rows = _sorted_rows(grouped[0])
    design = grouped[0][reference_rows]
    grid_index = np.empty(data.n_touches, dtype=np.int64)
    for obj in range(data.n_objects):
        rows = reference_rows if obj == 0 else _sorted_rows(grouped[obj])
        if obj and not np.array_equal(grouped[obj][rows], design):
            return None, (
                f"object {names[obj]!r} was not touched with the same actions as "
                f"{names[0]!r} (a shared design needs identical action rows on every object)."
            )
        # touch order[obj·m + rows[k]] is design action k of object obj
        grid_index[order[obj * m + rows]] = obj * m + np.arange(m)
    design = np.array(design, dtype=np.float64)
    design.flags.writeable = False
    grid_index.flags.writeable = False
    return SharedDesign(actions=design, grid_index=grid_index), ""


def find_shared_design(data: TrainingData) -> SharedDesign | None:
    """Detect a complete shared design: every object has the same multiset of action rows.

    Rows are compared exactly (a design written once and applied to every object reproduces
    its floats exactly, also through the CSV round trip).

    Args:
        data: Training touches.

    Returns:
        The design, or ``None`` when the objects' action sets differ (missing or extra touches).
    """
    design, _ = _design_mismatch(data)
    return design


def require_shared_design(data: TrainingData) -> SharedDesign:
    """Like :func:`find_shared_design`, but raise when there is none.

    Raises:
        InvalidInputError: Names the first object whose touches break the design.
    """
    design, reason = _design_mismatch(data)
    if design is None:
        raise InvalidInputError(f"structure='kronecker': {reason}")
    return design


@dataclass(frozen=True)
class _Spectral:
    """Per-feature eigendecompositions at one parameter vector (internal)."""

    latent_gram: FloatArray  # K^s (dy, L, L), unit diagonal
    action_gram: FloatArray  # K^x (dy, M, M)
    latent_values: FloatArray  # (dy, L)
    latent_vectors: FloatArray  # (dy, L, L)
    action_values: FloatArray  # (dy, M)
    action_vectors: FloatArray  # (dy, M, M)
    spectrum: FloatArray  # D (dy, L, M), incl. noise and jitter
    rotated: FloatArray  # Ỹ = U_sᵀ Y U_x (dy, L, M)
    jitter: FloatArray  # (dy,)
    latent_sq: FloatArray  # per-dimension (s_ld - s_l'd)², (ds, L·L)


class KroneckerLikelihood:
    """-log p(Y | S, X, γ) and its gradient on a shared design, drop-in for
    :class:`core.gp.likelihood.ManifoldLikelihood` (same packed vector, same values to rounding).

    Args:
        data: Training touches on a complete shared design.
        latent_dim: ds ≥ 1.
        design: The design (found with :func:`require_shared_design` when ``None``).

    Raises:
        InvalidInputError: ``data`` is not on a complete shared design, or bad ``latent_dim``.
    """

    def __init__(
        self, data: TrainingData, latent_dim: int, design: SharedDesign | None = None
    ) -> None:
        if isinstance(latent_dim, bool) or int(latent_dim) != latent_dim or latent_dim < 1:
            raise InvalidInputError(f"latent_dim: must be an integer ≥ 1, received {latent_dim}.")
        self.data = data
        self.layout = ParameterLayout.for_data(data, int(latent_dim))
        self.design = design if design is not None else require_shared_design(data)
        actions = self.design.actions - self.design.actions.mean(axis=0)
        m, dx = actions.shape
        diff = actions.T[:, :, None] - actions.T[:, None, :]  # (dx, M, M)
        self._sq_design = np.ascontiguousarray((diff**2).reshape(dx, m * m))
        centred = data.observations - data.observation_mean  # (N, dy)
        grid = np.empty((data.observation_dim, data.n_touches))
        grid[:, self.design.grid_index] = centred.T
        self._grid_y = grid.reshape(data.observation_dim, data.n_objects, m)
        #: Evaluate through L Cholesky blocks (few objects) instead of eigendecomposing K^x
        #: (:mod:`core.gp.kronecker_blocks`); the eigendecompositions remain the fallback.
        self.blocks = use_blocks(data.n_objects, m)
        self.max_jitter = 0.0
        self.evaluations = 0

    def spectral(self, vector: FloatArray) -> tuple[_Spectral, FloatArray]:
        """Eigendecompositions and spectrum at a packed vector, and β on the grid
        (dy, L, M), for conditioning."""
        sp = self._decompose(vector)
        # β = U_s (Ỹ / D) U_xᵀ
        beta_grid = (
            sp.latent_vectors @ (sp.rotated / sp.spectrum) @ np.swapaxes(sp.action_vectors, 1, 2)
        )
        return sp, beta_grid

    def _grams(self, vector: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """K^s (dy, L, L) and K^x (dy, M, M), unit diagonals, and the per-dimension squared
        latent differences (ds, L·L) at a packed vector."""
        latents, _, _, log_ls, log_lx = self.layout.split(vector)
        dy = self.layout.observation_dim
        n_objects, m = self.data.n_objects, self.design.size
        differences = np.empty((latents.shape[1], n_objects, n_objects))
        for d, column in enumerate(latents.T):
            np.subtract.outer(column, column, out=differences[d])
        latent_sq = np.square(differences, out=differences).reshape(latents.shape[1], -1)
        latent_gram = (-0.5 * np.exp(-2.0 * log_ls)) @ latent_sq
        action_gram = (-0.5 * np.exp(-2.0 * log_lx)) @ self._sq_design
        latent_gram = np.exp(latent_gram, out=latent_gram).reshape(dy, n_objects, n_objects)
        action_gram = np.exp(action_gram, out=action_gram).reshape(dy, m, m)
        return latent_gram, action_gram, latent_sq

    def _decompose(
        self,
        vector: FloatArray,
        grams: tuple[FloatArray, FloatArray, FloatArray] | None = None,
    ) -> _Spectral:
        """Everything but β: the value and the gradient do not need β in the grid basis."""
        _, log_sf, log_sn, _, _ = self.layout.split(vector)
        dy = self.layout.observation_dim
        signal = np.exp(log_sf)
        noise = np.exp(log_sn)
        latent_gram, action_gram, latent_sq = grams if grams is not None else self._grams(vector)
        latent_values, latent_vectors = np.linalg.eigh(latent_gram)
        action_values, action_vectors = np.linalg.eigh(action_gram)
        # docs/method.md eq. (M1): eigenvalues of σ_f² K^s ⊗ K^x + σ_n² I
        spectrum = (signal[:, None] * latent_values)[:, :, None] * action_values[:, None, :]
        spectrum += noise[:, None, None]
        jitter = np.zeros(dy)
        for a in range(dy):
            jitter[a] = self._jitter(spectrum[a], float(signal[a] + noise[a]), a)
            if jitter[a]:
                spectrum[a] += jitter[a]
        self.max_jitter = max(self.max_jitter, float(jitter.max()))
        rotated = (np.swapaxes(latent_vectors, 1, 2) @ self._grid_y) @ action_vectors
        return _Spectral(
            latent_gram=latent_gram,
            action_gram=action_gram,
            latent_values=latent_values,
            latent_vectors=latent_vectors,
            action_values=action_values,
            action_vectors=action_vectors,
            spectrum=spectrum,
            rotated=rotated,
            jitter=jitter,
            latent_sq=latent_sq,
        )

    @staticmethod
    def _jitter(spectrum: FloatArray, mean_diagonal: float, feature: int) -> float:
        """The jitter the dense path's ladder would add (0 when K_a is positive definite)."""
        smallest = float(spectrum.min())
        for relative in JITTER_LADDER:
            jitter = relative * mean_diagonal
            if smallest + jitter > _SPECTRUM_FLOOR * mean_diagonal:
                return jitter
        raise NotPositiveDefiniteError(
            f"The Gram matrix of feature {feature} stayed singular after adding jitter up to "
            f"{JITTER_LADDER[-1]:g} x its mean diagonal: raise the lower bound on the noise "
            f"variance."
        )

    def _value(self, spectral: _Spectral, scaled: FloatArray | None = None) -> float:
        """-log p from the spectrum; ``scaled`` = Ỹ / D when already at hand."""
        n = self.data.n_touches
        dy = self.layout.observation_dim
        if scaled is None:
            scaled = spectral.rotated / spectral.spectrum
        quad = float(np.vdot(spectral.rotated, scaled))
        log_det = float(np.sum(np.log(spectral.spectrum)))
        # docs/method.md eq. (M2)
        return 0.5 * quad + 0.5 * log_det + 0.5 * dy * n * _LOG_2PI

    def value(self, vector: FloatArray) -> float:
        """-log p at a packed vector."""
        self.evaluations += 1
        grams = None
        if self.blocks:
            _, log_sf, log_sn, _, _ = self.layout.split(vector)
            grams = self._grams(vector)
            value = block_value(grams[0], grams[1], self._grid_y, np.exp(log_sf), np.exp(log_sn))
            if value is not None:
                return value
        return self._value(self._decompose(vector, grams))

    def _spectral_sums(self, sp: _Spectral) -> BlockSums:
        """The value and the gradient's block sums through the eigendecompositions.

        Ω_s = U_s diag(w_s) U_sᵀ - P_s Λ_x P_sᵀ with P_s = U_s C̃ = β U_x, and
        Ω_x = U_x diag(w_x) U_xᵀ - P_x Λ_s P_xᵀ with P_x = U_x C̃ᵀ = βᵀ U_s (C̃ = Ỹ / D): β
        itself is never formed, and each Ω is one triangle from symmetric rank-k updates. Cost
        per feature 2 L M (L + M) (Ỹ) + 2 L M (L + M) (P_s, P_x) + L² (L + M) + M² (M + L)
        (the updates).
        """
        inv_d = 1.0 / sp.spectrum  # (dy, L, M)
        scaled = sp.rotated * inv_d  # C̃ = U_sᵀ β U_x, (dy, L, M)
        w_s = (inv_d @ sp.action_values[:, :, None])[:, :, 0]  # (dy, L)
        w_x = (sp.latent_values[:, None, :] @ inv_d)[:, 0, :]  # (dy, M)
        dy, n_objects, m = scaled.shape
        latent_half = np.empty((dy, n_objects, n_objects))
        action_half = np.empty((dy, m, m))
        for a in range(dy):
            u_s, u_x = sp.latent_vectors[a], sp.action_vectors[a]
            p_s = u_s @ scaled[a]  # (L, M)
            p_x = u_x @ scaled[a].T  # (M, L)
            omega = weighted_gram_difference(u_s, w_s[a], p_s, sp.action_values[a])
            np.multiply(sp.latent_gram[a], omega, out=latent_half[a])
            omega = weighted_gram_difference(u_x, w_x[a], p_x, sp.latent_values[a])
            np.multiply(sp.action_gram[a], omega, out=action_half[a])
        return BlockSums(
            value=self._value(sp, scaled),
            # tr W = Σ 1/D - ‖β‖², and ‖β‖ = ‖C̃‖ (orthogonal bases)
            noise_trace=np.sum(inv_d, axis=(1, 2)) - np.sum(scaled**2, axis=(1, 2)),
            latent_half=latent_half,
            action_half=action_half,
        )

    def value_and_gradient(self, vector: FloatArray) -> tuple[float, FloatArray]:
        """-log p and its gradient with respect to the packed vector (same layout).

        The block sums of W ∘ K_f (module docstring) come from L Cholesky blocks for few
        objects (:mod:`core.gp.kronecker_blocks`), else from the eigendecompositions
        (:meth:`_spectral_sums`); the gradient is assembled from them the same way.
        """
        self.evaluations += 1
        layout = self.layout
        latents, log_sf, log_sn, log_ls, log_lx = layout.split(vector)
        signal = np.exp(log_sf)
        noise = np.exp(log_sn)
        inv_ls2 = np.exp(-2.0 * log_ls)  # (dy, ds)
        inv_lx2 = np.exp(-2.0 * log_lx)  # (dy, dx)
        grams = self._grams(vector)
        latent_sq = grams[2]
        sums = block_sums(grams[0], grams[1], self._grid_y, signal, noise) if self.blocks else None
        if sums is None:
            sums = self._spectral_sums(self._decompose(vector, grams))
        g_sn = 0.5 * noise * sums.noise_trace
        # Upper triangles X of σ_f² K ∘ Ω: the symmetric block sums are X + Xᵀ - diag(X).
        latent_half = sums.latent_half * signal[:, None, None]
        action_half = sums.action_half * signal[:, None, None]
        n_objects = latents.shape[0]
        dy, m, _ = action_half.shape
        latent_diag = np.einsum("all->al", latent_half)  # (dy, L)
        # ½ Σ B = ½ (2 Σ X - tr X)
        g_sf = np.sum(latent_half, axis=(1, 2)) - 0.5 * np.sum(latent_diag, axis=1)
        # ½ Σ B ∘ (s_d - s_d')² = Σ X ∘ (s_d - s_d')² (zero diagonal)
        g_ls = (latent_half.reshape(dy, -1) @ latent_sq.T) * inv_ls2
        # B [1, S] = X V + Xᵀ V - diag(X) V
        basis = np.hstack([np.ones((n_objects, 1)), latents])  # (L, 1 + ds)
        products = latent_half @ basis + np.swapaxes(basis.T @ latent_half, 1, 2)
        products -= latent_diag[:, :, None] * basis
        row_sums = products[:, :, 0]  # (dy, L)
        # ∂/∂s_l = -Σ_a Σ_l' B_a[l,l'] (s_l - s_l') / ℓ_a²
        g_latents = -(
            latents * (row_sums.T @ inv_ls2) - np.einsum("ald,ad->ld", products[:, :, 1:], inv_ls2)
        )
        g_lx = (action_half.reshape(dy, m * m) @ self._sq_design.T) * inv_lx2
        grad = layout.join(g_latents, g_sf, g_sn, g_ls, g_lx)
        return sums.value, grad


def condition_kronecker(
    data: TrainingData,
    latents: FloatArray,
    hyperparameters: Hyperparameters,
    diagnostics: FitDiagnostics | None = None,
    design: SharedDesign | None = None,
) -> ManifoldModel:
    """Build a :class:`ManifoldModel` on a shared design through the eigendecompositions.

    The posterior carries :class:`core.types.KroneckerFactors` (no dense K⁻¹; it is
    materialised on request for small N) and β in data order, so every consumer of
    :func:`core.gp.posterior.condition`'s models keeps working.

    Args:
        data: Training touches on a complete shared design.
        latents: Object latents. Shape (L, ds).
        hyperparameters: Per-feature hyperparameters.
        diagnostics: Optional fit diagnostics to attach.
        design: The design (detected when ``None``).

    Raises:
        InvalidInputError: Bad shapes, or the data are not on a complete shared design.
        NotPositiveDefiniteError: A Gram matrix is singular even with jitter.
    """
    h = hyperparameters
    latents = check_conditioning(data, latents, h)
    likelihood = KroneckerLikelihood(data, h.latent_dim, design)
    sp, beta_grid = likelihood.spectral(likelihood.layout.pack(latents, h))
    log_likelihood = -likelihood._value(sp)
    grid = likelihood.design.grid_index
    beta = beta_grid.reshape(h.observation_dim, -1)[:, grid]
    factors = KroneckerFactors(
        design=likelihood.design.actions,
        grid_index=grid,
        latent_eigenvalues=sp.latent_values,
        latent_eigenvectors=sp.latent_vectors,
        action_eigenvalues=sp.action_values,
        action_eigenvectors=sp.action_vectors,
        spectrum=sp.spectrum,
        beta_grid=beta_grid,
    )
    latents = latents.copy()
    for array in (
        latents,
        beta,
        sp.jitter,
        sp.latent_values,
        sp.latent_vectors,
        sp.action_values,
        sp.action_vectors,
        sp.spectrum,
        beta_grid,
    ):
        array.flags.writeable = False
    return ManifoldModel(
        data=data,
        latents=latents,
        hyperparameters=h,
        posterior=GPPosterior(beta=beta, gram_inverse=None, jitter=sp.jitter, kronecker=factors),
        log_likelihood=float(log_likelihood),
        diagnostics=diagnostics,
    )


def _factors(model: ManifoldModel) -> KroneckerFactors:
    factors = model.posterior.kronecker
    if factors is None:
        raise InvalidInputError(
            "model: its posterior is not a Kronecker posterior (condition it on a shared design "
            "with structure='kronecker')."
        )
    return factors


def design_kernels(model: ManifoldModel, actions: FloatArray) -> FloatArray:
    """e^x_a(x)[m] = exp(-½ (x - x_m)ᵀ (Λ^x_a)⁻¹ (x - x_m)) against the M design actions.

    Args:
        model: A Kronecker-conditioned model.
        actions: Validated actions. Shape (C, dx).

    Returns:
        Shape (dy, C, M).
    """
    return feature_action_kernels(
        actions, _factors(model).design, model.hyperparameters.action_lengthscales
    )


def predict_kronecker(
    model: ManifoldModel, latents: FloatArray, actions: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """GP predictive mean and variance (with noise) at (s, x) through the eigendecompositions.

    With k^s = σ_f² k^s(s, S) (L,) and k^x = k^x(x, X_design) (M,): mean = k^sᵀ B k^x and
    variance = σ_f² - Σ_jk (U_sᵀ k^s)_j² (U_xᵀ k^x)_k² / D[j, k] + σ_n². O(Q (L² + M² + L·M)).

    Args:
        model: A Kronecker-conditioned model.
        latents: Query latents. Shape (Q, ds).
        actions: Query actions. Shape (Q, dx).

    Returns:
        Mean (Q, dy) and variance of y including the noise variance (Q, dy).
    """
    factors = _factors(model)
    h = model.hyperparameters
    latents = as_float_array(latents, "latents", (None, h.latent_dim))
    actions = as_float_array(actions, "actions", (latents.shape[0], h.action_dim))
    n_query = latents.shape[0]
    mean = np.empty((n_query, h.observation_dim))
    variance = np.empty_like(mean)
    action_kernels = design_kernels(model, actions)  # (dy, Q, M)
    for a in range(h.observation_dim):
        sq = np.sum(
            ((latents[:, None, :] - model.latents[None, :, :]) / h.latent_lengthscales[a]) ** 2,
            axis=2,
        )
        k_latent = h.signal_variance[a] * np.exp(-0.5 * sq)  # (Q, L)
        k_action = action_kernels[a]  # (Q, M)
        mean[:, a] = model.data.observation_mean[a] + np.sum(
            (k_latent @ factors.beta_grid[a]) * k_action, axis=1
        )
        left = (k_latent @ factors.latent_eigenvectors[a]) ** 2  # (Q, L)
        right = (k_action @ factors.action_eigenvectors[a]) ** 2  # (Q, M)
        reduction = np.sum((left @ (1.0 / factors.spectrum[a])) * right, axis=1)
        variance[:, a] = np.maximum(h.signal_variance[a] - reduction, 0.0) + h.noise_variance[a]
    return mean, variance


def predictive_covariance_kronecker(
    model: ManifoldModel, latent: FloatArray, actions: FloatArray
) -> FloatArray:
    """Full GP predictive covariance of f_a (noise not included) at (s, x_1..x_T), per feature,
    through the eigendecompositions (no dense K⁻¹).

    With k^s = σ_f² k^s(s, S) (L,) shared by the T touches and K^x_* = k^x(X, X_design) (T, M):
    V_a = σ_f² K^x(X, X) − R diag(w) Rᵀ, R = K^x_* U_x, w_k = Σ_j (U_sᵀ k^s)_j² / D[j, k]; its
    diagonal plus σ_n² is the variance of :func:`predict_kronecker`.

    Args:
        model: A Kronecker-conditioned model.
        latent: s. Shape (ds,).
        actions: x_1..x_T. Shape (T, dx).

    Returns:
        V_a for every feature. Shape (dy, T, T).
    """
    factors = _factors(model)
    h = model.hyperparameters
    s = as_float_array(latent, "latent", (h.latent_dim,))
    x = as_float_array(actions, "actions", (None, h.action_dim))
    action_kernels = design_kernels(model, x)  # (dy, T, M)
    out = np.empty((h.observation_dim, x.shape[0], x.shape[0]))
    for a in range(h.observation_dim):
        sq = np.sum(((s[None, :] - model.latents) / h.latent_lengthscales[a]) ** 2, axis=1)
        k_latent = h.signal_variance[a] * np.exp(-0.5 * sq)  # (L,)
        weights = (k_latent @ factors.latent_eigenvectors[a]) ** 2 @ (1.0 / factors.spectrum[a])
        rotated = action_kernels[a] @ factors.action_eigenvectors[a]  # (T, M)
        diff = (x[:, None, :] - x[None, :, :]) / h.action_lengthscales[a]
        prior = h.signal_variance[a] * np.exp(-0.5 * np.sum(diff**2, axis=2))
        cov = prior - (rotated * weights) @ rotated.T
        out[a] = 0.5 * (cov + cov.T)
    return out


def action_statistics_spectral(
    model: ManifoldModel, actions: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Action statistics of C candidates in the Kronecker form (see the module docstring).

    Args:
        model: A Kronecker-conditioned model.
        actions: Validated candidate actions. Shape (C, dx).

    Returns:
        u_a(x) (C, dy, L) and the trace spectrum t_a(x) (C, dy, L), with
        T_a(x) = U_s diag(t_a(x)) U_sᵀ for U_s = ``kronecker.latent_eigenvectors[a]``.
    """
    factors = _factors(model)
    kernels = design_kernels(model, actions)  # (dy, C, M)
    kernels_t = np.swapaxes(kernels, 1, 2)  # (dy, M, C)
    responses = factors.beta_grid @ kernels_t  # u = B e^x, (dy, L, C)
    rotated = np.swapaxes(factors.action_eigenvectors, 1, 2) @ kernels_t  # U_xᵀ e^x, (dy, M, C)
    spectrum = (1.0 / factors.spectrum) @ rotated**2  # t, (dy, L, C)
    return (
        np.ascontiguousarray(np.moveaxis(responses, 2, 0)),
        np.ascontiguousarray(np.moveaxis(spectrum, 2, 0)),
    )


def action_statistics_derivatives(
    model: ManifoldModel, action: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """u, t of one action and their derivatives with respect to x (Kronecker form).

    ∂e^x_m/∂x_d = -e^x_m (x_d - x_md) / ℓ_ad²; du/dx_d = B ∂e^x/∂x_d;
    dt_j/dx_d = Σ_k 2 ẽ_k (U_xᵀ ∂e^x/∂x_d)_k / D[j, k] with ẽ = U_xᵀ e^x.

    Args:
        model: A Kronecker-conditioned model.
        action: Validated action. Shape (dx,).

    Returns:
        u (dy, L), du/dx (dy, dx, L), t (dy, L), dt/dx (dy, dx, L).
    """
    factors = _factors(model)
    e = design_kernels(model, action[None, :])[:, 0, :]  # (dy, M)
    inverse_sq = 1.0 / model.hyperparameters.action_lengthscales**2  # (dy, dx)
    diff = action[:, None] - factors.design.T  # (dx, M)
    de = -diff[None] * inverse_sq[:, :, None] * e[:, None, :]  # (dy, dx, M)
    beta_t = np.swapaxes(factors.beta_grid, 1, 2)  # (dy, M, L)
    responses = (e[:, None, :] @ beta_t)[:, 0, :]  # (dy, L)
    d_responses = de @ beta_t  # (dy, dx, L)
    vectors = factors.action_eigenvectors  # (dy, M, M)
    rotated = (e[:, None, :] @ vectors)[:, 0, :]  # ẽ = U_xᵀ e, (dy, M)
    d_rotated = de @ vectors  # (dy, dx, M)
    inv_d_t = np.swapaxes(1.0 / factors.spectrum, 1, 2)  # (dy, M, L)
    spectrum = ((rotated**2)[:, None, :] @ inv_d_t)[:, 0, :]  # (dy, L)
    d_spectrum = (2.0 * rotated[:, None, :] * d_rotated) @ inv_d_t  # (dy, dx, L)
    return responses, d_responses, spectrum, d_spectrum
