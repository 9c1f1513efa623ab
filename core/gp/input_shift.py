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

σ_δ² is estimated from the training touches, each met at its own placement: their
leave-one-out residuals e_i (dy,) with variances v_i are modelled as
N(0, diag(v_i) + J_i diag(σ_δ²) J_iᵀ), and σ_δ² maximises that likelihood
(:func:`estimate_shift_variance`). The residuals of steep touches being larger than those of flat
ones is what identifies it; where the data show no such pattern the estimate goes to its lower
bound and the shift changes nothing.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import scipy.optimize

from core.errors import InvalidInputError
from core.gp.kernels import squared_exponential
from core.gp.noise_model import gram_inverse_diagonal
from core.gp.posterior import support_points
from core.types import ManifoldModel
from core.validation import FloatArray, as_float_array

__all__ = [
    "ShiftEstimate",
    "check_shift_variance",
    "estimate_shift_variance",
    "fit_shift_variance",
    "mean_jacobian",
    "shift_covariance",
    "with_input_shift",
]

#: Bounds of σ_δ,k² relative to the training actions' variance along k: from "none" to twice
#: the design's spread (the estimate also takes up noise that grows with the slope, which need
#: not be a placement's alone).
_LOWER_FRACTION, _UPPER_FRACTION = 1e-8, 4.0

#: Queries per block of :func:`mean_jacobian`.
_QUERY_CHUNK = 512


