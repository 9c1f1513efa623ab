"""Condition the per-feature GPs on the training touches (docs/method.md eq. (M1)–(M2)).

Three posterior structures (:class:`core.types.GPPosterior`): ``"dense"`` (Cholesky of each
N × N Gram matrix), ``"kronecker"`` (exact, for a complete shared action design:
:mod:`core.gp.kronecker`) and ``"sparse"`` (the approximate inducing-point posterior of
:mod:`core.gp.sparse`, for large data without a shared design). :func:`condition` picks one with
``structure="auto"`` (see :func:`resolve_structure`); :func:`predict` works on all three.
"""

from __future__ import annotations

from typing import Literal, Protocol

import numpy as np
import scipy.linalg

from core.errors import InvalidInputError
from core.gp.factor_inverse import spd_inverse
from core.gp.kernels import squared_exponential
from core.gp.kronecker import (
    KroneckerLikelihood,
    SharedDesign,
    condition_kronecker,
    find_shared_design,
    predict_kronecker,
)
from core.gp.kronecker import require_shared_design as _require_shared_design
from core.gp.likelihood import ManifoldLikelihood
from core.gp.linalg import cholesky_with_jitter, log_det_from_cholesky
from core.gp.parameters import ParameterLayout, check_conditioning
from core.gp.placement_groups import (
    add_shared_offsets,
    checked_placement_variance,
    shared_groups,
)
from core.gp.sparse import DEFAULT_INDUCING_POINTS, SparseLikelihood, condition_sparse
from core.gp.tied_likelihood import Kernels, TiedLikelihood, tied_structure
from core.types import (
    FitDiagnostics,
    GPPosterior,
    Hyperparameters,
    ManifoldModel,
    PosteriorStructure,
    TrainingData,
)
from core.validation import FloatArray, IntArray, as_float_array

#: What :func:`condition` may be asked for.
Structure = Literal["auto", "dense", "kronecker", "sparse"]
STRUCTURES: tuple[str, ...] = ("auto", "dense", "kronecker", "sparse")

#: ``structure="auto"`` uses the sparse path above this many touches when the design is not
#: shared (a dense posterior stores dy · N² floats: 360 MB for dy = 5 at this N).
AUTO_SPARSE_ABOVE = 3000


def resolve_structure(
    data: TrainingData, structure: Structure = "auto"
) -> tuple[PosteriorStructure, SharedDesign | None]:
    """Which posterior structure to use for ``data``.

    ``"auto"``: ``"kronecker"`` when every object was touched with the same actions (a complete
    shared design, :func:`core.gp.kronecker.find_shared_design`); otherwise ``"dense"`` up to
    :data:`AUTO_SPARSE_ABOVE` touches and ``"sparse"`` above. Missing touches (an object lacking
    some design actions) therefore fall back to dense (exact) or sparse (approximate).

    Args:
        data: Training touches.
        structure: ``"auto"``, ``"dense"``, ``"kronecker"`` or ``"sparse"``.

    Returns:
        The structure and, for ``"kronecker"``, the design.

    Raises:
        InvalidInputError: Unknown ``structure``, or ``"kronecker"`` on data without a complete
            shared design (the message names the first object that breaks it).
    """
    if structure not in STRUCTURES:
        raise InvalidInputError(
            f"structure: expected one of {', '.join(STRUCTURES)}, received {structure!r}."
        )
    if structure == "kronecker":
        return "kronecker", _require_shared_design(data)
    if structure == "auto":
        design = find_shared_design(data)
        if design is not None:
            return "kronecker", design
        return ("sparse" if data.n_touches > AUTO_SPARSE_ABOVE else "dense"), None
    return ("dense" if structure == "dense" else "sparse"), None


class Likelihood(Protocol):
    """What a fit needs from a likelihood: :class:`core.gp.likelihood.ManifoldLikelihood` (dense),
    :class:`core.gp.kronecker.KroneckerLikelihood` (exact, shared design) or
    :class:`core.gp.sparse.SparseLikelihood` (the negative variational bound)."""

    data: TrainingData
    layout: ParameterLayout
    max_jitter: float
    evaluations: int

    def value(self, vector: FloatArray) -> float:
        """-log p (or -F) at a packed vector."""
        ...

    def value_and_gradient(self, vector: FloatArray) -> tuple[float, FloatArray]:
        """The value and its gradient with respect to the packed vector."""
        ...


