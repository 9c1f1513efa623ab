"""Correlated observation noise: estimate Σ_ε, whiten, refit (docs/method.md "Real tactile data").

The per-feature GPs of docs/method.md (M1) assume independent noise across features. Real tactile
channels are not independent (the two vibration features move together, heat flux and
temperature see one heat exchange), so this module fits the GPs to y' = M (y - c)
(:class:`core.observation_transform.ObservationTransform`):

1. standardise every feature (offset = mean, scale = standard deviation; a constant feature is
   rejected with a message naming it), fit the independent model (M1) to z = (y - c) / scale;
2. estimate the noise covariance of z: Σ_z = diag(σ_n) R diag(σ_n), σ_n,a² the fitted noise
   variances and R the correlation across features of the first fit's leave-one-out residuals
   (standardised by their leave-one-out standard deviations; the posterior residuals of a
   sparse model, which has no exact leave-one-out);
3. whiten: W = Σ_z^{-1/2} (the symmetric root, so y'_a stays closest to feature a), refit the
   independent per-feature GPs to y' = W z. The refit starts from the first fit
   (:func:`warm_start`): whitening is a linear map of the observations, so the arrangement of
   the objects carries over; it is one start polished on all the data, not a second
   multi-start fit (the measurements are in docs/fitting.md).

``noise_model="auto"`` keeps the correlated model when its leave-one-out predictive
log-likelihood of the raw observations beats the independent one's by more than the number of
correlations it estimated, dy(dy-1)/2 nats (an AIC-like allowance: those correlations were also
estimated from the left-out touch), and by more than two standard errors of the paired
per-touch differences. See docs/noise-model.md for the comparison on data.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Generator, Iterator
from typing import Literal

import numpy as np

from core.errors import InvalidInputError
from core.gp.fit_options import FitProgress
from core.gp.fit_run import WarmStart
from core.gp.posterior import predict_model_space
from core.observation_transform import ObservationTransform
from core.types import Hyperparameters, ManifoldModel, TrainingData
from core.validation import FloatArray

#: What a fit may be asked for.
NoiseModelChoice = Literal["auto", "independent", "correlated"]
NOISE_MODEL_CHOICES: tuple[str, ...] = ("auto", "independent", "correlated")

#: A feature whose standard deviation is below this fraction of max(1, |mean|) is constant.
CONSTANT_FEATURE_TOLERANCE = 1e-10

#: Eigenvalues of an estimated correlation are floored at this (keeps W finite).
_EIGENVALUE_FLOOR = 1e-6


def check_features(data: TrainingData) -> None:
    """Reject constant features (no model can learn from them; they would divide by zero).

    Raises:
        InvalidInputError: Names every constant feature (``y_3``, 1-based as in the CSV) with
            its value.
    """
    y = data.observations
    mean = y.mean(axis=0)
    std = y.std(axis=0)
    constant = np.flatnonzero(std <= CONSTANT_FEATURE_TOLERANCE * np.maximum(1.0, np.abs(mean)))
    if constant.size:
        names = ", ".join(f"y_{a + 1} (= {mean[a]:.6g} on every touch)" for a in constant)
        raise InvalidInputError(
            f"observations: feature(s) {names} are constant; a constant channel carries no "
            f"information about the object. Remove the column(s) and fit again."
        )


def standardising_transform(data: TrainingData) -> ObservationTransform:
    """The ``"independent"`` transform: z = (y - mean) / std per feature.

    Raises:
        InvalidInputError: A feature is constant (see :func:`check_features`).
    """
    check_features(data)
    y = data.observations
    dy = data.observation_dim
    eye = np.eye(dy)
    return ObservationTransform(
        "independent", y.mean(axis=0), y.std(axis=0), eye, eye.copy(), "standardised"
    )


def transform_data(data: TrainingData, transform: ObservationTransform) -> TrainingData:
    """The training touches with observations mapped to y' = M (y - c)."""
    return TrainingData(
        object_names=data.object_names,
        object_index=data.object_index,
        actions=data.actions,
        observations=transform.apply(data.observations),
        placement_index=data.placement_index,
    )


