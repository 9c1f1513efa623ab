"""Nested warm starts: fit ds = 1, 2, ... each from the optimum one dimension below.

Fits of separate latent dimensions stop in separate local optima (docs/method.md M2), so their
maximised likelihoods need not grow with ds — measured on Experiment-2-like worlds: a 4-D fit
27 nats *below* the 3-D one, a 1-D fit 28 nats below what a 2-D fit reaches on a 1-D world
(docs/noise-model.md). Any choice of ds that compares fits inherits that noise. Here ds = k is
fitted with the usual starts plus the ds = k - 1 optimum with one latent coordinate appended
(:func:`appended_starts`): small random values, and the leading principal direction of what the
k - 1 latents leave unexplained in the object profiles. If the ds = k fit still ends below the
ds = k - 1 optimum, that optimum itself, embedded in ds = k with a constant new coordinate
(:func:`embed_model`: the same predictions and likelihood), is kept instead. So the maximised
log-likelihood is non-decreasing in ds by construction. A downward sweep then refits each
smaller ds from the projection of the one above (:func:`nested_fits`).

The ladder is the cheap variant for all the data of a cross-validation with warm folds
(:mod:`core.selection.latent_selection`): every ds fitted on its own (:func:`rung_tasks`,
:func:`fit_rung`), so the fits can run at once, then only the carrying over, upward
(:func:`kept_ladder`) — no fit starts from another.

Pure maths: the fit is a function argument, randomness comes in as a generator.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from core.errors import InvalidInputError
from core.gp.initialisation import object_profiles
from core.gp.posterior import condition
from core.types import Hyperparameters, ManifoldModel, TrainingData
from core.validation import FloatArray

#: RMS of the random new coordinate, relative to the unit RMS spread of the latents.
NEW_COORDINATE_SCALE = 0.1

#: A fit that also takes extra starting latents, each (L, ds) (``FitOptions.initial_latents``),
#: and the random generator its own random starts come from.
StartedFit = Callable[
    [TrainingData, int, tuple[FloatArray, ...], np.random.Generator], ManifoldModel
]


@dataclass(frozen=True)
class NestedFit:
    """One rung of :func:`nested_fits`.

    Attributes:
        model: The model kept at this ds.
        carried_over: ``True`` when the ds fit ended below the ds - 1 optimum and the latter,
            embedded (:func:`embed_model`), was kept instead.
        fitted_log_likelihood: Log-likelihood the ds fit itself reached (of the downward
            refit when ``from_above``).
        from_above: ``True`` when the downward refit from the ds + 1 model was kept.
    """

    model: ManifoldModel
    carried_over: bool
    fitted_log_likelihood: float
    from_above: bool = False


def appended_starts(model: ManifoldModel, rng: np.random.Generator) -> tuple[FloatArray, ...]:
    """Starts for ds + 1 from a ds model: its latents with one coordinate appended.

    1. Random: N(0, 1) values, centred, scaled to RMS :data:`NEW_COORDINATE_SCALE` (an exact
       constant column would sit on a saddle by symmetry).
    2. Residual direction: the object profiles (:func:`core.gp.initialisation.object_profiles`,
       L × R·dy) are centred and regressed linearly on the latents; the new coordinate is the
       leading left singular vector of the residual, scaled to RMS σ₁ / ‖profiles‖_F (the share
       of the profiles' spread it carries, at least :data:`NEW_COORDINATE_SCALE`). Left out
       when nothing is left (the residual vanishes).

    Args:
        model: A fitted model; its latents (L, ds) are normalised.
        rng: Random generator (the random coordinate).

    Returns:
        One or two starting latents, each of shape (L, ds + 1).
    """
    latents = np.asarray(model.latents, dtype=np.float64)
    n_objects = latents.shape[0]
    draw = rng.standard_normal((n_objects,))
    draw -= draw.mean()
    draw *= NEW_COORDINATE_SCALE / max(float(np.sqrt(np.mean(draw**2))), 1e-300)
    starts = [np.hstack([latents, draw[:, None]])]
    profiles = object_profiles(model.data)
    profiles = profiles - profiles.mean(axis=0)
    total = float(np.linalg.norm(profiles))
    design = np.hstack([np.ones((n_objects, 1)), latents])
    coefficients, *_ = np.linalg.lstsq(design, profiles, rcond=None)
    residual = profiles - design @ coefficients
    u, singular, _ = np.linalg.svd(residual, full_matrices=False)
    if total > 0 and singular.size and singular[0] > 1e-8 * total:
        share = max(float(singular[0]) / total, NEW_COORDINATE_SCALE)
        column = u[:, 0] * np.sqrt(n_objects) * share
        starts.append(np.hstack([latents, (column - column.mean())[:, None]]))
    return tuple(starts)


def embed_model(model: ManifoldModel) -> ManifoldModel:
    """The same model with one more latent dimension, constant across objects.

    The new coordinate is 0 for every object, so every kernel value, prediction and the
    log-likelihood are unchanged (its length-scales, set to 1, then play no part). The model
    is conditioned afresh (:func:`core.gp.posterior.condition`) and keeps its observation
    transform and diagnostics.

    Args:
        model: A model of ds latent dimensions.

    Returns:
        A model of ds + 1 latent dimensions.
    """
    h = model.hyperparameters
    latents = np.hstack([model.latents, np.zeros((model.latents.shape[0], 1))])
    hyper = Hyperparameters(
        signal_variance=h.signal_variance,
        noise_variance=h.noise_variance,
        latent_lengthscales=np.hstack(
            [h.latent_lengthscales, np.ones((h.latent_lengthscales.shape[0], 1))]
        ),
        action_lengthscales=h.action_lengthscales,
    )
    embedded = condition(model.data, latents, hyper, model.diagnostics)
    if model.transform is None:
        return embedded
    return dataclasses.replace(
        embedded,
        transform=model.transform,
        source_data=model.source_data,
        log_likelihood=float(
            embedded.log_likelihood + model.raw_data.n_touches * model.transform.log_jacobian
        ),
    )


def projected_start(model: ManifoldModel, latent_dim: int) -> FloatArray:
    """A start for ds = ``latent_dim`` from a larger model: its latents projected onto their
    leading ``latent_dim`` principal directions. Shape (L, latent_dim)."""
    centred = model.latents - model.latents.mean(axis=0)
    _, _, vt = np.linalg.svd(centred, full_matrices=False)
    return np.asarray(centred @ vt[:latent_dim].T, dtype=np.float64)


def nested_fits(
    data: TrainingData,
    top_dim: int,
    fit: StartedFit,
    rng: np.random.Generator,
    downward: bool = True,
) -> tuple[NestedFit, ...]:
    """Fit ds = 1..top_dim, each from the ds - 1 optimum (module docstring).

    Upward: ds = k is fitted with :func:`appended_starts` of the model kept at k - 1; if it
    ends below that model, the embedded model (:func:`embed_model`) is kept. Downward (when
    ``downward``): for k = top_dim - 1 .. 1, ds = k is fitted again from the kept k + 1
    model's latents projected onto their leading k principal directions
    (:func:`projected_start`), kept if it ends higher — the small fits stop in local optima
    most (measured: a 1-D fit 163 nats below the 2-D one on a 1-D world, 1,591 from the 2-D
    optimum's projection, 1,622 from the true latents); a final upward sweep embeds again
    wherever a rung fell below the one beneath.

    Args:
        data: Training touches.
        top_dim: The largest ds (≥ 1).
        fit: Fits ``data`` at a ds with extra starting latents (the usual starts too); it is
            passed ``rng`` for its own random starts.
        rng: Random generator (the appended coordinates and the fits' random starts).
        downward: Also the downward sweep (top_dim - 1 more fits).

    Returns:
        One :class:`NestedFit` per ds = 1..top_dim; their models' log-likelihoods are
        non-decreasing.
    """
    if isinstance(top_dim, bool) or not isinstance(top_dim, int | np.integer) or top_dim < 1:
        raise InvalidInputError(f"top_dim: expected an integer ≥ 1, received {top_dim!r}.")
    top = int(top_dim)
    rungs: list[NestedFit] = []
    for ds in range(1, top + 1):
        below = rungs[-1].model if rungs else None
        starts = () if below is None else appended_starts(below, rng)
        model = fit(data, ds, starts, rng)
        rungs.append(_kept(model, below))
    if downward:
        for ds in range(top - 1, 0, -1):
            model = fit(data, ds, (projected_start(rungs[ds].model, ds),), rng)
            if model.log_likelihood > rungs[ds - 1].model.log_likelihood:
                rungs[ds - 1] = NestedFit(model, False, float(model.log_likelihood), True)
        for ds in range(2, top + 1):
            rung, below = rungs[ds - 1], rungs[ds - 2].model
            if rung.model.log_likelihood < below.log_likelihood:
                rungs[ds - 1] = dataclasses.replace(
                    rung, model=embed_model(below), carried_over=True
                )
    return tuple(rungs)


def _kept(model: ManifoldModel, below: ManifoldModel | None) -> NestedFit:
    """The fit, or the embedded model below when the fit ended lower."""
    fitted = float(model.log_likelihood)
    if below is not None and fitted < below.log_likelihood:
        return NestedFit(embed_model(below), True, fitted)
    return NestedFit(model, False, fitted)


@dataclass(frozen=True)
class RungPlan:
    """What every fit of :func:`ladder_fits` shares (sent to a worker once): the touches and
    the fit."""

    data: TrainingData
    fit: StartedFit


@dataclass(frozen=True)
class RungTask:
    """One fit of a ladder: its ds and its own random generator (the fits are independent)."""

    latent_dim: int
    rng: np.random.Generator


@dataclass(frozen=True)
class RungResult:
    """The model one :class:`RungTask` fitted."""

    latent_dim: int
    model: ManifoldModel


def fit_rung(plan: RungPlan, task: RungTask) -> RungResult:
    """Fit the plan's touches at the task's ds, with no extra starts. A pure function of the
    plan and the task: where it runs does not change its result."""
    return RungResult(task.latent_dim, plan.fit(plan.data, task.latent_dim, (), task.rng))


def kept_ladder(models: Sequence[ManifoldModel]) -> tuple[NestedFit, ...]:
    """The models kept at each ds of a ladder, from its fits in increasing ds: a fit that ended
    below the model kept at the ds beneath is replaced by that model embedded
    (:func:`embed_model`, once per missing dimension). The log-likelihoods are then
    non-decreasing in ds, as with :func:`nested_fits`, but no fit starts from another (no
    appended or projected starts), so where a larger ds's own starts miss the lower optimum's
    neighbourhood it is carried over rather than refitted from it.

    Args:
        models: Each ds's own fit, in increasing ds (any prefix of a ladder).

    Returns:
        One :class:`NestedFit` per model; their models' log-likelihoods are non-decreasing.
    """
    rungs: list[NestedFit] = []
    for model in models:
        below = rungs[-1].model if rungs else None
        if below is not None:
            while below.latent_dim < model.latent_dim - 1:
                below = embed_model(below)
        rungs.append(_kept(model, below))
    return tuple(rungs)


def rung_tasks(dims: Sequence[int], rng: np.random.Generator) -> list[RungTask]:
    """One :class:`RungTask` per ds of ``sorted(dims)``, each with its own generator spawned
    from ``rng`` in that order: the fits are independent, so they may run at once, anywhere,
    with the same result (:func:`fit_rung`).

    Raises:
        InvalidInputError: ``dims`` are not distinct integers ≥ 1.
    """
    order = sorted(int(d) for d in dims)
    if not order or order[0] < 1 or len(set(order)) != len(order):
        raise InvalidInputError(f"dims: expected distinct integers ≥ 1, received {list(dims)}.")
    return [
        RungTask(ds, task_rng) for ds, task_rng in zip(order, rng.spawn(len(order)), strict=True)
    ]
