"""Moment matching (docs/method.md eq. (M3)), mutual information (M4) and the belief update (M5).

The latent s ~ N(μ, Σ) of the touched object is unknown; for an action x the observation y has
a non-Gaussian predictive distribution whose first two moments (and the cross-covariance with s)
are available in closed form. Those moments define a joint Gaussian over (s, y) from which the
mutual information I(s; y | x) and the updated belief follow.

The computation uses the per-object structure of docs/method.md ("Structure that makes it fast"):
the N training latents take only L distinct values, so everything splits into

* **action statistics** (depend on x only, computed once per model for a fixed candidate set):
  u_a(x)[l] = Σ_{i∈l} β_ai e_ai(x) and T_a(x)[l, l'] = Σ_{i∈l, j∈l'} (K_a⁻¹)_ij e_ai(x) e_aj(x);
* **belief terms** (depend on (μ, Σ) only): the L-vectors c_a, the L×L matrices G_ab and the
  L×ds offsets D_a[l] = Σ (Σ + Λ^s_a)⁻¹ (s_l - μ);

and the moments are small contractions of the two, batched over C candidate actions. This is an
exact rewrite of the appendix formula (checked against it in ``tests/core/test_moments.py``).

Every posterior structure of :class:`core.types.GPPosterior` is supported: the dense one over the
training touches, the sparse one over its inducing points (whose latents also take only L
values: the sums over "touches" run over the support points), and the Kronecker one of a shared
design, whose T_a(x) = U_s diag(t_a(x)) U_sᵀ is carried as the L-vector t_a(x) (the "trace
spectrum", :func:`core.gp.kronecker.action_statistics_spectral`) so that nothing of size L² per
candidate is stored and tr(G_aa T_a) = Σ_j t_a[j] (U_sᵀ G_aa U_s)_jj.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from core.errors import InvalidInputError
from core.gp.kernels import feature_action_kernels
from core.gp.kronecker import action_statistics_spectral
from core.gp.posterior import support_points
from core.types import GaussianBelief, ManifoldModel
from core.validation import FloatArray, as_float_array

# Relative floor on the eigenvalues of an updated covariance (update hygiene, docs/method.md).
_EIGENVALUE_FLOOR = 1e-12
# Candidates processed together in action_statistics (bounds memory at O(chunk · N · (dy + dx))).
_CHUNK = 256
# Up to this many objects, per-object sums over support points are products with the one-hot
# indicator (faster than reduceat for few objects).
_GEMM_SUM_MAX_OBJECTS = 8
# Up to this many objects the moments are contracted element-wise (batch-invariant to the bit);
# above, with GEMMs (the element-wise form costs O(C · dy² · L²) in numpy's einsum loops).
_ELEMENTWISE_MAX_OBJECTS = 32


@dataclass(frozen=True)
class ActionStatistics:
    """Action-only statistics of C candidate actions (docs/method.md, structure of (M3)).

    They depend on the model and the actions but not on the belief: compute them once per model
    for a fixed candidate set and reuse them at every touch.

    Attributes:
        actions: The candidate actions x. Shape (C, dx).
        responses: u_a(x)[l] = Σ_{i∈l} β_ai e_ai(x). Shape (C, dy, L).
        trace_blocks: T_a(x)[l, l'] = Σ_{i∈l, j∈l'} (K_a⁻¹)_ij e_ai(x) e_aj(x), with the noisy
            K_a. Shape (C, dy, L, L); or, when ``trace_basis`` is set, the trace spectrum t_a(x)
            with T_a(x) = U_a diag(t_a(x)) U_aᵀ. Shape (C, dy, L).
        trace_basis: U_a (columns), for a Kronecker posterior; ``None`` otherwise.
            Shape (dy, L, L).
    """

    actions: FloatArray
    responses: FloatArray
    trace_blocks: FloatArray
    trace_basis: FloatArray | None = None

    @property
    def n_actions(self) -> int:
        """C."""
        return int(self.actions.shape[0])

    def subset(self, indices: np.ndarray) -> ActionStatistics:
        """The statistics of some of the candidates (same order as ``indices``)."""
        return ActionStatistics(
            actions=self.actions[indices],
            responses=self.responses[indices],
            trace_blocks=self.trace_blocks[indices],
            trace_basis=self.trace_basis,
        )

    def dense_trace_blocks(self) -> FloatArray:
        """T_a(x) as L × L matrices, expanded from the spectrum if needed. Shape (C, dy, L, L)."""
        if self.trace_basis is None:
            return self.trace_blocks
        basis = self.trace_basis
        return np.asarray(
            np.einsum("alj,caj,amj->calm", basis, self.trace_blocks, basis), dtype=np.float64
        )


@dataclass(frozen=True)
class BeliefTerms:
    """Belief-only terms of the structured (M3) (independent of the action).

    Attributes:
        weights: c_a[l] = σ_f,a² |Σ (Λ^s_a)⁻¹ + I|^(-½) exp(-½ (μ - s_l)ᵀ (Σ + Λ^s_a)⁻¹ (μ - s_l)).
            Shape (dy, L).
        pair_weights: G_ab[l, l'], the belief part of Q_ab. Shape (dy, dy, L, L).
        offsets: D_a[l] = Σ (Σ + Λ^s_a)⁻¹ (s_l - μ). Shape (dy, L, ds).
        spectral_weights: diag(U_aᵀ G_aa U_a) for a Kronecker posterior (tr(G_aa T_a) is their
            dot product with the trace spectrum), ``None`` otherwise. Shape (dy, L).
    """

    weights: FloatArray
    pair_weights: FloatArray
    offsets: FloatArray
    spectral_weights: FloatArray | None = None


@dataclass(frozen=True)
class PredictiveMoments:
    """Moments of the joint Gaussian over (s, y) for C candidate actions (docs/method.md eq. (M3)).

    Attributes:
        mean: m = E[y], including the model's constant mean. Shape (C, dy).
        cov: S = Cov[y], including the observation noise. Shape (C, dy, dy).
        cross_cov: C = Cov[s, y]. Shape (C, ds, dy).
        actions: The actions the moments belong to. Shape (C, dx).
    """

    mean: FloatArray
    cov: FloatArray
    cross_cov: FloatArray
    actions: FloatArray

    @property
    def n_actions(self) -> int:
        """C."""
        return int(self.mean.shape[0])


def object_indicator(model: ManifoldModel) -> FloatArray:
    """One-hot matrix of the object of every support point (the touches, or the inducing points
    of a sparse posterior). Shape (N, L)."""
    objects, _ = support_points(model)
    indicator = np.zeros((objects.shape[0], model.data.n_objects))
    indicator[np.arange(objects.shape[0]), objects] = 1.0
    return indicator


def action_kernels(model: ManifoldModel, actions: FloatArray) -> FloatArray:
    """e_ai(x) = exp(-½ (x - x_i)ᵀ (Λ^x_a)⁻¹ (x - x_i)) for every feature, action and support
    point (training touch, or inducing point of a sparse posterior).

    (:func:`core.gp.kernels.feature_action_kernels`).

    Args:
        model: A conditioned model.
        actions: Validated actions. Shape (C, dx).

    Returns:
        Shape (dy, C, N).
    """
    _, support = support_points(model)
    return feature_action_kernels(actions, support, model.hyperparameters.action_lengthscales)


def _check_actions(model: ManifoldModel, actions: FloatArray, name: str) -> FloatArray:
    return as_float_array(actions, name, (None, model.hyperparameters.action_dim))


def action_statistics(model: ManifoldModel, actions: FloatArray) -> ActionStatistics:
    """Action statistics u_a(x) and T_a(x) of C candidate actions (docs/method.md (M3)).

    Cost O(C · dy · N · (dx + N)) over the N support points (dense and sparse posteriors);
    O(C · dy · (M² + L·M)) on a Kronecker posterior of M design actions, whose statistics hold
    the trace spectrum (see :class:`ActionStatistics`). Memory O(C · dy · L²) (O(C · dy · L) for
    Kronecker) plus a bounded working set.

    Args:
        model: A conditioned model.
        actions: Candidate actions. Shape (C, dx).

    Raises:
        InvalidInputError: ``actions`` has the wrong shape or non-finite entries.
    """
    actions = _check_actions(model, actions, "actions").copy()
    factors = model.posterior.kronecker
    if factors is not None:
        responses, spectrum = action_statistics_spectral(model, actions)
        for array in (actions, responses, spectrum):
            array.flags.writeable = False
        return ActionStatistics(
            actions=actions,
            responses=responses,
            trace_blocks=spectrum,
            trace_basis=factors.latent_eigenvectors,
        )
    beta = model.posterior.beta  # (dy, N)
    gram_inverse = model.posterior.gram_inverse  # (dy, N, N)
    n_features, n_objects, n_actions = beta.shape[0], model.data.n_objects, actions.shape[0]
    objects, _ = support_points(model)
    blocks = SupportBlocks(objects, n_objects)
    responses = np.empty((n_actions, n_features, n_objects))
    trace_blocks = np.zeros((n_actions, n_features, n_objects, n_objects))
    for start in range(0, n_actions, _CHUNK):
        chunk = slice(start, min(start + _CHUNK, n_actions))
        kernels = action_kernels(model, actions[chunk])  # (dy, c, N)
        # u_a(x)[l] = Σ_{i∈l} β_ai e_ai(x)
        if blocks.reduce:
            responses[chunk] = np.swapaxes(blocks.sums(kernels * beta[:, None, :]), 0, 1)
        else:
            weighted_beta = beta[:, :, None] * blocks.indicator[None]  # β_ai [obj_i = l]
            responses[chunk] = np.swapaxes(kernels @ weighted_beta, 0, 1)
        for a in range(n_features):
            for right, block in enumerate(blocks.members):
                if block is None:
                    continue  # an object without inducing points: its blocks are 0
                # Y[c, i] = Σ_{j∈l'} (K_a⁻¹)_ij e_aj(x_c)
                partial = kernels[a][:, block] @ gram_inverse[a][block, :]
                partial *= kernels[a]
                trace_blocks[chunk, a, :, right] = blocks.sums(partial)
    for array in (actions, responses, trace_blocks):
        array.flags.writeable = False
    return ActionStatistics(actions=actions, responses=responses, trace_blocks=trace_blocks)


class SupportBlocks:
    """The support points of each object, and sums over them along the last axis.

    Args:
        objects: Object of every support point. Shape (N,).
        n_objects: L.

    Support points grouped by object (the usual case: training data and inducing points come
    object by object) are contiguous slices (views, not copies); otherwise index arrays. Sums
    use ``reduceat`` over grouped points when there are more than :data:`_GEMM_SUM_MAX_OBJECTS`
    objects (O(N)), else a product with the one-hot indicator (O(N · L), faster for small L).
    """

    def __init__(self, objects: np.ndarray, n_objects: int) -> None:
        self.n_objects = n_objects
        counts = np.bincount(objects, minlength=n_objects)
        self.present = np.flatnonzero(counts > 0)
        grouped = bool(np.all(np.diff(objects) >= 0))
        self.reduce = grouped and n_objects > _GEMM_SUM_MAX_OBJECTS
        self.indicator = np.zeros((objects.shape[0], n_objects))
        self.indicator[np.arange(objects.shape[0]), objects] = 1.0
        ends = np.cumsum(counts)
        self.starts = (ends - counts)[self.present].astype(np.intp)
        self.members: list[slice | np.ndarray | None] = []
        for obj in range(n_objects):
            if not counts[obj]:
                self.members.append(None)
            elif grouped:
                self.members.append(slice(int(ends[obj] - counts[obj]), int(ends[obj])))
            else:
                self.members.append(np.flatnonzero(objects == obj))

    def sums(self, values: FloatArray, axis: int = -1) -> FloatArray:
        """Σ over each object's support points along ``axis`` (of length N), which becomes an
        axis of length L. (Reducing a leading axis is fastest: the sums are then vectorised.)"""
        if not self.reduce:
            moved = np.moveaxis(values, axis, -1) @ self.indicator
            return np.asarray(np.moveaxis(moved, -1, axis), dtype=np.float64)
        axis = axis % values.ndim
        shape = list(values.shape)
        shape[axis] = self.n_objects
        out = np.zeros(shape)
        index: list[slice | np.ndarray | int] = [slice(None)] * values.ndim
        if axis == values.ndim - 1:
            index[axis] = self.present
            out[tuple(index)] = np.add.reduceat(values, self.starts, axis=axis)
            return out
        # reduceat is slow along a leading axis; summing each block's slice is vectorised.
        source: list[slice | np.ndarray | int] = [slice(None)] * values.ndim
        for obj in self.present:
            index[axis] = int(obj)
            source[axis] = self.members[obj]  # type: ignore[assignment]
            out[tuple(index)] = values[tuple(source)].sum(axis=axis)
        return out


def _check_belief(model: ManifoldModel, belief: GaussianBelief) -> None:
    if belief.dim != model.latent_dim:
        raise InvalidInputError(
            f"belief: latent dimension {belief.dim} does not match the model's "
            f"latent_dim={model.latent_dim}."
        )


def belief_terms(model: ManifoldModel, belief: GaussianBelief) -> BeliefTerms:
    """Belief-only terms c_a, G_ab and D_a of the structured (M3). Cost O(dy² L² ds + dy² ds³).

    Args:
        model: A conditioned model (latents S of shape (L, ds)).
        belief: s ~ N(μ, Σ), ds-dimensional.
    """
    _check_belief(model, belief)
    h = model.hyperparameters
    mu, sigma = belief.mean, belief.cov
    latents = model.latents  # (L, ds)
    lam = h.latent_lengthscales**2  # (dy, ds): diagonals of Λ^s_a
    signal = h.signal_variance  # (dy,)
    ds = mu.shape[0]

    # docs/method.md eq. (M3): q_ai's belief part, c_a[l].
    sigma_plus_lam = sigma[None, :, :] + lam[:, :, None] * np.eye(ds)[None]  # (dy, ds, ds)
    diff = mu[None, :] - latents  # (L, ds): μ - s_l
    rhs = np.broadcast_to(diff.T[None], (lam.shape[0], ds, latents.shape[0]))
    solved = np.linalg.solve(sigma_plus_lam, rhs)  # (dy, ds, L): (Σ + Λ_a)⁻¹ (μ - s_l)
    quad = np.einsum("ld,adl->al", diff, solved)
    _, logdet_sum = np.linalg.slogdet(sigma_plus_lam)
    log_det_ratio = logdet_sum - np.sum(np.log(lam), axis=1)  # log |Σ Λ_a⁻¹ + I|
    weights = signal[:, None] * np.exp(-0.5 * log_det_ratio[:, None] - 0.5 * quad)
    # D_a[l] = Σ (Σ + Λ_a)⁻¹ (s_l - μ)
    offsets = -np.einsum("ij,ajl->ali", sigma, solved)

    # docs/method.md eq. (M3): Q_ab,ij's belief part, G_ab[l, l'].
    lam_a = lam[:, None, :]  # (dy, 1, ds)
    lam_b = lam[None, :, :]  # (1, dy, ds)
    lam_sum = lam_a + lam_b  # (dy, dy, ds): Λ_a + Λ_b
    inv_sum = 1.0 / lam_a + 1.0 / lam_b  # Λ_a⁻¹ + Λ_b⁻¹
    det_matrix = inv_sum[..., :, None] * sigma[None, None] + np.eye(ds)
    _, logdet_pair = np.linalg.slogdet(det_matrix)  # log |(Λ_a⁻¹ + Λ_b⁻¹) Σ + I|
    r_matrix = (1.0 / inv_sum)[..., :, None] * np.eye(ds) + sigma[None, None]  # R_ab
    r_inverse = np.asarray(np.linalg.inv(r_matrix), dtype=np.float64)  # (dy, dy, ds, ds)
    # s̄_ll' = Λ_b (Λ_a + Λ_b)⁻¹ s_l + Λ_a (Λ_a + Λ_b)⁻¹ s_l'
    w_left = lam_b / lam_sum  # (dy, dy, ds)
    w_right = lam_a / lam_sum
    if latents.shape[0] <= _ELEMENTWISE_MAX_OBJECTS:
        sep = latents[:, None, :] - latents[None, :, :]  # (L, L, ds): s_l - s_l'
        sep_quad = np.einsum("lmd,abd->ablm", sep**2, 1.0 / lam_sum)
        s_bar = (
            w_left[:, :, None, None, :] * latents[None, None, :, None, :]
            + w_right[:, :, None, None, :] * latents[None, None, None, :, :]
        )
        centred = s_bar - mu  # (dy, dy, L, L, ds)
        mean_quad = np.einsum("ablmi,abij,ablmj->ablm", centred, r_inverse, centred)
        exponent = -0.5 * sep_quad - 0.5 * mean_quad
    else:
        exponent = _pair_exponent(latents, mu, 1.0 / lam_sum, w_left, w_right, r_inverse)
    pair_weights = (
        (signal[:, None] * signal[None, :])[:, :, None, None]
        * np.exp(-0.5 * logdet_pair)[:, :, None, None]
        * np.exp(exponent)
    )
    factors = model.posterior.kronecker
    spectral = None
    if factors is not None:
        spectral = _spectral_weights(pair_weights, factors.latent_eigenvectors)
    return BeliefTerms(
        weights=weights, pair_weights=pair_weights, offsets=offsets, spectral_weights=spectral
    )


def _pair_exponent(
    latents: FloatArray,
    mu: FloatArray,
    inv_lam_sum: FloatArray,
    w_left: FloatArray,
    w_right: FloatArray,
    r_inverse: FloatArray,
) -> FloatArray:
    """-½ (sep_quad + mean_quad) of G_ab[l, l'] without (dy, dy, L, L, ds) temporaries.

    Both quadratic forms are expanded into per-l terms, per-l' terms and one batched GEMM of
    inner dimension 2·ds: with g = (Λ_a + Λ_b)⁻¹, p_l = w_left ∘ s_l - μ, q_l' = w_right ∘ s_l',
    sep_quad = s_lᵀ g s_l + s_l'ᵀ g s_l' - 2 s_lᵀ g s_l' and
    mean_quad = p_lᵀ R⁻¹ p_l + q_l'ᵀ R⁻¹ q_l' + 2 p_lᵀ R⁻¹ q_l'. O(dy² L² ds). Shape (dy, dy, L, L).
    """
    s = latents[None, None, :, :]  # (1, 1, L, ds)
    p = w_left[:, :, None, :] * s - mu  # (dy, dy, L, ds)
    q = w_right[:, :, None, :] * s
    p_r = p @ r_inverse  # (dy, dy, L, ds)
    q_r = q @ r_inverse
    s_g = s * inv_lam_sum[:, :, None, :]
    row = np.sum(s_g * s, axis=3) + np.sum(p_r * p, axis=3)  # terms of l
    col = np.sum(s_g * s, axis=3) + np.sum(q_r * q, axis=3)  # terms of l'
    left = np.concatenate([-2.0 * s_g, 2.0 * p_r], axis=3)  # (dy, dy, L, 2 ds)
    right = np.concatenate([np.broadcast_to(s, q.shape), q], axis=3)
    exponent = left @ np.swapaxes(right, 2, 3)  # cross terms, (dy, dy, L, L)
    exponent += row[..., :, None]
    exponent += col[..., None, :]
    exponent *= -0.5
    return np.asarray(exponent, dtype=np.float64)


def _spectral_weights(pair_weights: FloatArray, basis: FloatArray) -> FloatArray:
    """diag(U_aᵀ G_aa U_a) for every feature. Shape (dy, L)."""
    diagonal_pair = np.einsum("aalm->alm", pair_weights)  # G_aa
    return np.asarray(np.sum(basis * (diagonal_pair @ basis), axis=1), dtype=np.float64)


def moments_from_terms(
    model: ManifoldModel, terms: BeliefTerms, stats: ActionStatistics
) -> PredictiveMoments:
    """Contract belief terms with action statistics into m, S and C (docs/method.md eq. (M3)).

    Cost O(C · dy² · L²) on top of the terms.
    """
    h = model.hyperparameters
    u = stats.responses  # (C, dy, L)
    weights, pair = terms.weights, terms.pair_weights
    n_objects = u.shape[2]
    centred_mean = np.einsum("al,cal->ca", weights, u)  # m_a - mean_a = c_aᵀ u_a
    if n_objects <= _ELEMENTWISE_MAX_OBJECTS:
        # Element-wise contractions: a candidate's moments do not depend on the batch it is in.
        pair_u = np.einsum("ablm,cbm->cabl", pair, u)
        cov = np.einsum("cal,cabl->cab", u, pair_u)  # u_aᵀ G_ab u_b
    else:
        # (G_ab u_b)[l] for every candidate as GEMMs G_ab (L, L) @ u_b (L, C); results agree
        # with the element-wise form to rounding.
        pair_u = pair @ np.moveaxis(u, 0, 2)[None]  # (dy_a, dy_b, L, C)
        cov = np.einsum("cal,ablc->cab", u, pair_u)  # u_aᵀ G_ab u_b
    cov -= centred_mean[:, :, None] * centred_mean[:, None, :]
    if stats.trace_basis is not None:
        spectral = terms.spectral_weights
        if spectral is None:
            spectral = _spectral_weights(pair, stats.trace_basis)
        trace = np.einsum("aj,caj->ca", spectral, stats.trace_blocks)  # tr(K_a⁻¹ Q_aa)
    else:
        diagonal_pair = np.einsum("aalm->alm", pair)  # G_aa
        trace = np.einsum("alm,calm->ca", diagonal_pair, stats.trace_blocks)  # tr(K_a⁻¹ Q_aa)
    features = np.arange(h.observation_dim)
    # docs/method.md eq. (M3): δ_ab (σ_f,a² - tr(K_a⁻¹ Q_aa)) + δ_ab σ_n,a²  (noise belongs in S)
    cov[:, features, features] += h.signal_variance - trace + h.noise_variance
    cov = 0.5 * (cov + np.swapaxes(cov, 1, 2))
    cross_cov = np.einsum("al,cal,ald->cda", weights, u, terms.offsets)
    return PredictiveMoments(
        mean=centred_mean + model.data.observation_mean,
        cov=cov,
        cross_cov=cross_cov,
        actions=stats.actions,
    )


def predictive_moments(
    model: ManifoldModel, belief: GaussianBelief, stats: ActionStatistics
) -> PredictiveMoments:
    """Predictive moments m, S (with noise) and C of every candidate (docs/method.md eq. (M3)).

    Args:
        model: The model the statistics were computed with.
        belief: s ~ N(μ, Σ).
        stats: Action statistics from :func:`action_statistics` for this model.

    Raises:
        InvalidInputError: The belief or statistics do not match the model.
    """
    h = model.hyperparameters
    expected = (h.observation_dim, model.data.n_objects)
    if stats.responses.shape[1:] != expected or stats.actions.shape[1] != h.action_dim:
        raise InvalidInputError(
            f"stats: computed for (dy, L) = {stats.responses.shape[1:]} and "
            f"dx = {stats.actions.shape[1]}, but the model has (dy, L) = {expected} and "
            f"dx = {h.action_dim}; recompute them with action_statistics(model, actions)."
        )
    return moments_from_terms(model, belief_terms(model, belief), stats)


def _check_moments(moments: PredictiveMoments, belief: GaussianBelief) -> None:
    if moments.cross_cov.shape[1] != belief.dim:
        raise InvalidInputError(
            f"moments: cross-covariance is for ds={moments.cross_cov.shape[1]}, "
            f"the belief has ds={belief.dim}."
        )


def mutual_information(moments: PredictiveMoments, belief: GaussianBelief) -> FloatArray:
    """U1 = ½ [log det Σ - log det(Σ - C S⁻¹ Cᵀ)] for every candidate (docs/method.md eq. (M4)).

    Computed as -½ Σ_k log(1 - ρ_k²) with ρ_k the canonical correlations of the moment-matched
    joint (eigenvalues of Σ^(-½) C S⁻¹ Cᵀ Σ^(-½)), which avoids cancellation when U1 is small.

    Args:
        moments: Predictive moments of C candidates under ``belief``.
        belief: The belief the moments were computed under.

    Returns:
        Mutual information in nats. Shape (C,).
    """
    _check_moments(moments, belief)
    sigma_factor = np.linalg.cholesky(belief.cov)
    s_factor = np.linalg.cholesky(moments.cov)  # (C, dy, dy)
    # B = L_Σ⁻¹ C L_S⁻ᵀ, so B Bᵀ = L_Σ⁻¹ C S⁻¹ Cᵀ L_Σ⁻ᵀ
    left = np.linalg.solve(sigma_factor[None], moments.cross_cov)  # (C, ds, dy)
    whitened = np.linalg.solve(s_factor, np.swapaxes(left, 1, 2))  # (C, dy, ds) = Bᵀ
    gram = np.swapaxes(whitened, 1, 2) @ whitened  # (C, ds, ds)
    rho_sq = np.clip(np.linalg.eigvalsh(gram), 0.0, 1.0 - 1e-15)
    return np.asarray(-0.5 * np.sum(np.log1p(-rho_sq), axis=1), dtype=np.float64)


def update_belief(
    belief: GaussianBelief, moments: PredictiveMoments, index: int, observation: FloatArray
) -> GaussianBelief:
    """Condition the belief on the observation of candidate ``index`` (docs/method.md eq. (M5)).

    μ' = μ + C S⁻¹ (y - m),  Σ' = Σ - C S⁻¹ Cᵀ; Σ' is symmetrised and its eigenvalues are kept
    above 1e-12 times the largest.

    Args:
        belief: The belief the moments were computed under.
        moments: Predictive moments of C candidates.
        index: Which candidate was performed, 0 ≤ index < C.
        observation: The observation y. Shape (dy,).

    Raises:
        InvalidInputError: Bad index, or an observation of the wrong shape or non-finite.
    """
    _check_moments(moments, belief)
    n = moments.n_actions
    if isinstance(index, bool) or not isinstance(index, int | np.integer) or not 0 <= index < n:
        raise InvalidInputError(f"index: expected an integer in 0..{n - 1}, received {index!r}.")
    y = as_float_array(observation, "observation", (moments.mean.shape[1],))
    cross = moments.cross_cov[index]  # (ds, dy)
    gain = np.linalg.solve(moments.cov[index], cross.T).T  # C S⁻¹, (ds, dy)
    mean = belief.mean + gain @ (y - moments.mean[index])
    cov = belief.cov - gain @ cross.T
    cov = 0.5 * (cov + cov.T)
    eigenvalues, vectors = np.linalg.eigh(cov)
    floor = _EIGENVALUE_FLOOR * max(float(np.max(np.abs(eigenvalues))), 1e-300)
    if eigenvalues.min() < floor:
        cov = (vectors * np.maximum(eigenvalues, floor)) @ vectors.T
        cov = 0.5 * (cov + cov.T)
    return GaussianBelief(mean=mean, cov=cov)
