"""The input shift: a placement moves the object's surface, so every press lands off alike.

A placement tilts the object a little (docs/calibration.md, "The input shift"): every press of
that placement goes deeper or shallower than commanded, by the same amount. Through the slope
of the response this moves each feature by ∂m/∂x · δ: a lot where the response is steep (where
a press starts to reach an insert), nothing where it is flat. A constant offset per feature
(σ_b², :mod:`core.gp.placement_effect`) cannot describe that; a shift of the action can. Linearised
through the GP's predictive mean (the noisy-input GP of McHutchon & Rasmussen, 2011), with
δ ~ N(0, diag(σ_δ²)) in action units:

    y'_t ≈ m(s_l, x_t) + J_l(x_t) δ + ε_t,   J_l(x) = ∂m(s_l, x)/∂x  (dy × dx),

so under object l the touches of one placement gain the covariance J_l(x_t) diag(σ_δ²) J_l(x_u)ᵀ
between every pair of touches t, u and every pair of features (docs/method.md, "The input
shift"). The shift is object-dependent through the slope: two objects that differ only beyond
a threshold depth are told apart less surely by a press near that threshold.

σ_δ² is estimated from the training touches that share a placement (by default a collection
touches half its touches in pairs): leave the whole placement out, and the residuals of two of
its touches i, j covary, beyond what the fitted model (its σ_b² included) predicts, by
J_i diag(σ_δ²) J_jᵀ. Those cross-products are linear in σ_δ², so a non-negative least-squares
fit over every pair gives the estimate (:func:`shared_shift_variance`). Only the part of the
touches' errors that a placement shares identifies it: noise that grows with the slope but is
drawn afresh at every touch cancels in the cross-products. Without recorded placements there is
no estimate and the shift changes nothing.

A placement also creeps: every lift-off can leave the object sitting a little differently, so
the shift wanders from touch to touch as a random walk, δ_t = δ_0 + Σ_{i<t} ε_i with ε_i ~
N(0, diag(σ_c²)). The t-th and u-th touches of one placement (counted from 0) then share
diag(σ_δ² + σ_c² min(t, u)), so a trial's later touches share more than its first ones. The
creep moves the object the way a placement does, only by less: σ_c² = κ σ_δ², one κ ≥ 0 for all
action dimensions (fitted per dimension, runs of three touches from a training collection gave
σ_c² at its cap along a direction where the slopes are nearly zero: noise, not creep). Pairs
cannot see κ (their min(t, u) is 0); runs of three touches or more can: for each κ the
cross-products give σ_δ² by non-negative least squares, and κ is the one whose fit leaves the
least residual (docs/method.md (S3)).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import scipy.optimize

from core.errors import InvalidInputError
from core.gp.kernels import squared_exponential
from core.gp.placement_groups import shared_groups
from core.gp.posterior import support_points
from core.types import ManifoldModel
from core.validation import FloatArray, IntArray, as_float_array

__all__ = [
    "ShiftEstimate",
    "check_shift_creep",
    "check_shift_variance",
    "estimate_shift_variance",
    "mean_jacobian",
    "shared_shift_variance",
    "shift_covariance",
    "with_input_shift",
]

#: Largest σ_δ,k² relative to the training actions' variance along k: twice the design's spread.
_UPPER_FRACTION = 4.0

#: Largest κ = σ_c² / σ_δ²: a touch's creep at most twice the placement's own shift variance.
_KAPPA_MAX = 2.0

#: Queries per block of :func:`mean_jacobian`.
_QUERY_CHUNK = 512


@dataclass(frozen=True)
class ShiftEstimate:
    """σ_δ² estimated from the training touches that share placements
    (:func:`estimate_shift_variance`).

    Attributes:
        variance: σ_δ,k², the variance of the shift along each action dimension, in squared
            action units. Shape (dx,).
        creep: σ_c,k² = κ σ_δ,k², the variance the shift gains per touch within a placement.
            Shape (dx,).
        groups: Placements with at least two training touches.
        pairs: Ordered pairs of touches of one placement (each gives dy² cross-products).
        runs: Placements with three touches or more (the only ones that see the creep).
    """

    variance: FloatArray
    creep: FloatArray
    groups: int
    pairs: int
    runs: int


def mean_jacobian(model: ManifoldModel, latents: FloatArray, actions: FloatArray) -> FloatArray:
    """∂m_a(s_q, x_q)/∂x of the model-space predictive mean at every query. Shape (Q, dy, dx).

    m_a(s, x) = c_a + Σ_i σ_f,a² k^s_a(s, s_i) k^x_a(x, x_i) β_ai over the posterior's support
    points (every structure keeps β over them, :class:`core.types.GPPosterior`), and
    ∂k^x_a(x, x_i)/∂x_k = k^x_a(x, x_i) (x_ik − x_k) / ℓ_a,k².

    Args:
        model: A conditioned model.
        latents: Query latents. Shape (Q, ds).
        actions: Query actions. Shape (Q, dx).
    """
    h = model.hyperparameters
    latents = as_float_array(latents, "latents", (None, h.latent_dim))
    actions = as_float_array(actions, "actions", (latents.shape[0], h.action_dim))
    support_objects, support_actions = support_points(model)
    out = np.empty((latents.shape[0], h.observation_dim, h.action_dim))
    for start in range(0, latents.shape[0], _QUERY_CHUNK):  # bounded (chunk × n) temporaries
        rows = slice(start, start + _QUERY_CHUNK)
        for a in range(h.observation_dim):
            k_latent = squared_exponential(latents[rows], model.latents, h.latent_lengthscales[a])
            k_action = squared_exponential(actions[rows], support_actions, h.action_lengthscales[a])
            weights = h.signal_variance[a] * k_latent[:, support_objects] * k_action
            weights *= model.posterior.beta[a][None, :]  # (chunk, n)
            total = weights.sum(axis=1)
            slope = weights @ support_actions - total[:, None] * actions[rows]  # (chunk, dx)
            out[rows, a, :] = slope / h.action_lengthscales[a] ** 2
    return out


def shift_covariance(
    model: ManifoldModel,
    latent: FloatArray,
    actions: FloatArray,
    variance: FloatArray,
    shared: bool = True,
    creep: FloatArray | None = None,
) -> FloatArray:
    """The covariance the input shift adds to T touches under one object, feature-major.

    Entry ((a, t), (b, u)) is J_a(x_t) diag(σ_δ² + σ_c² min(t, u)) J_b(x_u)ᵀ when the touches
    share one placement in this order (``shared``), else J_a(x_t) diag(σ_δ²) J_b(x_t)ᵀ for t = u
    only (each touch its own placement, the first of it).

    Args:
        model: A conditioned model.
        latent: The object's latent s_l. Shape (ds,).
        actions: The touches' actions, in the order they were made. Shape (T, dx).
        variance: σ_δ² (:func:`check_shift_variance`). Shape (dx,).
        shared: Whether the touches met one placement.
        creep: σ_c², the shift's variance gained per touch (``None``: no creep). Shape (dx,).

    Returns:
        Shape (dy·T, dy·T), rows and columns ordered feature-major (a·T + t).
    """
    h = model.hyperparameters
    x = as_float_array(actions, "actions", (None, h.action_dim))
    s = as_float_array(latent, "latent", (h.latent_dim,))
    t = x.shape[0]
    jac = mean_jacobian(model, np.tile(s, (t, 1)), x)  # (T, dy, dx)
    rows = np.transpose(jac, (1, 0, 2)).reshape(h.observation_dim * t, h.action_dim)
    cov = (rows * variance[None, :]) @ rows.T
    touch = np.tile(np.arange(t), h.observation_dim)
    if not shared:
        cov = np.where(touch[:, None] == touch[None, :], cov, 0.0)
    elif creep is not None and t > 1:
        cov += np.minimum(touch[:, None], touch[None, :]) * ((rows * creep[None, :]) @ rows.T)
    return np.asarray(cov, dtype=np.float64)


def check_shift_variance(model: ManifoldModel, variance: object) -> FloatArray:
    """σ_δ² as a checked array: dx finite values ≥ 0. Shape (dx,).

    Raises:
        InvalidInputError: Wrong length, not finite, or negative.
    """
    return _per_action_variance(model, variance, "shift_variance", "σ_δ,k²")


def check_shift_creep(model: ManifoldModel, creep: object) -> FloatArray:
    """σ_c² as a checked array: dx finite values ≥ 0. Shape (dx,).

    Raises:
        InvalidInputError: Wrong length, not finite, or negative.
    """
    return _per_action_variance(model, creep, "shift_creep_variance", "σ_c,k²")


def _per_action_variance(model: ManifoldModel, value: object, name: str, symbol: str) -> FloatArray:
    checked = as_float_array(value, name, (model.hyperparameters.action_dim,))
    if np.any(checked < 0.0):
        raise InvalidInputError(f"{name}: every {symbol} must be ≥ 0, received {checked.tolist()}.")
    return checked


def shared_shift_variance(
    residuals: list[FloatArray],
    covariances: list[FloatArray],
    jacobians: list[FloatArray],
    action_variance: FloatArray,
) -> tuple[FloatArray, FloatArray, int]:
    """σ_δ² ≥ 0 and σ_c² = κ σ_δ² from the leave-placement-out residuals of placements with
    ≥ 2 touches, each placement's touches in the order they were made.

    For touches i ≠ j (positions i, j in their placement) and features a, b: E[r_ia r_jb] =
    [a = b] A_a,ij + Σ_k σ_δ,k² (1 + κ min(i, j)) J_ia,k J_jb,k. For a given κ the excess
    cross-products are linear in σ_δ², fitted by non-negative least squares (Lawson–Hanson);
    κ ∈ [0, :data:`_KAPPA_MAX`] minimises the residual norm (bounded Brent, against κ = 0). σ_δ²
    is then capped at 4 × ``action_variance`` (a shift beyond twice the design's spread is not a
    placement's). Without runs of three touches no pair has min(i, j) > 0: κ = 0.

    Args:
        residuals: Per placement, r_G in touch order. Shape (n_G, dy) each.
        covariances: Per placement, the model's leave-placement-out covariance A_G per feature.
            Shape (dy, n_G, n_G) each.
        jacobians: Per placement, the slopes J of its touches. Shape (n_G, dy, dx) each.
        action_variance: The training actions' variance per dimension. Shape (dx,).

    Returns:
        ``(σ_δ², σ_c², pairs)``: shapes (dx,) and (dx,), and the number of ordered pairs used.
    """
    spread = as_float_array(action_variance, "action_variance", (None,))
    design: list[FloatArray] = []
    creep: list[FloatArray] = []
    target: list[FloatArray] = []
    for r, cov, jac in zip(residuals, covariances, jacobians, strict=True):
        n = r.shape[0]
        first, second = np.nonzero(~np.eye(n, dtype=bool))  # ordered pairs i ≠ j
        # (pairs, dy, dy) products r_ia r_jb and the model's part, (pairs, dy, dy, dx) slopes.
        products = r[first][:, :, None] * r[second][:, None, :]
        expected = np.zeros_like(products)
        diagonal = np.arange(r.shape[1])
        expected[:, diagonal, diagonal] = cov[:, first, second].T
        slopes = jac[first][:, :, None, :] * jac[second][:, None, :, :]
        design.append(slopes.reshape(-1, jac.shape[2]))
        creep.append(
            (np.minimum(first, second)[:, None, None, None] * slopes).reshape(design[-1].shape)
        )
        target.append((products - expected).reshape(-1))
    if not design:
        return np.zeros_like(spread), np.zeros_like(spread), 0
    shared, steps, vector = np.concatenate(design), np.concatenate(creep), np.concatenate(target)

    def misfit(kappa: float) -> float:
        return float(scipy.optimize.nnls(shared + kappa * steps, vector)[1])

    kappa = 0.0
    if np.any(steps != 0.0):
        best = scipy.optimize.minimize_scalar(misfit, bounds=(0.0, _KAPPA_MAX), method="bounded")
        if best.fun < misfit(0.0):
            kappa = float(best.x)
    variance, _ = scipy.optimize.nnls(shared + kappa * steps, vector)
    pairs = sum(r.shape[0] * (r.shape[0] - 1) for r in residuals)
    variance = np.minimum(variance, _UPPER_FRACTION * spread)
    return variance, kappa * variance, int(pairs)


def estimate_shift_variance(
    model: ManifoldModel, dimensions: IntArray | None = None
) -> ShiftEstimate | None:
    """σ_δ² and σ_c² from the training touches that share a placement
    (:func:`shared_shift_variance`), each placement's touches in the order of their times
    (in the data's order when no times were recorded).

    ``dimensions`` are the action dimensions a placement can shift; σ_δ² is estimated along
    those alone and is zero along the others. On the rig that is the press depth: a placement
    tilts the object, so a press lands deeper or shallower, which the press-depth component
    describes and the DMP's shape components do not (docs/method.md, "The input shift"). Left free,
    the least-squares fit also puts variance on shape components where the training touches'
    slopes are small; the planners' touches, which go where the slopes are large, then share
    more than they do (docs/calibration.md, "The shift along the press depth only").

    Leaving placement G out of the GP conditioned on all the touches gives its residuals
    r_G,a = A_G,a β_G,a with covariance A_G,a = ((K_a⁻¹)_GG)⁻¹ (the block leave-out identities,
    as the placement effect's estimator uses them), K_a the model's own noisy Gram matrix (its
    σ_b² included when the fit has it, so only what a constant offset does not describe is
    left); J at each touch is the slope of the full posterior's mean at the object's latent.

    Args:
        model: A conditioned model whose training touches record placements.
        dimensions: Indices of the action dimensions the shift may move, distinct, in
            0..dx-1; ``None``: every dimension. Shape (k,).

    Returns:
        The estimate; ``None`` when the touches record no placement with two touches, or for a
        sparse posterior (no K⁻¹ over the touches).

    Raises:
        InvalidInputError: ``dimensions`` empty, repeated or out of range.
    """
    dx = model.data.action_dim
    along = checked_shift_dimensions(dimensions, dx)
    if model.posterior.inducing is not None:
        return None
    data = model.data
    groups = shared_groups(data.object_index, model.raw_data.placement_index)
    if not groups:
        return None
    times = model.raw_data.touch_times_s
    inverse = model.posterior.gram_inverse  # (dy, N, N)
    beta = model.posterior.beta  # (dy, N)
    residuals: list[FloatArray] = []
    covariances: list[FloatArray] = []
    jacobians: list[FloatArray] = []
    if times is not None:  # each placement's touches in the order they were made
        groups = [g[np.argsort(times[g], kind="stable")] for g in groups]
    for g in groups:
        cov = np.asarray(np.linalg.inv(inverse[:, g[:, None], g[None, :]]), dtype=np.float64)
        residuals.append(np.einsum("aij,aj->ia", cov, beta[:, g]))
        covariances.append(cov)
        jacobians.append(mean_jacobian(model, model.latents[data.object_index[g]], data.actions[g]))
    spread = np.maximum(data.actions.var(axis=0), np.finfo(float).tiny)
    free, free_creep, pairs = shared_shift_variance(
        residuals, covariances, [j[:, :, along] for j in jacobians], spread[along]
    )
    variance, creep = np.zeros(dx), np.zeros(dx)
    variance[along], creep[along] = free, free_creep
    runs = sum(g.size >= 3 for g in groups)
    return ShiftEstimate(variance, creep, groups=len(groups), pairs=pairs, runs=runs)


def checked_shift_dimensions(dimensions: IntArray | None, action_dim: int) -> IntArray:
    """The action dimensions a shift may move, as sorted indices (all of them for ``None``).

    Raises:
        InvalidInputError: Empty, not integers, repeated, or outside 0..action_dim-1.
    """
    if dimensions is None:
        return np.arange(action_dim)
    values = np.asarray(dimensions)
    if (
        values.ndim != 1
        or values.size == 0
        or not np.issubdtype(values.dtype, np.integer)
        or np.unique(values).size != values.size
        or values.min() < 0
        or values.max() >= action_dim
    ):
        raise InvalidInputError(
            f"shift_dimensions: expected distinct action dimensions in 0..{action_dim - 1}, "
            f"received {dimensions!r}."
        )
    return np.sort(values.astype(np.int64))


def with_input_shift(
    model: ManifoldModel, dimensions: IntArray | None = None
) -> tuple[ManifoldModel, ShiftEstimate | None]:
    """The model with σ_δ² (and σ_c², when runs of three touches show it) estimated from its
    training touches, for scoring trials.

    The fit is left as it is (its σ_n² already holds the average shift its touches saw); the
    shift's covariance enters the object likelihood of a trial's touches
    (:func:`core.recognition.object_posterior.object_log_likelihoods`) and the model's own
    samples (:class:`core.evaluation.trial_engine.ModelTrial`). Run it after the placement and
    drift effects, so the residuals are taken under the model that scores.

    Args:
        model: A conditioned model.
        dimensions: The action dimensions a placement may shift (:func:`estimate_shift_variance`);
            ``None``: all.

    Returns:
        The model and the estimate; the model unchanged and ``None`` without placements of two
        touches or for a sparse posterior.
    """
    estimate = estimate_shift_variance(model, dimensions)
    if estimate is None:
        return model, None
    creep = estimate.creep if np.any(estimate.creep > 0.0) else None
    return (
        dataclasses.replace(model, shift_variance=estimate.variance, shift_creep_variance=creep),
        estimate,
    )