def attach_transform(
    model: ManifoldModel, transform: ObservationTransform, raw_data: TrainingData
) -> ManifoldModel:
    """A model conditioned on ``transform_data(raw_data, transform)``, with the transform kept.

    The log-likelihood becomes that of the raw observations: + N · log|det M|.

    Raises:
        InvalidInputError: The model's data are not the transformed ``raw_data``.
    """
    expected = transform.apply(raw_data.observations)
    if model.data.observations.shape != expected.shape or not np.allclose(
        model.data.observations, expected, rtol=1e-12, atol=1e-12
    ):
        raise InvalidInputError(
            "attach_transform: the model was not conditioned on the transformed raw data."
        )
    return dataclasses.replace(
        model,
        transform=transform,
        source_data=raw_data,
        log_likelihood=float(model.log_likelihood + raw_data.n_touches * transform.log_jacobian),
    )


def gram_inverse_diagonal(model: ManifoldModel) -> FloatArray | None:
    """diag(K_a⁻¹) of every feature in data order (dy, N); ``None`` for a sparse posterior.

    A Kronecker posterior gives it from its eigendecompositions without materialising K⁻¹:
    diag(K⁻¹)[(l, m)] = Σ_jk U_s[l, j]² U_x[m, k]² / D[j, k]  (O(L² M + L M²) per feature).
    """
    posterior = model.posterior
    factors = posterior.kronecker
    if factors is not None:
        latent_sq = factors.latent_eigenvectors**2  # (dy, L, L)
        action_sq = factors.action_eigenvectors**2  # (dy, M, M)
        grid = latent_sq @ (1.0 / factors.spectrum) @ np.swapaxes(action_sq, 1, 2)  # (dy, L, M)
        return np.asarray(grid.reshape(grid.shape[0], -1)[:, factors.grid_index])
    if posterior.structure == "sparse":
        return None
    return np.asarray(np.diagonal(posterior.gram_inverse, axis1=1, axis2=2))


def standardised_residuals(model: ManifoldModel) -> FloatArray:
    """Residuals of the model-space training observations, each standardised. Shape (N, dy).

    Leave-one-out where the posterior holds K⁻¹ (dense, Kronecker): r_ai = β_ai / sqrt([K_a⁻¹]_ii)
    (the left-out residual divided by its predictive standard deviation, Rasmussen & Williams
    §5.4.2); the posterior residuals y' - m' divided by sqrt(v') for a sparse model.
    """
    diagonal = gram_inverse_diagonal(model)  # (dy, N)
    if diagonal is not None:
        return np.asarray((model.posterior.beta / np.sqrt(diagonal)).T, dtype=np.float64)
    data = model.data
    mean, variance = predict_model_space(model, model.latents[data.object_index], data.actions)
    return np.asarray((data.observations - mean) / np.sqrt(variance), dtype=np.float64)


def residual_correlation(model: ManifoldModel) -> FloatArray:
    """Correlation across features of :func:`standardised_residuals`. Shape (dy, dy)."""
    residuals = standardised_residuals(model)
    residuals = residuals - residuals.mean(axis=0)
    covariance = residuals.T @ residuals / residuals.shape[0]
    std = np.sqrt(np.diag(covariance))
    return np.asarray(covariance / np.outer(std, std), dtype=np.float64)


