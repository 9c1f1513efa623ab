"""Object manifold learning: maximise Σ_a log p(y_a | S, X, γ_a) over S and γ (docs/method.md M2).

The public entry points: :func:`fit_manifold` (a fitted, normalised model), :func:`iter_fit`
(the same fit as a generator of progress events) and :func:`fit_hyperparameters` (latents held
fixed). Their settings are :class:`core.gp.fit_options.FitOptions`; how a fit runs — data-driven and
random starts, screening on a subsample, differential evolution, the choice of the winner and
the normalisation of its latents — is described and implemented in :mod:`core.gp.fit_run`.
"""

from __future__ import annotations

from collections.abc import Callable, Generator

import numpy as np

from core.errors import ConvergenceError, CoreError, InvalidInputError
from core.gp.fit_options import OPTIMIZERS, FitOptions, FitProgress, Optimizer
from core.gp.fit_run import (
    FitProblem,
    FitRun,
    StartMap,
    WarmStart,
    at_bounds,
    fit_structure,
    normalise_latents,
)
from core.gp.initialisation import normalise_spread
from core.gp.noise_model import (
    NOISE_MODEL_CHOICES,
    NoiseModelChoice,
    attach_transform,
    iter_fit_noise_model,
    transform_data,
)
from core.gp.optimiser_stream import run_to_end
from core.gp.parameters import initial_hyperparameters, parameter_bounds
from core.gp.posterior import condition, make_likelihood
from core.types import FitDiagnostics, ManifoldModel, TrainingData
from core.validation import FloatArray, as_float_array

__all__ = [
    "NOISE_MODEL_CHOICES",
    "OPTIMIZERS",
    "FitCancelledError",
    "FitOptions",
    "FitProgress",
    "NoiseModelChoice",
    "Optimizer",
    "fit_hyperparameters",
    "fit_manifold",
    "iter_fit",
    "normalise_latents",
    "refit_warm",
]


class FitCancelledError(CoreError):
    """A :func:`fit_manifold` callback returned ``False``.

    Attributes:
        best_so_far: The best model reached before the cancellation (normalised, conditioned
            on all the data), or ``None`` if no start had produced parameters yet.
    """

    def __init__(self, message: str, best_so_far: ManifoldModel | None) -> None:
        super().__init__(message)
        self.best_so_far = best_so_far


def iter_fit(
    data: TrainingData,
    latent_dim: int,
    rng: np.random.Generator,
    options: FitOptions = FitOptions(),
    noise_model: NoiseModelChoice | None = None,
    start_map: StartMap | None = None,
    fitted: ManifoldModel | None = None,
) -> Generator[FitProgress, None, None]:
    """Fit the object manifold, yielding progress (a generator; see the module docstring).

    Events come every ``options.progress_every`` optimiser iterations and at the end of each
    stage; the last event has ``phase="done"`` and carries the model. Close the generator to
    stop early (the running optimiser is stopped cleanly).

    Args:
        data: Training touches (L ≥ 2 objects).
        latent_dim: ds ≥ 1.
        rng: Random generator (random starts, screening subsample, DE).
        options: Fit settings.
        noise_model: ``None`` (default): the GPs are fitted to the observations as given, no
            transform. ``"independent"``, ``"correlated"`` or ``"auto"``: standardise the
            features, and whiten their correlated noise (:mod:`core.gp.noise_model`); the model
            keeps the transform. Those run one fit (independent) or two (a first fit gives the
            residual noise covariance, then a refit), with the stage named in ``phase``.
        start_map: Runs the first stage of the starts (:data:`core.gp.fit_run.StartMap`, e.g. as
            Dask tasks); ``None``: one after another here. The model does not depend on it.
        fitted: With a noise model: a fit of these data at this ds already done (e.g. by
            the selection of ds) with the noise model ``"independent"`` or the one asked
            for; only what follows it runs (:func:`core.gp.noise_model.iter_fit_noise_model`).

    Yields:
        :class:`FitProgress` events.

    Raises:
        InvalidInputError: Bad ``latent_dim``, ``rng``, ``options`` or ``noise_model``, or a
            constant feature (with a noise model).
        ConvergenceError: Every start failed.
    """
    if fitted is not None and (noise_model is None or fitted.latent_dim != latent_dim):
        raise InvalidInputError(
            f"fitted: needs a noise model and ds = {latent_dim}, received noise model "
            f"{noise_model!r} and a model of ds = {fitted.latent_dim}."
        )
    if noise_model is None:
        return FitRun(data, latent_dim, rng, options, start_map).events()
    if noise_model not in NOISE_MODEL_CHOICES:
        raise InvalidInputError(
            f"noise_model: expected one of {', '.join(NOISE_MODEL_CHOICES)} or None, received "
            f"{noise_model!r}."
        )
    return iter_fit_noise_model(
        data,
        lambda model_data, warm: FitRun(
            model_data, latent_dim, rng, options, start_map, warm
        ).events(),
        noise_model,
        fitted,
    )