@dataclass(frozen=True)
class ShiftEstimate:
    """σ_δ² estimated from the training touches (:func:`estimate_shift_variance`).

    Attributes:
        variance: σ_δ,k², the variance of the shift along each action dimension, in squared
            action units. Shape (dx,).
        log_likelihood_gain: How much the leave-one-out residuals' log-likelihood rose over
            σ_δ² = 0, in nats (≥ 0).
        touches: Training touches the estimate used.
    """

    variance: FloatArray
    log_likelihood_gain: float
    touches: int


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
) -> FloatArray:
    """The covariance the input shift adds to T touches under one object, feature-major.

    Entry ((a, t), (b, u)) is J_a(x_t) diag(σ_δ²) J_b(x_u)ᵀ when the touches share one placement
    (``shared``), else only for t = u (each touch its own shift).

    Args:
        model: A conditioned model.
        latent: The object's latent s_l. Shape (ds,).
        actions: The touches' actions. Shape (T, dx).
        variance: σ_δ² (:func:`check_shift_variance`). Shape (dx,).
        shared: Whether the touches met one placement.

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
    if not shared:
        touch = np.tile(np.arange(t), h.observation_dim)
        cov = np.where(touch[:, None] == touch[None, :], cov, 0.0)
    return np.asarray(cov, dtype=np.float64)


def check_shift_variance(model: ManifoldModel, variance: object) -> FloatArray:
    """σ_δ² as a checked array: dx finite values ≥ 0. Shape (dx,).

    Raises:
        InvalidInputError: Wrong length, not finite, or negative.
    """
    value = as_float_array(variance, "shift_variance", (model.hyperparameters.action_dim,))
    if np.any(value < 0.0):
        raise InvalidInputError(
            f"shift_variance: every σ_δ,k² must be ≥ 0, received {value.tolist()}."
        )
    return value


def _negative_log_likelihood(
    log_variance: FloatArray, residuals: FloatArray, variances: FloatArray, jac: FloatArray
) -> tuple[float, FloatArray]:
    """½ Σ_i [log det C_i + e_iᵀ C_i⁻¹ e_i] with C_i = diag(v_i) + J_i diag(σ²) J_iᵀ, and its
    gradient in log σ² (constants left out)."""
    variance = np.exp(log_variance)
    cov = np.einsum("nak,k,nbk->nab", jac, variance, jac)
    cov[:, np.arange(variances.shape[1]), np.arange(variances.shape[1])] += variances
    factor = np.linalg.cholesky(cov)
    log_det = 2.0 * np.sum(np.log(np.diagonal(factor, axis1=1, axis2=2)))
    solve_e = np.linalg.solve(cov, residuals[..., None])[..., 0]  # (N, dy)
    solve_j = np.linalg.solve(cov, jac)  # (N, dy, dx)
    value = 0.5 * (log_det + float(np.sum(residuals * solve_e)))
    trace = np.einsum("nak,nak->k", jac, solve_j)
    quad = np.sum(np.einsum("nak,na->nk", jac, solve_e) ** 2, axis=0)
    return value, 0.5 * variance * (trace - quad)


def fit_shift_variance(
    residuals: FloatArray, variances: FloatArray, jacobians: FloatArray, action_variance: FloatArray
) -> tuple[FloatArray, float]:
    """σ_δ² maximising Σ_i log N(e_i; 0, diag(v_i) + J_i diag(σ_δ²) J_iᵀ).

    Bounded to [10⁻⁸, 4] times ``action_variance`` per dimension (:data:`_LOWER_FRACTION`,
    :data:`_UPPER_FRACTION`); L-BFGS-B with the analytic gradient from three starts.

    Args:
        residuals: e_i. Shape (N, dy).
        variances: v_i, > 0. Shape (N, dy).
        jacobians: J_i. Shape (N, dy, dx).
        action_variance: The actions' variance per dimension, > 0. Shape (dx,).

    Returns:
        ``(σ_δ², gain)``: shape (dx,), and the log-likelihood's rise over σ_δ² at its lower bound
        in nats (the lower bound and 0 when nothing rises).
    """
    e = as_float_array(residuals, "residuals", (None, None))
    v = as_float_array(variances, "variances", e.shape)
    jac = as_float_array(jacobians, "jacobians", (e.shape[0], e.shape[1], None))
    spread = as_float_array(action_variance, "action_variance", (jac.shape[2],))
    if np.any(v <= 0.0) or np.any(spread <= 0.0):
        raise InvalidInputError("fit_shift_variance: variances must be > 0.")
    lower, upper = np.log(_LOWER_FRACTION * spread), np.log(_UPPER_FRACTION * spread)
    baseline, _ = _negative_log_likelihood(lower, e, v, jac)
    best: scipy.optimize.OptimizeResult | None = None
    for fraction in (1e-4, 1e-2, 0.25):
        result = scipy.optimize.minimize(
            _negative_log_likelihood,
            np.log(fraction * spread),
            args=(e, v, jac),
            jac=True,
            method="L-BFGS-B",
            bounds=list(zip(lower, upper, strict=True)),
        )
        if best is None or result.fun < best.fun:
            best = result
    assert best is not None
    gain = baseline - float(best.fun)
    if gain <= 0.0:
        return np.exp(lower), 0.0
    return np.asarray(np.exp(best.x), dtype=np.float64), float(gain)


def estimate_shift_variance(model: ManifoldModel) -> ShiftEstimate | None:
    """σ_δ² by maximum likelihood on the training touches' leave-one-out residuals.

    Each training touch met its own placement (a collection turns the table between touches), so
    its residual carries its own shift: e_i ~ N(0, diag(v_i) + J_i diag(σ_δ²) J_iᵀ), with e_i and
    v_i the exact leave-one-out residual and variance (:func:`core.gp.noise_model
    .gram_inverse_diagonal`) and J_i the mean's slope at the touch (the full posterior's: one
    touch among hundreds hardly changes it); :func:`fit_shift_variance`.

    Returns:
        The estimate, or ``None`` for a posterior without exact leave-one-out (sparse).
    """
    diagonal = gram_inverse_diagonal(model)  # (dy, N)
    if diagonal is None:
        return None
    data = model.data
    jac = mean_jacobian(model, model.latents[data.object_index], data.actions)
    spread = np.maximum(data.actions.var(axis=0), np.finfo(float).tiny)
    variance, gain = fit_shift_variance(
        (model.posterior.beta / diagonal).T, (1.0 / diagonal).T, jac, spread
    )
    return ShiftEstimate(variance=variance, log_likelihood_gain=gain, touches=int(jac.shape[0]))


def with_input_shift(model: ManifoldModel) -> tuple[ManifoldModel, ShiftEstimate | None]:
    """The model with σ_δ² estimated from its training touches, for scoring trials.

    The fit is left as it is (its σ_n² already holds the average shift its touches saw); the
    shift's covariance enters the object likelihood of a trial's touches
    (:func:`core.recognition.object_posterior.object_log_likelihoods`) and the model's own
    samples (:class:`core.evaluation.trial_engine.ModelTrial`). Run it after the placement and
    drift effects, so the residuals are taken under the model that scores.

    Returns:
        The model and the estimate; the model unchanged and ``None`` for a sparse posterior.
    """
    estimate = estimate_shift_variance(model)
    if estimate is None:
        return model, None
    return dataclasses.replace(model, shift_variance=estimate.variance), estimate
