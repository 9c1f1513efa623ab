"""The placement effect: a random offset shared by the touches of one placement of an object.

The base model (docs/method.md, (M1)) treats the touches of a trial as independent given the
object. On a rig they are not: the object is set down once per trial (its pose and contact point
shift a little every time) and the sensor drifts slowly, so every touch of a trial is shifted
alike. Per model-space feature a (docs/calibration.md, eq. (C1)–(C3)):

    y_ta = f_a(s_l, x_t) + b_a + ε_ta,   b_a ~ N(0, σ_b,a²) once per placement,
    ε_ta ~ N(0, σ_w,a²) per touch,        σ_w,a² = σ_n,a² − σ_b,a².

σ_n,a² of (M1) was fitted with every touch's noise independent, on touches that met many
placements, so it estimates the whole per-touch variance σ_b,a² + σ_w,a²: the split keeps each
touch's own predictive density as it was and moves σ_b,a² into a covariance shared by the touches
of one placement. Under object l the T touches of a trial are then one joint Gaussian per feature,

    y_a ~ N(m_a(s_l, X), V_a(s_l, X) + σ_b,a² 11ᵀ + σ_w,a² I),

with m_a and V_a the GP predictive mean and full T × T covariance of f_a at (s_l, x_1..x_T) (the
GP's cross-covariances between the touches included). The evidence of repeated touches then
saturates: a shared offset counts once, not once per touch.

σ_b² is estimated from a collection that records placements (several touches per placement):
:func:`estimate_placement_variance`. The fit then carries it into its own likelihood
(:func:`with_placement_effect`): a GP fitted with independent noise to touches taken in runs at one
placement learns part of the runs' shared offsets as a response to the actions, so the model is
refitted with σ_b² in its training covariance (:mod:`core.gp.placement_groups`), σ_b² estimated
again under the refitted model, and so on for a few rounds.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Literal

import numpy as np
import scipy.linalg

from core.errors import InvalidInputError
from core.gp.fit_options import FitOptions
from core.gp.input_shift import shift_covariance
from core.gp.kernels import squared_exponential
from core.gp.kronecker import predictive_covariance_kronecker
from core.gp.linalg import cholesky_with_jitter, gaussian_log_density
from core.gp.manifold import refit_warm
from core.gp.noise_model import attach_transform
from core.gp.placement_groups import checked_placement_variance, placement_groups, shared_groups
from core.gp.posterior import condition, gram_matrix, predict_model_space, support_points
from core.types import ManifoldModel
from core.validation import FloatArray, IntArray, as_float_array

#: σ_b,a² is kept at or below this fraction of σ_n,a², so that σ_w,a² stays positive.
MAX_PLACEMENT_FRACTION = 0.95

#: Rounds of (refit with σ_b² in the likelihood, estimate σ_b² again) after the first estimate.
PLACEMENT_ROUNDS = 2

PlacementPooling = Literal["mean", "median"]

#: How the objects' placements make one σ_b² (:func:`estimate_placement_variance`).
PLACEMENT_POOLINGS: tuple[PlacementPooling, ...] = ("mean", "median")

__all__ = [
    "MAX_PLACEMENT_FRACTION",
    "PLACEMENT_POOLINGS",
    "PLACEMENT_ROUNDS",
    "PlacementEstimate",
    "PlacementMoments",
    "PlacementPooling",
    "check_placement_pooling",
    "check_placement_variance",
    "estimate_placement_variance",
    "object_moment_estimates",
    "object_rows",
    "placement_groups",
    "placement_moments",
    "predictive_covariance",
    "trial_log_likelihoods",
    "with_placement_effect",
]


@dataclass(frozen=True)
class PlacementEstimate:
    """σ_b² estimated from touches grouped by placement (:func:`estimate_placement_variance`).

    Attributes:
        variance: σ_b,a², model space, after clipping to [0, MAX_PLACEMENT_FRACTION · σ_n,a²].
            Shape (dy,).
        raw_variance: The moment estimate before clipping (may be negative). Shape (dy,).
        groups: Placements with at least two touches (those that inform the estimate).
        pairs: Ordered pairs (i ≠ j) of touches sharing a placement, Σ_G n_G (n_G − 1).
        pooling: How the objects' placements were pooled (:data:`PLACEMENT_POOLINGS`).
    """

    variance: FloatArray
    raw_variance: FloatArray
    groups: int
    pairs: int
    pooling: PlacementPooling = "mean"


@dataclass(frozen=True)
class PlacementMoments:
    """Every placement's term of the method-of-moments sum of :func:`estimate_placement_variance`.

    Attributes:
        objects: The object of each placement with two touches or more. Shape (G,).
        pairs: Its ordered pairs of touches, n_G (n_G − 1). Shape (G,).
        contributions: Σ_{i≠j∈G} (r_i r_j − A_G,ij) per feature, the placement's part of the
            sum (eq. (C4)). Shape (G, dy).
        in_fit: The σ_b,0² already in the training covariance (zeros for none), which the
            sum's mean estimates σ_b² less of. Shape (dy,).
    """

    objects: IntArray
    pairs: IntArray
    contributions: FloatArray
    in_fit: FloatArray


def placement_moments(model: ManifoldModel, placement_index: IntArray) -> PlacementMoments:
    """The placements' terms of eq. (C4) from the leave-one-placement-out residuals
    (:func:`estimate_placement_variance` says how; O(N³) per feature).

    Args:
        model: A fitted model.
        placement_index: Placement number of every training touch. Shape (N,), integers.
    """
    data = model.data
    h = model.hyperparameters
    dy = h.observation_dim
    groups = shared_groups(data.object_index, placement_index)
    current = model.placement_variance if model.placement_in_fit else None
    in_fit = np.zeros(dy) if current is None else np.asarray(current, dtype=np.float64)
    objects = np.array([data.object_index[g[0]] for g in groups], dtype=np.int64)
    pairs = np.array([g.size * (g.size - 1) for g in groups], dtype=np.int64)
    contributions = np.zeros((len(groups), dy))
    if not groups:
        return PlacementMoments(objects, pairs, contributions, in_fit)
    training = dataclasses.replace(data, placement_index=placement_index)
    centred = data.observations - data.observation_mean
    identity = np.eye(data.n_touches)
    for a in range(dy):
        factor, _ = cholesky_with_jitter(
            gram_matrix(training, model.latents, h, a, current),
            what=f"Gram matrix of feature {a}",
        )
        inverse = scipy.linalg.cho_solve((factor, True), identity, check_finite=False)
        beta = inverse @ centred[:, a]
        for k, g in enumerate(groups):
            held_out_cov = np.linalg.inv(inverse[np.ix_(g, g)])
            residual = held_out_cov @ beta[g]
            cross = float(residual.sum() ** 2 - residual @ residual)
            expected = float(held_out_cov.sum() - np.trace(held_out_cov))
            contributions[k, a] = cross - expected
    return PlacementMoments(objects, pairs, contributions, in_fit)


def object_moment_estimates(moments: PlacementMoments, n_objects: int) -> FloatArray:
    """Each object's own moment estimate of σ_b², from its placements' terms alone:

        σ̂_l,a² = Σ_{G of l} c_G,a / Σ_{G of l} n_G (n_G − 1)   (+ the σ_b,0² in the fit).

    Args:
        moments: The placements' terms (:func:`placement_moments`).
        n_objects: L.

    Returns:
        σ̂_l,a², NaN for an object without a placement of two touches. Shape (L, dy).
    """
    dy = moments.contributions.shape[1]
    pairs = np.bincount(moments.objects, weights=moments.pairs, minlength=n_objects)
    raw = np.full((n_objects, dy), np.nan)
    known = pairs > 0
    for a in range(dy):
        sums = np.bincount(
            moments.objects, weights=moments.contributions[:, a], minlength=n_objects
        )
        raw[known, a] = sums[known] / pairs[known] + moments.in_fit[a]
    return raw


def check_placement_pooling(pooling: object) -> PlacementPooling:
    """``pooling`` if it is one of :data:`PLACEMENT_POOLINGS`.

    Raises:
        InvalidInputError: Anything else.
    """
    for known in PLACEMENT_POOLINGS:
        if pooling == known:
            return known
    raise InvalidInputError(
        f"placement_pooling: expected one of {list(PLACEMENT_POOLINGS)}, received {pooling!r}."
    )


def estimate_placement_variance(
    model: ManifoldModel,
    placement_index: IntArray,
    within_noise: bool = True,
    pooling: PlacementPooling = "mean",
) -> PlacementEstimate:
    """σ_b,a² from the leave-one-placement-out residuals of the training touches.

    For a placement G (its touches' indices), the GP conditioned on all the other touches
    predicts y_G with residual r_G = (K⁻¹)_GG⁻¹ β_G and, under the fitted model, covariance
    A_G = (K⁻¹)_GG⁻¹ = V_G + σ_n² I (the standard block leave-out identities; K the noisy Gram
    matrix, β = K⁻¹ (y − mean)). Under the placement model (eq. (C1)) the touches of G also
    share b, so E[r_i r_j] = A_G,ij + σ_b² for i ≠ j in G. The method-of-moments estimate pools
    every within-placement pair (docs/calibration.md, eq. (C4)):

        σ_b,a² = Σ_G Σ_{i≠j∈G} (r_i r_j − A_G,ij) / Σ_G n_G (n_G − 1),

    unbiased whatever the GP's own uncertainty at the held-out touches (it is subtracted), then
    clipped to [0, MAX_PLACEMENT_FRACTION · σ_n,a²]. Leaving the whole placement out matters:
    leaving one touch out would let its placement-mates' shared offset leak into the prediction.

    ``pooling`` says whose placements the one σ_b² describes. ``"mean"`` (the default) is the
    sum above: a pair-weighted mean over the objects. ``"median"`` is the median over the
    objects of each one's own estimate (:func:`object_moment_estimates`, the same sum over its
    placements alone): how much a placement moves the touches is a property of the object (a
    stiff plate's force moves with the contact point, a cloth's hardly), and one
    placement-sensitive object lifts the mean for every trial; the median is the typical
    object's, still one value for every object so that the estimates' noise never counts as
    evidence. Not the default: measured on the unseen workshop through the whole calibration,
    the input shift estimated after it takes back what σ_b² gives up, and the answers came out
    less sure, not more (docs/calibration.md, "The typical object's placement variance").

    A model whose training covariance already holds a σ_b,0² (``placement_in_fit``) has it in
    A_G's within-placement entries, so the sum estimates σ_b² − σ_b,0² and σ_b,0² is added back;
    the other placements' touches are then predicted with their own offsets accounted for.

    Args:
        model: A model fitted on the touches (dense, Kronecker or sparse: the Gram matrices are
            rebuilt here, O(N³) per feature).
        placement_index: Placement number of every training touch (with the object it forms the
            placement). Shape (N,).
        within_noise: Clip to [0, MAX_PLACEMENT_FRACTION · σ_n,a²], for a split of the fitted
            σ_n,a² (σ_b² for scoring only, eq. (C2)); ``False``: only to ≥ 0, for a refit that
            fits σ_w,a² beside it (:func:`with_placement_effect`).
        pooling: ``"median"`` or ``"mean"`` over the objects (above).

    Returns:
        The estimate; ``variance`` is zero when no placement has two touches.

    Raises:
        InvalidInputError: ``placement_index`` is not N integers ≥ 0, or an unknown
            ``pooling``.
    """
    pooling = check_placement_pooling(pooling)
    data = model.data
    placement = np.asarray(placement_index)
    if placement.shape != (data.n_touches,) or not np.issubdtype(placement.dtype, np.integer):
        raise InvalidInputError(
            f"placement_index: expected {data.n_touches} integers, received dtype "
            f"{placement.dtype} with shape {placement.shape}."
        )
    h = model.hyperparameters
    moments = placement_moments(model, placement)
    if moments.pairs.size == 0:
        zero = np.zeros(h.observation_dim)
        return PlacementEstimate(
            variance=zero, raw_variance=zero.copy(), groups=0, pairs=0, pooling=pooling
        )
    pairs = int(moments.pairs.sum())
    if pooling == "median":
        by_object = object_moment_estimates(moments, data.n_objects)
        raw = np.median(by_object[~np.isnan(by_object[:, 0])], axis=0)
    else:
        raw = moments.contributions.sum(axis=0) / pairs + moments.in_fit
    upper = MAX_PLACEMENT_FRACTION * h.noise_variance if within_noise else np.inf
    variance = np.clip(raw, 0.0, upper)
    return PlacementEstimate(
        variance=variance,
        raw_variance=raw,
        groups=int(moments.pairs.size),
        pairs=pairs,
        pooling=pooling,
    )


def with_placement_effect(
    model: ManifoldModel,
    options: FitOptions = FitOptions(),
    rounds: int = PLACEMENT_ROUNDS,
    pooling: PlacementPooling = "mean",
) -> tuple[ManifoldModel, PlacementEstimate | None]:
    """The model with the placement effect of its training touches, if they record placements.

    σ_b² is estimated (:func:`estimate_placement_variance`); then, ``rounds`` times, the model is
    refitted from where it stands with σ_b² held fixed in its likelihood and the
    within-placement noise fitted (:func:`core.gp.manifold.refit_warm`), and σ_b² estimated
    again under the refit. σ_b² is not bounded by the fitted σ_n² here (the refit fits σ_w²
    beside it). The result is conditioned with the last estimate in its training covariance
    (``placement_in_fit``; each touch's noise variance σ_w² + σ_b²), which is also the σ_b² a
    trial is scored with. A sparse posterior (no dense training covariance), and a fit with tied
    kernels (whose shared eigenbasis σ_b² Z Zᵀ would break), keep their fit and get the first
    estimate, clipped below σ_n², for scoring only.

    Args:
        model: A fitted model; its raw training data may carry ``placement_index``.
        options: Settings of the warm refits (``threads``, the joint run's iteration limit and
            stall rule).
        rounds: Refits with σ_b² in the likelihood (0: σ_b² split off the fitted σ_n² for
            scoring trials only, eq. (C2), the fit left as it is).
        pooling: How the objects' placements make σ_b² (:func:`estimate_placement_variance`).

    Returns:
        The model and the last estimate; the model unchanged and ``None`` when the training
        touches have no placements, or none touched twice (every touch met its own placement:
        nothing to estimate from, and the model stays as without placements).

    Raises:
        InvalidInputError: ``rounds`` is not an integer ≥ 0, or an unknown ``pooling``.
    """
    if isinstance(rounds, bool) or not isinstance(rounds, int) or rounds < 0:
        raise InvalidInputError(f"rounds: expected an integer ≥ 0, received {rounds!r}.")
    pooling = check_placement_pooling(pooling)
    placement = model.raw_data.placement_index
    if placement is None:
        return model, None
    scoring_only = (
        rounds == 0
        or model.posterior.inducing is not None
        or options.structure in ("kronecker", "sparse")
        or options.kernels == "tied"
    )
    estimate = estimate_placement_variance(model, placement, scoring_only, pooling)
    if estimate.groups == 0:
        return model, None
    if scoring_only:
        return dataclasses.replace(model, placement_variance=estimate.variance), estimate
    diagnostics = model.diagnostics  # the fit's own (its starts), not the refits'
    for _ in range(rounds):
        model = refit_warm(model.raw_data, model, options, placement_variance=estimate.variance)
        estimate = estimate_placement_variance(model, placement, False, pooling)
    model = dataclasses.replace(model, diagnostics=diagnostics)
    return _conditioned_with(model, estimate.variance), estimate


def _conditioned_with(model: ManifoldModel, variance: FloatArray) -> ManifoldModel:
    """``model`` conditioned again with σ_b² = ``variance`` in its training covariance; each
    touch's noise variance becomes σ_w² + σ_b² with the model's own within-placement σ_w² (its
    σ_n² less the σ_b² it holds, or all of σ_n² for a model without one in its covariance)."""
    h = model.hyperparameters
    held = model.placement_variance if model.placement_in_fit else None
    within = h.noise_variance if held is None else h.noise_variance - held
    hyper = dataclasses.replace(h, noise_variance=within + variance)
    data = dataclasses.replace(model.data, placement_index=model.raw_data.placement_index)
    conditioned = condition(
        data, model.latents, hyper, model.diagnostics, placement_variance=variance
    )
    if model.transform is None:
        return conditioned
    return attach_transform(conditioned, model.transform, model.raw_data)


def check_placement_variance(model: ManifoldModel, variance: FloatArray) -> FloatArray:
    """σ_b² as a checked array: dy values in [0, σ_n²). Shape (dy,).

    Raises:
        InvalidInputError: Wrong length, negative, or not below the noise variance.
    """
    h = model.hyperparameters
    return checked_placement_variance(variance, h.noise_variance, h.observation_dim)


def object_rows(model: ManifoldModel, variance: FloatArray) -> FloatArray:
    """A trial's shared variance under each object: ``variance`` (dy,) repeated for every
    object, or (L, dy) as given, each row checked (:func:`check_placement_variance`).
    Shape (L, dy)."""
    n_objects = model.latents.shape[0]
    array = np.asarray(variance, dtype=np.float64)
    if array.ndim == 2 and array.shape[0] == n_objects:
        return np.stack([check_placement_variance(model, row) for row in array])
    return np.tile(check_placement_variance(model, array), (n_objects, 1))


def predictive_covariance(
    model: ManifoldModel, latent: FloatArray, actions: FloatArray
) -> FloatArray:
    """Full GP predictive covariance of f_a (noise not included) at (s, x_1..x_T), per feature.

    V_a = σ_f,a² K^x_a(X, X) − k_a(Z*, Z) A_a k_a(Z, Z*) with Z* = (s, x_t) (the latent kernel
    is 1 between the touches: they share s) and A_a the posterior's matrix over its support
    points (K_a⁻¹ for dense and Kronecker posteriors). Its diagonal plus σ_n,a² is the variance of
    :func:`core.gp.posterior.predict_model_space`. A Kronecker posterior whose K⁻¹ is not
    materialised goes through its eigendecompositions instead
    (:func:`core.gp.kronecker.predictive_covariance_kronecker`), so K⁻¹ is never built for it here.

    Args:
        model: A conditioned model.
        latent: s. Shape (ds,).
        actions: x_1..x_T. Shape (T, dx).

    Returns:
        V_a for every feature. Shape (dy, T, T).
    """
    if model.posterior.kronecker is not None and not model.posterior.has_dense_inverse:
        return predictive_covariance_kronecker(model, latent, actions)
    h = model.hyperparameters
    s = as_float_array(latent, "latent", (h.latent_dim,))
    x = as_float_array(actions, "actions", (None, h.action_dim))
    support_objects, support_actions = support_points(model)
    gram_inverse = model.posterior.gram_inverse
    out = np.empty((h.observation_dim, x.shape[0], x.shape[0]))
    for a in range(h.observation_dim):
        k_latent = squared_exponential(s[None, :], model.latents, h.latent_lengthscales[a])[0]
        k_action = squared_exponential(x, support_actions, h.action_lengthscales[a])
        cross = h.signal_variance[a] * k_latent[support_objects][None, :] * k_action
        prior = h.signal_variance[a] * squared_exponential(x, x, h.action_lengthscales[a])
        cov = prior - cross @ gram_inverse[a] @ cross.T
        out[a] = 0.5 * (cov + cov.T)
    return out


def trial_log_likelihoods(
    model: ManifoldModel,
    actions: FloatArray,
    observations: FloatArray,
    variance: FloatArray,
    shift_variance: FloatArray | None = None,
    shared_placement: bool = True,
    shift_creep: FloatArray | None = None,
) -> FloatArray:
    """log p(y_1..y_T | l) of one trial's touches under every object, with a placement effect.

    Per object l and model-space feature a, one joint Gaussian over the T touches (eq. (C3)):
    N(y'_a; m_a(s_l, X), V_a(s_l, X) + σ_b,a² 11ᵀ + (σ_n,a² − σ_b,a²) I), summed over a, plus
    T · log|det M| (the Jacobian of the observation transform y' = M (y − c)). With T = 1 it
    equals the independent per-touch density of
    :func:`core.recognition.object_posterior.object_log_likelihoods`.

    Args:
        model: A conditioned model.
        actions: The trial's actions. Shape (T, dx).
        observations: Their raw observations. Shape (T, dy).
        variance: σ_b,a² in model space (:func:`check_placement_variance`). Shape (dy,), or
            (L, dy): each object's own (:mod:`core.gp.object_placement`), row l under object l.
        shift_variance: σ_δ², a placement's shift of the action (:mod:`core.gp.input_shift`):
            its covariance J_l diag(σ_δ²) J_lᵀ couples the touches and the features, so the
            trial is then one joint Gaussian over all of them. ``None``: none. Shape (dx,).
        shared_placement: Whether the touches met one placement (the shift is then shared;
            otherwise each touch has its own).
        shift_creep: σ_c², the shift's variance gained per touch of the placement (``None``:
            none). Shape (dx,).

    Returns:
        Log-likelihood of the trial under each object. Shape (L,).
    """
    h = model.hyperparameters
    x = as_float_array(actions, "actions", (None, h.action_dim))
    y = as_float_array(observations, "observations", (x.shape[0], h.observation_dim))
    rows = object_rows(model, variance)
    n_objects, t = model.latents.shape[0], x.shape[0]
    if t == 0:
        return np.zeros(n_objects)
    y_model = model.to_model_space(y)
    jacobian = 0.0 if model.transform is None else model.transform.log_jacobian
    ones = np.ones((t, t))
    out = np.empty(n_objects)
    for obj in range(n_objects):
        sigma_b = rows[obj]
        within = h.noise_variance - sigma_b
        latent = model.latents[obj]
        mean, _ = predict_model_space(model, np.tile(latent, (t, 1)), x)
        cov_f = predictive_covariance(model, latent, x)
        if shift_variance is not None:
            blocks = [
                cov_f[a] + sigma_b[a] * ones + within[a] * np.eye(t)
                for a in range(h.observation_dim)
            ]
            cov = scipy.linalg.block_diag(*blocks) + shift_covariance(
                model, latent, x, shift_variance, shared_placement, shift_creep
            )
            out[obj] = gaussian_log_density(
                (y_model - mean).T.reshape(-1), cov, "trial covariance with the input shift"
            )
            out[obj] += t * jacobian
            continue
        out[obj] = t * jacobian + sum(
            gaussian_log_density(
                y_model[:, a] - mean[:, a],
                cov_f[a] + sigma_b[a] * ones + within[a] * np.eye(t),
                f"trial covariance of feature {a}",
            )
            for a in range(h.observation_dim)
        )
    return out