def refit_warm(
    data: TrainingData,
    model: ManifoldModel,
    options: FitOptions = FitOptions(),
    placement_variance: FloatArray | None = None,
) -> ManifoldModel:
    """The model refitted to ``data`` from where it stands: one joint L-BFGS-B run on all of
    ``data`` from its latents and hyperparameters (:class:`core.gp.fit_run.WarmStart`: no
    starts, screening or restarts, nothing random).

    For touches of the objects the model was fitted to, e.g. a cross-validation fold's
    training part (its other touches left out): the objects' arrangement carries over, so
    the refit only moves to the nearest optimum of ``data``. The model's observation
    transform (standardisation, whitening) is kept as it is, not estimated again from
    ``data``, and the refitted model keeps it.

    Args:
        data: Raw training touches of the model's objects (the same names, in order).
        model: A fitted model (``model.latent_dim`` is the refit's ds).
        options: Fit settings (``max_iterations``, the stall rule of the joint run,
            ``structure``, ``threads``).
        placement_variance: σ_b,a² held fixed in the refit: touches of ``data`` sharing a
            placement share an offset in its likelihood and posterior, and the refit fits the
            within-placement noise (:class:`core.gp.fit_run.WarmStart`; dense). ``None``:
            independent noise. Shape (dy,).

    Returns:
        The refitted model, conditioned on ``data`` (with the model's transform, if any).

    Raises:
        InvalidInputError: ``data`` are not touches of the model's objects, or dy or dx
            differ from the model's.
    """
    if not isinstance(data, TrainingData):
        raise InvalidInputError(f"data: expected TrainingData, received {type(data).__name__}.")
    if tuple(data.object_names) != tuple(model.data.object_names):
        raise InvalidInputError(
            f"data: expected touches of the model's {model.data.n_objects} objects, in its "
            f"order, received {data.n_objects} objects (first: {data.object_names[0]!r})."
        )
    if (data.action_dim, data.observation_dim) != (
        model.data.action_dim,
        model.data.observation_dim,
    ):
        raise InvalidInputError(
            f"data: expected dx = {model.data.action_dim}, dy = {model.data.observation_dim} "
            f"as the model's, received dx = {data.action_dim}, dy = {data.observation_dim}."
        )
    transform = model.transform
    model_data = data if transform is None else transform_data(data, transform)
    warm = WarmStart(model.latents, model.hyperparameters, placement_variance)
    # A warm run draws nothing at random; the generator is only FitRun's argument.
    run = FitRun(model_data, model.latent_dim, np.random.default_rng(0), options, warm_start=warm)
    fitted: ManifoldModel | None = None
    for event in run.events():
        if event.model is not None:
            fitted = event.model
    if fitted is None:  # pragma: no cover - a fit's last event carries its model
        raise ConvergenceError("the manifold fit ended without a model.")
    return fitted if transform is None else attach_transform(fitted, transform, data)