def whitening_transform(
    base: ObservationTransform, covariance: FloatArray, note: str
) -> ObservationTransform:
    """The ``"correlated"`` transform whitening a noise covariance of the standardised features.

    Args:
        base: The standardising transform (its offset and scale are kept).
        covariance: Σ_z, noise covariance of z = (y - c) / scale. Shape (dy, dy).
        note: How Σ_z was estimated.

    Returns:
        y' = Σ_z^{-1/2} z, with the correlation of Σ_z recorded.
    """
    dy = base.dim
    cov = np.asarray(covariance, dtype=np.float64)
    if cov.shape != (dy, dy) or not np.all(np.isfinite(cov)):
        raise InvalidInputError(
            f"noise covariance: expected a finite ({dy}, {dy}) matrix, received {cov.shape}."
        )
    cov = 0.5 * (cov + cov.T)
    std = np.sqrt(np.diag(cov))
    if np.any(std <= 0):
        raise InvalidInputError("noise covariance: every feature needs a positive variance.")
    # Floor the correlation's eigenvalues (a nearly singular estimate would blow W up).
    values, vectors = np.linalg.eigh(cov / np.outer(std, std))
    correlation = (vectors * np.maximum(values, _EIGENVALUE_FLOOR)) @ vectors.T
    correlation = correlation / np.sqrt(np.outer(np.diag(correlation), np.diag(correlation)))
    sigma = correlation * np.outer(std, std)
    # W = Σ_z^{-1/2}, the symmetric root (y'_a stays closest to feature a).
    # docs/method.md "Real tactile data": y' = Σ_ε^{-1/2} y.
    s_values, s_vectors = np.linalg.eigh(sigma)
    whitening = (s_vectors / np.sqrt(s_values)) @ s_vectors.T
    return ObservationTransform("correlated", base.offset, base.scale, whitening, correlation, note)


def correlated_transform(
    independent: ManifoldModel, base: ObservationTransform
) -> ObservationTransform:
    """Σ_z = diag(σ_n) R diag(σ_n) from a first independent fit, whitened (module docstring).

    Args:
        independent: The model fitted to the standardised data ``transform_data(raw, base)``.
        base: The standardising transform.
    """
    sigma = np.sqrt(independent.hyperparameters.noise_variance)
    correlation = residual_correlation(independent)
    where = "leave-one-out" if independent.posterior.structure != "sparse" else "posterior"
    return whitening_transform(
        base,
        correlation * np.outer(sigma, sigma),
        f"noise correlation from the {where} residuals of a first independent fit",
    )


def warm_start(independent: ManifoldModel, transform: ObservationTransform) -> WarmStart:
    """Where the refit on the whitened observations y' = W z starts: the first fit's latents
    and length-scales, and its signal and noise variances carried through W.

    With the noise covariance Σ_z that W whitens, y' has unit noise variance in every feature
    (W Σ_z W = I), and feature a's signal, a mix Σ_b W_ab f_b of the first fit's independent
    signals, has variance Σ_b W_ab² σ_f,b². The length-scales of feature a are kept: the
    symmetric root keeps y'_a closest to z_a.

    Args:
        independent: The model fitted to the standardised observations z.
        transform: The ``"correlated"`` transform (its ``whitening`` is W).
    """
    h = independent.hyperparameters
    whitening = np.asarray(transform.whitening)
    return WarmStart(
        latents=independent.latents,
        hyperparameters=Hyperparameters(
            signal_variance=(whitening**2) @ h.signal_variance,
            noise_variance=np.ones_like(h.noise_variance),
            latent_lengthscales=h.latent_lengthscales,
            action_lengthscales=h.action_lengthscales,
        ),
    )


def within_object_transform(data: TrainingData) -> ObservationTransform:
    """Whitening by the pooled within-object covariance of the standardised features.

    The quick fix docs/method.md describes (it mixes the signal's variation with the action into the
    "noise"); kept for comparison in bench/correlated_noise.py.
    """
    base = standardising_transform(data)
    z = base.apply(data.observations)
    means = np.zeros((data.n_objects, data.observation_dim))
    np.add.at(means, data.object_index, z)
    means /= data.touches_per_object()[:, None]
    centred = z - means[data.object_index]
    covariance = centred.T @ centred / (data.n_touches - data.n_objects)
    return whitening_transform(base, covariance, "pooled within-object covariance")