def make_likelihood(
    data: TrainingData,
    latent_dim: int,
    structure: Structure = "auto",
    n_inducing: int = DEFAULT_INDUCING_POINTS,
    threads: int = 1,
    placement_variance: FloatArray | None = None,
    kernels: Kernels = "per_feature",
) -> Likelihood:
    """The likelihood for ``data`` under a structure (see :func:`resolve_structure`).

    Args:
        data: Training touches.
        latent_dim: ds ≥ 1.
        structure: ``"auto"``, ``"dense"``, ``"kronecker"`` or ``"sparse"``.
        n_inducing: Inducing points of the sparse path.
        threads: Threads of a dense evaluation's features (:mod:`core.gp.likelihood`).
        placement_variance: σ_b² per feature, held fixed, for touches sharing a placement
            (dense only, see :class:`core.gp.likelihood.ManifoldLikelihood`). Shape (dy,).
        kernels: ``"tied"``: length-scales shared by the features
            (:class:`core.gp.tied_likelihood.TiedLikelihood`, dense, its own fast path; ``threads``
            does not apply).

    Raises:
        InvalidInputError: A placement variance for a Kronecker or sparse structure, or for
            tied kernels; tied kernels with a structure they cannot use
            (:func:`core.gp.tied_likelihood.tied_structure`).
    """
    if kernels == "tied":
        tied_structure(data, structure, AUTO_SPARSE_ABOVE)
        if placement_variance is not None:
            raise InvalidInputError(
                "placement_variance: tied kernels have no placement effect in their likelihood "
                "(σ_b² Z Zᵀ would break the eigenbasis the features share)."
            )
        return TiedLikelihood(data, latent_dim)
    chosen, design = resolve_structure(data, structure)
    if placement_variance is not None and chosen != "dense":
        raise InvalidInputError(
            f"placement_variance: only the dense likelihood has a placement effect, not {chosen!r}."
        )
    if chosen == "kronecker":
        return KroneckerLikelihood(data, latent_dim, design)
    if chosen == "sparse":
        return SparseLikelihood(data, latent_dim, n_inducing=n_inducing)
    return ManifoldLikelihood(data, latent_dim, threads, placement_variance)


def support_points(model: ManifoldModel) -> tuple[IntArray, FloatArray]:
    """Object index (n,) and actions (n, dx) of the points the posterior's β and K⁻¹ refer to:
    the training touches, or the inducing points of a sparse posterior."""
    inducing = model.posterior.inducing
    if inducing is not None:
        return inducing.object_index, inducing.actions
    return model.data.object_index, model.data.actions


def gram_matrix(
    data: TrainingData,
    latents: FloatArray,
    hyperparameters: Hyperparameters,
    feature: int,
    placement_variance: FloatArray | None = None,
) -> FloatArray:
    """Noisy Gram matrix K_a = σ_f² K^s[obj, obj] ∘ K^x + σ_n² I of one feature (M1).

    Args:
        data: Training touches (N of them).
        latents: Object latents. Shape (L, ds).
        hyperparameters: GP hyperparameters.
        feature: The feature index a.
        placement_variance: σ_b² per feature, shared by touches of one placement (added to
            their off-diagonal entries, :mod:`core.gp.placement_groups`); ``None``: none.
            Shape (dy,).

    Returns:
        K_a. Shape (N, N).
    """
    h = hyperparameters
    latent_gram = squared_exponential(latents, latents, h.latent_lengthscales[feature])
    action_gram = squared_exponential(data.actions, data.actions, h.action_lengthscales[feature])
    obj = data.object_index
    gram = h.signal_variance[feature] * latent_gram[np.ix_(obj, obj)] * action_gram
    gram[np.diag_indices_from(gram)] += h.noise_variance[feature]
    if placement_variance is not None:
        groups = shared_groups(data.object_index, data.placement_index)
        add_shared_offsets(gram, groups, float(placement_variance[feature]))
    return np.asarray(gram, dtype=np.float64)