def fit_manifold(
    data: TrainingData,
    latent_dim: int,
    rng: np.random.Generator,
    options: FitOptions = FitOptions(),
    callback: Callable[[FitProgress], bool | None] | None = None,
    noise_model: NoiseModelChoice | None = None,
    start_map: StartMap | None = None,
) -> ManifoldModel:
    """Fit the object manifold (docs/method.md M2) and return the normalised model.

    Args:
        data: Training touches.
        latent_dim: ds ≥ 1.
        rng: Random generator.
        options: Fit settings.
        callback: Receives every :class:`FitProgress`; returning ``False`` (not ``None``)
            cancels the fit.
        noise_model: See :func:`iter_fit` (``None``: no observation transform).
        start_map: See :func:`iter_fit`.

    Returns:
        The fitted model (latents normalised; ``diagnostics`` filled in).

    Raises:
        FitCancelledError: The callback returned ``False``; its ``best_so_far`` holds the best
            model reached (``None`` with a noise model: its stages are not comparable).
        InvalidInputError: Bad arguments.
        ConvergenceError: Every start failed.
    """
    run = FitRun(data, latent_dim, rng, options, start_map) if noise_model is None else None
    events = (
        run.events()
        if run is not None
        else iter_fit(data, latent_dim, rng, options, noise_model, start_map)
    )
    model: ManifoldModel | None = None
    try:
        for event in events:
            if callback is not None and callback(event) is False:
                events.close()
                raise FitCancelledError(
                    f"manifold fit cancelled by the callback at start {event.start} of "
                    f"{event.n_starts}, iteration {event.iteration}.",
                    run.best_model_so_far() if run is not None else None,
                )
            if event.model is not None:
                model = event.model
    finally:
        events.close()
    if model is None:  # pragma: no cover - the generator always ends with a model
        raise ConvergenceError("the manifold fit ended without a model.")
    return model


def fit_hyperparameters(
    data: TrainingData,
    latents: FloatArray,
    options: FitOptions = FitOptions(),
) -> ManifoldModel:
    """Fit only the hyperparameters, with the latents held fixed (e.g. the paper's
    "randomly-set object parameter" baseline).

    The latents are normalised first (which does not change what the model can fit); the
    hyperparameters start from :func:`core.gp.parameters.initial_hyperparameters` and are
    optimised with L-BFGS-B on all the data (``options.max_iterations``, ``ftol``, ``gtol``).

    Args:
        data: Training touches.
        latents: Fixed object latents. Shape (L, ds).
        options: Fit settings (the L-BFGS-B ones, ``structure``, ``kernels`` and ``threads``:
            the features' problems on that many threads, the same result as on one).

    Returns:
        The model; ``diagnostics`` describe the single start.
    """
    latents = as_float_array(latents, "latents", (data.n_objects, None))
    if latents.shape[1] < 1:
        raise InvalidInputError(f"latents: need at least one column, received {latents.shape}.")
    normalised, _, _ = normalise_spread(latents)
    structure = fit_structure(data, options.structure, options.kernels)
    likelihood = make_likelihood(
        data, latents.shape[1], structure, options.n_inducing, kernels=options.kernels
    )
    layout = likelihood.layout
    lower, upper = parameter_bounds(data, layout, max(options.latent_bound, 1.0))
    hyper = initial_hyperparameters(data, layout.latent_dim, options.initial_latent_lengthscale)
    vector = np.clip(layout.pack(normalised, hyper), lower, upper)
    problem = FitProblem(likelihood, lower, upper, structure, options.n_inducing).with_threads(
        options.threads
    )
    result = run_to_end(problem.fit_separately(vector, layout, options, options.max_iterations))
    final = result.vector
    s, h = layout.unpack(final)
    free = np.zeros(layout.size, dtype=bool)
    free[layout.hyperparameters] = True
    on_bounds = at_bounds(final, lower, upper, layout, free)
    diagnostics = FitDiagnostics(
        starts_log_likelihood=(-result.value,),
        best_start=0,
        iterations=result.iterations,
        converged=result.converged,
        message=result.message,
        jitter_used=problem.max_jitter,
        hyperparameters_at_bounds=on_bounds,
        kernels=options.kernels,
    )
    s, h = normalise_latents(s, h)
    return condition(data, s, h, diagnostics, structure=structure, n_inducing=options.n_inducing)