def loo_log_likelihoods(model: ManifoldModel) -> FloatArray | None:
    """Leave-one-out predictive log-density of every raw training observation, in nats.

    Σ_a log N(y'_ai; μ_-i, σ²_-i) + log|det M| per touch i, with σ²_-i = 1/[K_a⁻¹]_ii and
    y'_ai - μ_-i = β_ai / [K_a⁻¹]_ii (exact for the dense and Kronecker posteriors, at the fitted
    latents and hyperparameters). ``None`` for a sparse posterior (no exact leave-one-out).

    Returns:
        Shape (N,), or ``None``.
    """
    diagonal = gram_inverse_diagonal(model)  # (dy, N)
    if diagonal is None:
        return None
    log_density = 0.5 * np.log(diagonal) - 0.5 * model.posterior.beta**2 / diagonal
    log_density -= 0.5 * np.log(2.0 * np.pi)
    jacobian = 0.0 if model.transform is None else model.transform.log_jacobian
    return np.asarray(log_density.sum(axis=0) + jacobian, dtype=np.float64)


def loo_log_likelihood(model: ManifoldModel) -> float | None:
    """Sum of :func:`loo_log_likelihoods` (``None`` for a sparse posterior)."""
    values = loo_log_likelihoods(model)
    return None if values is None else float(values.sum())


#: The first (independent) fit's share of the evaluations of a fit with a correlated refit,
#: for ``FitProgress.fraction`` (the refit starts warm: docs/fitting.md).
FIRST_FIT_SHARE = 0.8


def _stage(
    events: Iterator[FitProgress],
    name: str,
    sink: list[ManifoldModel],
    done: float = 0.0,
    share: float = 1.0,
) -> Generator[FitProgress, None, None]:
    """Re-yield a fit's events with the stage named and their fraction mapped onto
    [done, done + share] of the whole; its model goes to ``sink``."""
    for event in events:
        if event.model is not None:
            sink.append(event.model)
        yield dataclasses.replace(
            event,
            phase=f"{name}: {event.phase}",
            model=None,
            fraction=done + share * event.fraction,
        )


def iter_fit_noise_model(
    data: TrainingData,
    fit: Callable[[TrainingData, WarmStart | None], Iterator[FitProgress]],
    noise_model: NoiseModelChoice,
    fitted: ManifoldModel | None = None,
) -> Generator[FitProgress, None, None]:
    """Fit with a noise model (module docstring), yielding the fits' progress.

    Args:
        data: Raw training touches.
        fit: Runs one manifold fit on model-space data, from a warm start when one is given
            (e.g. a :class:`core.gp.fit_run.FitRun` with the latent dimension, rng and options
            bound).
        noise_model: ``"independent"`` (standardise only), ``"correlated"`` (standardise and
            whiten the residual noise covariance of a first fit) or ``"auto"`` (both; keep the
            correlated one when it wins on leave-one-out predictive likelihood).
        fitted: A fit of ``data`` already done (e.g. by the selection of ds): with
            ``noise_model="independent"`` (a model with their standardising transform), it is
            the first fit and ``fit`` runs only the refit; with the ``noise_model`` asked for,
            ``"correlated"``, it is the model.

    Yields:
        The fits' events with the stage in ``phase`` (``"independent: joint"``…); the last
        event (``phase="done"``) carries the model with its transform.

    Raises:
        InvalidInputError: Unknown ``noise_model``, a constant feature, or ``fitted`` not
            a fit of ``data`` with one of those noise models.
    """
    if noise_model not in NOISE_MODEL_CHOICES:
        raise InvalidInputError(
            f"noise_model: expected one of {', '.join(NOISE_MODEL_CHOICES)}, received "
            f"{noise_model!r}."
        )
    base = standardising_transform(data)
    given = None if fitted is None else fitted.transform
    if fitted is not None and given is not None and given.kind == noise_model == "correlated":
        attach_transform(fitted, given, data)  # raises unless fitted to these data
        yield _last(fitted)  # the refit is done too
        return
    models: list[ManifoldModel] = []
    first_share = 1.0 if noise_model == "independent" else FIRST_FIT_SHARE
    if fitted is None:
        first_fit = fit(transform_data(data, base), None)
        yield from _stage(first_fit, "independent", models, 0.0, first_share)
        first = attach_transform(models[-1], base, data)
    else:
        _check_fitted(fitted, data, base)
        models.append(fitted)  # its latents and hyperparameters are model-space
        first = dataclasses.replace(fitted, transform=base)  # base's own note
    final = first
    if noise_model != "independent":
        transform = correlated_transform(models[-1], base)
        refit = fit(transform_data(data, transform), warm_start(models[0], transform))
        yield from _stage(refit, "correlated", models, first_share, 1.0 - first_share)
        second = attach_transform(models[-1], transform, data)
        final = second if noise_model == "correlated" else choose_noise_model(first, second)
    if final.transform is not None and noise_model != "auto":
        final = _with_note(final, f"{noise_model} (as asked); {final.transform.note}")
    yield _last(final)