def condition(
    data: TrainingData,
    latents: FloatArray,
    hyperparameters: Hyperparameters,
    diagnostics: FitDiagnostics | None = None,
    structure: Structure = "auto",
    n_inducing: int = DEFAULT_INDUCING_POINTS,
    placement_variance: FloatArray | None = None,
) -> ManifoldModel:
    """Build a :class:`ManifoldModel`: β_a, K_a⁻¹ (or its structured form) and the
    log-likelihood.

    The dense path factors each K_a (Cholesky) and stores K_a⁻¹. A complete shared design goes
    through the eigendecompositions instead (exact, :func:`core.gp.kronecker.condition_kronecker`);
    ``"sparse"`` builds the inducing-point posterior (:func:`core.gp.sparse.condition_sparse`,
    approximate; ``log_likelihood`` is then the variational bound).

    Args:
        data: Training touches.
        latents: Object latents s_l. Shape (L, ds).
        hyperparameters: Per-feature hyperparameters (dy features, ds latent, dx action dims).
        diagnostics: Optional fit diagnostics to attach.
        structure: ``"auto"`` (default, see :func:`resolve_structure`), ``"dense"``,
            ``"kronecker"`` or ``"sparse"``.
        n_inducing: Inducing points of the sparse path.
        placement_variance: σ_b² per feature in the training covariance: touches sharing a
            placement (``data.placement_index``) share an offset (:mod:`core.gp.placement_groups`).
            The model keeps it (``placement_variance``, ``placement_in_fit``). Dense only: a
            Kronecker structure asked with ``"auto"`` becomes dense (the offsets break the
            shared design's product form). ``None``: independent noise. Shape (dy,).

    Raises:
        InvalidInputError: Shapes disagree between data, latents and hyperparameters, the
            structure cannot be used for the data, or a placement variance is given for a
            sparse or Kronecker structure, out of range or without recorded placements.
        NotPositiveDefiniteError: A Gram matrix is singular even with jitter.
    """
    if placement_variance is not None:
        return _condition_with_placements(
            data, latents, hyperparameters, diagnostics, structure, placement_variance
        )
    chosen, design = resolve_structure(data, structure)
    if chosen == "kronecker":
        return condition_kronecker(data, latents, hyperparameters, diagnostics, design)
    if chosen == "sparse":
        return condition_sparse(data, latents, hyperparameters, diagnostics, n_inducing=n_inducing)
    return _condition_dense(data, latents, hyperparameters, diagnostics, None)


def _condition_with_placements(
    data: TrainingData,
    latents: FloatArray,
    hyperparameters: Hyperparameters,
    diagnostics: FitDiagnostics | None,
    structure: Structure,
    placement_variance: FloatArray,
) -> ManifoldModel:
    """:func:`condition` with σ_b² in the training covariance (the dense path)."""
    h = hyperparameters
    variance = checked_placement_variance(placement_variance, h.noise_variance, h.observation_dim)
    if data.placement_index is None:
        raise InvalidInputError(
            "placement_variance: the training touches record no placements to share an offset."
        )
    chosen, _ = resolve_structure(data, structure)
    if chosen == "sparse" or structure == "kronecker":
        raise InvalidInputError(
            f"placement_variance: a placement effect in the training covariance needs the "
            f"dense posterior, not {chosen!r} (structure {structure!r})."
        )
    return _condition_dense(data, latents, h, diagnostics, variance)


def _condition_dense(
    data: TrainingData,
    latents: FloatArray,
    hyperparameters: Hyperparameters,
    diagnostics: FitDiagnostics | None,
    placement_variance: FloatArray | None,
) -> ManifoldModel:
    """The dense posterior: each K_a⁻¹ stored, with β_a = K_a⁻¹ y_a.

    K_a⁻¹ comes from its factor in place (:func:`core.gp.factor_inverse.spd_inverse`, the
    likelihood's own route: n³ flops against 2n³ for solves against the identity); only a K_a
    whose plain factorisation fails takes the jitter ladder and solves with its factor.
    """
    h = hyperparameters
    latents = check_conditioning(data, latents, h)
    n = data.n_touches
    centred = data.observations - data.observation_mean
    beta = np.empty((h.observation_dim, n))
    gram_inverse = np.empty((h.observation_dim, n, n))
    jitter = np.zeros(h.observation_dim)
    log_likelihood = 0.0
    for a in range(h.observation_dim):
        gram = gram_matrix(data, latents, h, a, placement_variance)
        inverse = np.asfortranarray(gram)
        info, log_det = spd_inverse(inverse)
        if info == 0:
            upper = np.triu(inverse)
            gram_inverse[a] = upper + np.triu(upper, 1).T
            beta[a] = gram_inverse[a] @ centred[:, a]
        else:
            factor, jitter[a] = cholesky_with_jitter(gram, what=f"Gram matrix of feature {a}")
            beta[a] = scipy.linalg.cho_solve((factor, True), centred[:, a], check_finite=False)
            gram_inverse[a] = scipy.linalg.cho_solve((factor, True), np.eye(n), check_finite=False)
            log_det = log_det_from_cholesky(factor)
        # docs/method.md eq. (M2)
        log_likelihood += (
            -0.5 * float(centred[:, a] @ beta[a]) - 0.5 * log_det - 0.5 * n * np.log(2.0 * np.pi)
        )
    latents.flags.writeable = False
    for array in (beta, gram_inverse, jitter):
        array.flags.writeable = False
    return ManifoldModel(
        data=data,
        latents=latents,
        hyperparameters=h,
        posterior=GPPosterior(beta=beta, gram_inverse=gram_inverse, jitter=jitter),
        log_likelihood=float(log_likelihood),
        diagnostics=diagnostics,
        placement_variance=placement_variance,
        placement_in_fit=placement_variance is not None,
    )


def predict(
    model: ManifoldModel, latents: FloatArray, actions: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Predictive mean and variance of the raw observation at deterministic inputs (s, x).

    In raw units: with an observation transform y' = M (y - c) (``model.transform``) the
    model-space prediction (:func:`predict_model_space`) is mapped back, mean M⁻¹ m' + c and the
    marginal variances diag(M⁻¹ diag(v') M⁻ᵀ) (the features are correlated in raw units; the
    full covariance is ``model.observation_transform.restore_covariance``). Without a transform
    the two functions agree exactly. Works on every posterior structure.

    Args:
        model: A conditioned model.
        latents: Query latents. Shape (Q, ds).
        actions: Query actions. Shape (Q, dx).

    Returns:
        Mean (Q, dy) and variance of y including the noise (Q, dy), in raw units.
    """
    mean, variance = predict_model_space(model, latents, actions)
    transform = model.transform
    if transform is None or transform.is_identity:
        return mean, variance
    return transform.restore_mean(mean), transform.restore_variance(variance)


def predict_model_space(
    model: ManifoldModel, latents: FloatArray, actions: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """GP predictive mean and variance of the model-space observation y' at inputs (s, x).

    The per-feature GPs' own predictive (independent across features); equal to
    :func:`predict` for a model without an observation transform. Works on every posterior
    structure (dense, Kronecker, sparse).

    Args:
        model: A conditioned model.
        latents: Query latents. Shape (Q, ds).
        actions: Query actions. Shape (Q, dx).

    Returns:
        Mean (Q, dy) and variance of y' including the noise variance (Q, dy).
    """
    if model.posterior.kronecker is not None:
        return predict_kronecker(model, latents, actions)
    h = model.hyperparameters
    latents = as_float_array(latents, "latents", (None, h.latent_dim))
    actions = as_float_array(actions, "actions", (latents.shape[0], h.action_dim))
    data = model.data
    support_objects, support_actions = support_points(model)
    mean = np.empty((latents.shape[0], h.observation_dim))
    variance = np.empty_like(mean)
    for a in range(h.observation_dim):
        k_latent = squared_exponential(latents, model.latents, h.latent_lengthscales[a])
        k_action = squared_exponential(actions, support_actions, h.action_lengthscales[a])
        cross = h.signal_variance[a] * k_latent[:, support_objects] * k_action
        mean[:, a] = data.observation_mean[a] + cross @ model.posterior.beta[a]
        reduction = np.sum((cross @ model.posterior.gram_inverse[a]) * cross, axis=1)
        variance[:, a] = np.maximum(h.signal_variance[a] - reduction, 0.0) + h.noise_variance[a]
    return mean, variance