def _last(model: ManifoldModel) -> FitProgress:
    """The event that ends a fit with a noise model: it carries the model."""
    return FitProgress(
        start=0,
        n_starts=1,
        iteration=0,
        log_likelihood=model.log_likelihood,
        best_log_likelihood=model.log_likelihood,
        phase="done",
        model=model,
        fraction=1.0,
    )


def _check_fitted(model: ManifoldModel, data: TrainingData, base: ObservationTransform) -> None:
    """Reject a first fit that is not the standardised fit of ``data``."""
    transform = model.transform
    if (
        transform is None
        or transform.kind != "independent"
        or not np.array_equal(transform.offset, base.offset)
        or not np.array_equal(transform.scale, base.scale)
    ):
        raise InvalidInputError(
            "fitted: expected a model fitted with noise_model='independent' to these "
            "data (their standardising transform)."
        )
    attach_transform(model, base, data)  # raises unless conditioned on these touches


def _with_note(model: ManifoldModel, note: str) -> ManifoldModel:
    assert model.transform is not None
    return dataclasses.replace(model, transform=dataclasses.replace(model.transform, note=note))


def choose_noise_model(independent: ManifoldModel, correlated: ManifoldModel) -> ManifoldModel:
    """``"auto"``: the correlated model if its leave-one-out gain is clear (note added).

    Clear: the total gain Σ_i d_i (d_i the per-touch difference of leave-one-out log-densities)
    exceeds both dy(dy-1)/2 nats (the estimated correlations) and two standard errors of the
    sum, 2 · sqrt(N) · std(d).
    """
    loo_independent = loo_log_likelihoods(independent)
    loo_correlated = loo_log_likelihoods(correlated)
    dy = independent.data.observation_dim
    allowance = 0.5 * dy * (dy - 1)
    if loo_independent is None or loo_correlated is None:
        return _with_note(
            independent,
            "auto: independent (a sparse posterior has no exact leave-one-out likelihood to "
            "compare; ask for 'correlated' explicitly)",
        )
    differences = loo_correlated - loo_independent
    gain = float(differences.sum())
    two_se = float(2.0 * np.sqrt(differences.shape[0]) * differences.std(ddof=1))
    scores = (
        f"leave-one-out log-likelihood {loo_correlated.sum():.2f} (correlated) vs "
        f"{loo_independent.sum():.2f} (independent) nats: gain {gain:.2f}, needed more than "
        f"{max(allowance, two_se):.2f} (the {allowance:.0f} estimated correlations and two "
        f"standard errors, {two_se:.2f})"
    )
    if gain > max(allowance, two_se):
        return _with_note(correlated, f"auto: correlated; {scores}")
    return _with_note(independent, f"auto: independent; {scores}")
